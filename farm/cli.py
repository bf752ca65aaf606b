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
    "render",
    "precompute",
    "post",
    "volume",
    "advect",
    "scatter",
    "dome",
    "build_extension",
)


class UsageError(ValueError):
    """A bad command-line value, found before any work starts."""


def _load():
    cmds = {}
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f".cmd_{name}", __package__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__package__}.cmd_{name}":
                raise
            continue
        cmds[name.replace("_", "-")] = mod
    return cmds


def build_parser():
    parser = argparse.ArgumentParser(prog="nephele", description=__doc__.split("\n\n")[0])
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
    except KeyboardInterrupt:
        print(f"nephele {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
