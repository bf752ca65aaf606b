"""The layer rules, read from the code's own imports (``ast``, nothing imported).

Imports point down only: ``farm`` → ``addon`` → ``fileio`` / ``volume_files`` → ``core``
(docs/architecture.md).  Only the add-on imports Blender at module level; the two
places that need Blender's bundled modules or a render import it inside a function.
An algorithm module never imports a task module, and no two modules import each other,
directly or round a longer circle.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "nephele"
LAYERS = ("core", "fileio", "volume_files", "addon", "farm")
BLENDER = {"bpy", "mathutils", "bpy_extras", "bl_ui", "bl_operators", "gpu", "blf"}
# Where Blender may be imported inside a function: the bundled OpenImageIO/OpenVDB, and the farm's workers.
LAZY_BLENDER = {"nephele.fileio", "nephele.farm.worker"}


def _module_name(path):
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([PACKAGE, *parts])


def _sources():
    files = [ROOT / "__init__.py", ROOT / "fileio.py", ROOT / "volume_files.py"]
    for top in ("core", "addon", "farm"):
        files += sorted((ROOT / top).rglob("*.py"))
    return {_module_name(f): f for f in files}


MODULES = _sources()


def _is_package(name):
    return MODULES[name].name == "__init__.py"


def _resolve(name, node):
    """Absolute names an import node names (a ``from`` import's names when they are modules)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = name.split(".") if _is_package(name) else name.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module
    subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
    return subs or [target]


def _imports(name):
    """``[(imported name, lazy)]`` of module ``name``; lazy: inside a function body."""
    tree = ast.parse(MODULES[name].read_bytes(), filename=str(MODULES[name]))
    out = []

    def visit(node, lazy):
        for child in ast.iter_child_nodes(node):
            inner = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                out.extend((target, lazy) for target in _resolve(name, child))
            visit(child, inner)

    visit(tree, False)
    return out


IMPORTS = {name: _imports(name) for name in MODULES}


def _layer(name):
    parts = name.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def _internal(target):
    """The module of ours ``target`` names (a name inside a module counts as that module), or None."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def _constant(name, variable):
    """The literal value of module ``name``'s top-level ``variable``."""
    tree = ast.parse(MODULES[name].read_bytes())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == variable for t in node.targets):
            return ast.literal_eval(node.value)
    raise KeyError(f"{name} has no {variable}")


def _registry_edges():
    """What the three registries import by name (``importlib``, invisible to ``ast``): the farm's
    commands, the add-on's modules and the core modules the table of kinds names."""
    from nephele.core.pipeline.kinds import TASK_MODULES

    return {
        f"{PACKAGE}.farm.cli": [f"{PACKAGE}.farm.cmd_{c}" for c in _constant(f"{PACKAGE}.farm.cli", "COMMANDS")],
        f"{PACKAGE}.addon": [f"{PACKAGE}.addon.{m}" for m in _constant(f"{PACKAGE}.addon", "MODULES")],
        f"{PACKAGE}.core.pipeline.tasks": [f"{PACKAGE}.core.{m}" for m in TASK_MODULES],
    }


def _edges(lazy_too=True):
    out = {name: {_internal(t) for t, lazy in IMPORTS[name] if (lazy_too or not lazy) and _internal(t)}
           for name in MODULES}
    if lazy_too:
        for name, targets in _registry_edges().items():
            assert set(targets) <= set(MODULES), set(targets) - set(MODULES)
            out[name] |= set(targets)
    return {name: sorted(targets) for name, targets in out.items()}


def test_the_tree_is_read():
    assert len(MODULES) > 100 and {"nephele.core.pipeline.tasks", "nephele.addon.frame", "nephele.farm.cli"} <= set(
        MODULES
    )
    assert ("nephele.core.pipeline.cache", False) in IMPORTS["nephele.core.pipeline.tasks"]


BELOW = {"core": set(), "fileio": {"core"}, "volume_files": {"core", "fileio"},
         "addon": {"core", "fileio", "volume_files"}, "farm": {"core", "fileio", "volume_files", "addon"}}


@pytest.mark.parametrize("layer", LAYERS)
def test_imports_point_down(layer):
    bad = [f"{name} imports {target}" for name in MODULES if _layer(name) == layer
           for target in _edges()[name] if _layer(target) not in BELOW[layer] | {layer, None}]
    assert not bad, bad


def test_only_the_addon_imports_blender():
    bad = []
    for name, imports in IMPORTS.items():
        for target, lazy in imports:
            if target.split(".")[0] in BLENDER and _layer(name) != "addon" and not (lazy and name in LAZY_BLENDER):
                bad.append(f"{name} imports {target}" + (" (in a function)" if lazy else ""))
    assert not bad, bad


def test_no_algorithm_module_imports_a_task_module():
    from nephele.core.pipeline.kinds import TASK_MODULES

    tasks = {f"{PACKAGE}.core.{m}" for m in TASK_MODULES} | {n for n in MODULES if n.endswith("_task")}
    # (a domain's ``__init__`` is its namespace, re-exporting the task modules' public names too)
    algorithms = [n for n in MODULES if _layer(n) == "core" and n not in tasks and ".pipeline" not in n
                  and not _is_package(n)]
    bad = [f"{n} imports {t}" for n in algorithms for t in _edges()[n] if t in tasks]
    assert not bad, bad


def _cycles(edges):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def test_cycle_finder_finds_a_circle():
    assert _cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) == [["a", "b", "c"]]


@pytest.mark.parametrize("lazy_too", [False, True], ids=["module level", "with imports in functions"])
def test_no_import_cycles(lazy_too):
    """No module imports one that imports it back, directly or round a longer circle
    (with imports in functions, what the registries import by name counts too).

    A package's ``__init__`` that re-exports its modules is the one allowed hub: an edge
    from a module to its own package's ``__init__`` (the package is imported first anyway)
    is not an import of something above it.
    """
    edges = {n: [t for t in ts if not n.startswith(t + ".")] for n, ts in _edges(lazy_too).items()}
    assert not _cycles(edges), _cycles(edges)
