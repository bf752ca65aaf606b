"""Running per-frame tasks, with or without the cache, and planning what a frame needs.

Tasks and planners are registered in :mod:`.registry`, by the modules the
table of object kinds (:data:`.kinds.KINDS`) names.  Both sides plan through
:func:`plan`: the add-on's updaters for the frame shown (then
:func:`run_cached`: load, or compute and store), the farm for every object
and frame, running the tasks on Dask workers before rendering.
"""

import importlib

from .cache import Cache
from .kinds import KINDS, TASK_MODULES
from .registry import PLANNERS, TASKS


def load_all():
    """Import the core modules that register tasks (:data:`.kinds.TASK_MODULES`; a missing one is an error)."""
    for name in TASK_MODULES:
        importlib.import_module(f"..{name}", __package__)


def _lookup(kind):
    if kind not in TASKS:
        load_all()
    try:
        return TASKS[kind]
    except KeyError:
        raise KeyError(f"no task registered for kind {kind!r} (known: {sorted(TASKS)})") from None


def run(kind, params):
    """Compute task ``kind`` without any cache."""
    return _lookup(kind)(params)


def run_cached(kind, params, cache=None):
    """Load task ``kind`` for ``params`` from ``cache``, or compute it and store it there.

    ``cache`` is a :class:`~nephele.core.pipeline.cache.Cache`, a directory path, or None (no caching).
    """
    if cache is None:
        return run(kind, params)
    if not isinstance(cache, Cache):
        cache = Cache(cache)
    hit = cache.load(kind, params)
    if hit is not None:
        return hit
    out = run(kind, params)
    cache.store(kind, params, out)
    return out


def plan(obj_params, frame):
    """The ``(kind, task_params)`` list a scene object with ``obj_params`` needs at ``frame``.

    Empty for an object kind without tasks (or one this version does not know);
    a task kind its row of :data:`.kinds.KINDS` does not list is an error.
    """
    row = KINDS.get(obj_params.get("kind"))
    if row is None or not row.tasks:
        return []
    if obj_params["kind"] not in PLANNERS:
        importlib.import_module(f"..{row.module}", __package__)
    out = list(PLANNERS[obj_params["kind"]](obj_params, frame))
    stray = sorted({kind for kind, _ in out} - set(row.tasks))
    if stray:
        raise KeyError(f"the planner of {obj_params['kind']!r} returned task kinds {stray}, "
                       f"not in its row of KINDS {row.tasks}")
    return out
