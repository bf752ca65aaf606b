"""``{nephele-help} COMMAND``: the ``nephele COMMAND --help`` text, from the parser itself.

The command-line pages show what the installed ``nephele`` prints, so they cannot fall
behind the options (``farm/cli.py`` builds the parser; nothing is run).
"""

import os

from docutils import nodes
from sphinx.util.docutils import SphinxDirective


def help_text(command=None, width=76):
    """The help of ``nephele`` (``command=None``) or of one sub-command, wrapped at ``width``."""
    from nephele.farm.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)  # argparse wraps at the terminal width it finds here
    try:
        parser = build_parser()
        if command is not None:
            parser = parser._subparsers._group_actions[0].choices[command]
        return parser.format_help().rstrip()
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


class NepheleHelp(SphinxDirective):
    optional_arguments = 1

    def run(self):
        command = self.arguments[0] if self.arguments else None
        try:
            text = help_text(command)
        except KeyError:
            raise self.error(f"nephele has no command {command!r}") from None
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return [block]


def setup(app):
    app.add_directive("nephele-help", NepheleHelp)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
