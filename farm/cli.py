"""``nephele``: the command line.  Each sub-command is a plain module
``farm/cmd_<name>.py`` with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``.  Bad input (a :class:`~nephele.core.errors.DataError`
or :class:`UsageError`) and an output that cannot be written (a full disk, a
read-only folder: :class:`~nephele.core.files.WriteError`) print one line
and exit with code 2, no traceback.
"""

import argparse
import importlib
import sys

from ..core.errors import DataError, UsageError

COMMANDS = (
    "info",
    "contour",
    "demo",
    "film",
    "render",
    "precompute",
    "post",
    "volume",
    "advect",
    "scatter",
    "dome",
    "muscle",
    "build_extension",
    "cluster_check",
)


DESCRIPTION = "Turn climate data and other scientific fields into films with Blender."
EPILOG = """optional parts (pip extras):
  pip install 'nephele[data]'   NetCDF files, .ply/.glb export, advection, scattering, dome
  pip install 'nephele[farm]'   rendering with Blender (bpy 5.2, Python 3.13) on Dask or Slurm

Run 'nephele COMMAND --help' for a command's options."""

# Optional packages -> the extra that installs them (pyproject.toml [project.optional-dependencies]).
EXTRAS = {
    "xarray": "data", "netCDF4": "data", "cftime": "data", "pandas": "data", "scipy": "data", "trimesh": "data",
    "bpy": "farm", "mathutils": "farm", "dask": "farm", "distributed": "farm", "dask_jobqueue": "farm",
    "imageio_ffmpeg": "farm", "psutil": "farm",
}


def _load():
    # The one list of commands: a missing or broken command module is an error, never skipped.
    return {name.replace("_", "-"): importlib.import_module(f".cmd_{name}", __package__) for name in COMMANDS}


def build_parser():
    parser = argparse.ArgumentParser(prog="nephele", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, mod in _load().items():
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None):
    """Run a command; returns its exit status."""
    code = _main(argv)
    if "nephele.core.climate.hdf5check" in sys.modules:  # a damaged NetCDF-4 header left a thread stuck in HDF5
        sys.modules["nephele.core.climate.hdf5check"].end_now(code)
    return code


def _main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    from ..core import native

    # A fallback is said aloud: once per run, where the user looks.
    native.on_fallback(lambda text: print(f"nephele {args.command}: note: {text}", file=sys.stderr))
    try:
        return int(args._run(args) or 0)
    except (DataError, UsageError, FileNotFoundError) as exc:
        print(f"nephele {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a full disk, a read-only or forbidden folder: where, and what to do
        from ..core.files import write_error

        problem = write_error(exc, exc.filename or "output")
        if problem is None:
            raise
        print(f"nephele {args.command}: error: {problem}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        extra = EXTRAS.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"nephele {args.command}: error: this needs {exc.name}, which is not installed: "
              f"pip install 'nephele[{extra}]'", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nephele {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
