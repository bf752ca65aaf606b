"""Sphinx configuration of Nephele's documentation (``make docs``).

The build is offline and strict: no intersphinx, nothing fetched, warnings are
errors (``-W`` in the Makefile).  Pages are Markdown (MyST), one file per page;
the API reference is autodoc + numpydoc on the public names.
"""

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))

project = "Nephele"
author = "the Nephele developers"
copyright = "the Nephele developers, GPL-3.0-or-later"
release = version = "0.1.0"

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "nephele_cli",
    "nephele_xref",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# The figure scripts in docs/ are code, not pages; the lock file is report.py's.
exclude_patterns = ["_build", "*.py", "_ext", "benchmarks.lock"]

# MyST: heading anchors for links such as `benchmarks.md#...`, $math$, ::: fences.
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist", "attrs_inline"]

# autodoc / numpydoc: document what the docstrings say, in source order, without the type
# hints repeated in the signature (the numpydoc Parameters sections carry them).
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autodoc_default_options = {}
autosummary_generate = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# No network: MathJax is loaded by the browser when a page with math is opened, never by the build.
html_theme = "pydata_sphinx_theme"
html_title = "Nephele"
html_static_path = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 7,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_sidebars = {"index": [], "getting-started": [], "testing": [], "architecture": []}
html_show_sourcelink = False


def _benchmark_targets(app, docname, source):
    """Give every section of benchmarks.md a stable target, ``bench-<name>``.

    benchmarks/report.py writes each section between ``<!-- BEGIN name -->`` and
    ``<!-- END name -->``; pages link to ``bench-name`` whatever its title says.
    """
    if docname == "benchmarks":
        source[0] = re.sub(r"<!-- BEGIN ([\w-]+) -->\n", r"<!-- BEGIN \1 -->\n(bench-\1)=\n", source[0])


def setup(app):
    app.connect("source-read", _benchmark_targets)
