"""``nephele``: the command line.  Each sub-command is a plain module
``farm/cmd_<name>.py`` with ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``.  Bad input (a :class:`~nephele.core.errors.DataError`
or :class:`UsageError`) prints one line and exits with code 2, no traceback.
"""

import argparse
import importlib
import sys

from ..core.errors import DataError

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


class UsageError(ValueError):
    """A bad command-line value, found before any work starts."""


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
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (DataError, UsageError, FileNotFoundError) as exc:
        print(f"nephele {args.command}: error: {exc}", file=sys.stderr)
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
