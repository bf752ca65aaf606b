"""The registry of per-frame tasks and planners, and the code stamps that key their cache entries.

A feature registers

* a **task**, ``@task("contour")`` on ``fn(params) -> dict[str, ndarray]``: the
  heavy work for one frame, fully determined by ``params`` (JSON-serialisable);
* optionally a **planner**, ``@planner("contour")`` on
  ``fn(obj_params, frame) -> list[(kind, task_params)]``: given the parameters
  a scene object stores (``obj["nephele"]``, see :mod:`nephele.addon.frame`)
  and a frame number, the tasks that frame needs.

The cache (:mod:`.cache`) keys entries with :func:`code_stamp`; running tasks
(:mod:`.tasks`) uses both, so neither imports the other's user.
"""

import importlib
import sys

from .codehash import code_stamp as _file_stamp

TASKS = {}
PLANNERS = {}

# The one list of core modules (under nephele.core) that register tasks when imported (a missing one is an error).
TASK_MODULES = ("surface.contour_task", "volume.volume_task", "flow.advect_task", "light.scatter_task", "muscle.film")


def task(kind):
    """Decorator registering ``fn(params) -> dict of arrays`` as the task ``kind``."""

    def deco(fn):
        TASKS[kind] = fn
        return fn

    return deco


def code_stamp(kind):
    """Hash of the code task ``kind`` depends on (its module and every core module it
    imports, transitively; :mod:`.codehash`), part of its cache key; ``""`` for a kind
    no module registers (e.g. a test's own cache entries)."""
    if kind not in TASKS:
        load_all()
    fn = TASKS.get(kind)
    mod = sys.modules.get(getattr(fn, "__module__", None) or "")
    path = getattr(mod, "__file__", None)
    return _file_stamp(path) if path else ""


def planner(kind):
    """Decorator registering ``fn(obj_params, frame) -> [(kind, task_params), ...]`` for objects of ``kind``."""

    def deco(fn):
        PLANNERS[kind] = fn
        return fn

    return deco


def load_all():
    """Import the core modules that register tasks."""
    for name in TASK_MODULES:
        importlib.import_module(f"..{name}", __package__)
