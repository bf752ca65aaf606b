"""Cross-references to where a name is documented, and constants documented where they are exported.

The API pages document each public name once, under the package that exports it
(``nephele.core.volume.resample``), while docstrings name it where it is defined
(``nephele.core.volume.sparse.resample``), relative to their own module
(``blobby.blobby_surface``) or their own class (``points`` in ``GlobeGrid``).  Python's
domain finds none of these; this finds the one documented object they mean.

A reference is resolved only when exactly one documented object fits: its full name
ends with the reference's dotted name, and, where several do, the one sharing the
longest leading part with the reference (or with the page's module and class).  Anything
else stays unresolved, and ``sphinx -n`` reports it.

A constant documented under the package that exports it (``.. autodata:: PRESET_DEFAULTS``
in ``nephele.core.camera``) gets the docstring written under its assignment in the module
that defines it (``camera/dome.py``), not the docstring of its type (a tuple's "Built-in
immutable sequence").
"""

import sys

from sphinx.pycode import ModuleAnalyzer
from sphinx.util.nodes import make_refnode

# Reference roles -> the object types they may point at.
ROLES = {
    "func": {"function", "method", "classmethod", "staticmethod"},
    "meth": {"method", "classmethod", "staticmethod", "function", "property"},
    "class": {"class", "exception"},
    "exc": {"exception", "class"},
    "attr": {"attribute", "property", "data"},
    "data": {"data", "attribute"},
    "const": {"data", "attribute"},
    "mod": {"module"},
    "obj": None,
}


def _shared(a, b):
    n = 0
    for x, y in zip(a.split("."), b.split(".")):
        if x != y:
            break
        n += 1
    return n


def candidates(objects, target, role):
    """Documented full names that the dotted ``target`` may mean, for reference ``role``."""
    kinds = ROLES.get(role)
    tail = "." + target
    return [name for name, obj in objects.items()
            if (name.endswith(tail) or name == target) and (kinds is None or obj.objtype in kinds)]


def choose(found, hints):
    """The one of ``found`` sharing the most leading components with a hint (the reference, its module,
    its class), or None when two share as many."""
    if len(found) == 1:
        return found[0]
    best = {}
    for name in found:
        best[name] = max(_shared(name, h) for h in hints if h)
    top = max(best.values(), default=0)
    winners = [n for n, s in best.items() if s == top]
    return winners[0] if len(winners) == 1 and top > 0 else None


def resolve(app, env, node, contnode):
    if node.get("refdomain") != "py" or node.get("reftype") not in ROLES:
        return None
    role = node["reftype"]
    target = node.get("reftarget", "").lstrip(".~")
    if not target:
        return None
    objects = env.get_domain("py").objects
    module, cls = node.get("py:module"), node.get("py:class")
    hints = [target, f"{module}.{cls}" if module and cls else None, module]
    parts = target.split(".")
    name = None
    # The reference's own tail first (``sparse.resample`` -> ``resample`` under the package that
    # exports it), then, for a bare method name, the class of the docstring it is in.
    tails = [".".join(parts[i:]) for i in range(len(parts))]
    if cls and len(parts) == 1:
        tails.insert(0, f"{cls}.{target}")
    for tail in tails:
        name = choose(candidates(objects, tail, role), hints)
        if name is not None:
            break
    if name is None:
        return None
    obj = objects[name]
    return make_refnode(app.builder, node.get("refdoc"), obj.docname, obj.node_id, contnode, name)


def constant_docstring(app, what, name, obj, options, lines):
    """The defining module's docstring of a re-exported constant, never its type's."""
    if what != "data":
        return
    package, _, attr = name.rpartition(".")
    words = " ".join(lines).split()
    if words and words[:6] != (type(obj).__doc__ or "").split()[:6]:
        return  # its own docstring
    lines[:] = []
    # The package's own modules first, then its siblings (``blobby.BLOCK`` is set in ``_blobby_base``).
    near = [m for m in sorted(sys.modules) if m.startswith(package + ".")]
    near += [m for m in sorted(sys.modules) if m.startswith(package.rpartition(".")[0] + ".") and m not in near]
    for modname in near:
        if getattr(sys.modules[modname], attr, lines) is not obj:
            continue
        try:
            docs = ModuleAnalyzer.for_module(modname).find_attr_docs()
        except Exception:  # a compiled or unreadable module: nothing to say
            continue
        if ("", attr) in docs:
            lines.extend(docs[("", attr)])
            return


def setup(app):
    app.connect("missing-reference", resolve)
    app.connect("autodoc-process-docstring", constant_docstring, priority=400)  # before numpydoc (500)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
