"""The one table of object kinds (core/pipeline/kinds.py) matches what registers where.

Each row's core module registers the planner of the kind and every task kind the row
lists; each row's add-on module registers the kind's frame updater (read from the
add-on's source with ``ast``: no Blender needed); the add-on names no task kind of
its own (it plans through ``tasks.plan``).
"""

import ast
from pathlib import Path

import pytest

from nephele.core.pipeline import registry, tasks
from nephele.core.pipeline.kinds import KINDS, TASK_MODULES

ADDON = Path(registry.__file__).resolve().parents[2] / "addon"


def test_every_task_module_registers_its_rows():
    tasks.load_all()
    for kind, row in KINDS.items():
        if not row.tasks:
            assert not row.module and kind not in registry.PLANNERS
            continue
        assert registry.PLANNERS[kind].__module__.endswith(f"core.{row.module}"), kind
        for t in row.tasks:
            assert registry.TASKS[t].__module__.endswith(f"core.{row.module}"), t
    listed = {t for row in KINDS.values() for t in row.tasks}
    assert listed == set(registry.TASKS), "every registered task kind has its row"
    assert set(TASK_MODULES) == {row.module for row in KINDS.values() if row.module}


def _constants(tree):
    """Module-level ``NAME = "constant"`` assignments of a parsed module."""
    return {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
            for t in n.targets if isinstance(t, ast.Name) and isinstance(n.value, ast.Constant)}


def _registered_updaters():
    """``kind -> add-on module`` of every ``register_job(kind, ...)`` and ``register_updater(kind)`` call."""
    out = {}
    for path in sorted(ADDON.glob("*.py")):
        tree = ast.parse(path.read_bytes())
        # sibling modules imported as names (``from . import scatter_scene as ss``), for ``ss.KIND``
        siblings = {a.asname or a.name: a.name for n in tree.body if isinstance(n, ast.ImportFrom)
                    and n.level == 1 and n.module is None for a in n.names}
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) in (
                    "register_job", "register_updater") and path.stem != "frame":
                arg = node.args[0]
                if isinstance(arg, ast.Constant):
                    kind = arg.value
                elif isinstance(arg, ast.Attribute):
                    kind = _constants(ast.parse((ADDON / f"{siblings[arg.value.id]}.py").read_bytes()))[arg.attr]
                else:
                    kind = _constants(tree)[arg.id]
                assert kind not in out, f"{kind} registered by {out.get(kind)} and {path.stem}"
                out[kind] = path.stem
    return out


def test_every_updater_is_where_the_table_says():
    assert _registered_updaters() == {kind: row.updater for kind, row in KINDS.items() if row.updater}


def test_the_addon_names_no_task_kind():
    task_only = {t for row in KINDS.values() for t in row.tasks} - set(KINDS)
    assert task_only >= {"advect_contour", "muscle_frame"}
    found = [f"{path.name}:{node.lineno} {node.value!r}" for path in sorted(ADDON.glob("*.py"))
             for node in ast.walk(ast.parse(path.read_bytes()))
             if isinstance(node, ast.Constant) and node.value in task_only]
    assert not found, found


def test_plan_refuses_a_task_kind_outside_the_row(monkeypatch):
    tasks.load_all()
    monkeypatch.setitem(registry.PLANNERS, "contour", lambda p, f: [("advect_contour", {})])
    with pytest.raises(KeyError, match="not in its row"):
        tasks.plan({"kind": "contour"}, 1)
    assert tasks.plan({"kind": "splats"}, 1) == [] and tasks.plan({"kind": "from a newer version"}, 1) == []
