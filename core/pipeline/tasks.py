"""Registry of pure-NumPy per-frame tasks, so the farm can precompute what a scene needs.

A feature registers

* a **task**, ``@task("contour")`` on ``fn(params) -> dict[str, ndarray]``: the
  heavy work for one frame, fully determined by ``params`` (JSON-serialisable);
* optionally a **planner**, ``@planner("contour")`` on
  ``fn(obj_params, frame) -> list[(kind, task_params)]``: given the parameters
  a scene object stores (``obj["nephele"]``, see :mod:`nephele.addon.frame`)
  and a frame number, the tasks that frame needs.

The Blender updater calls :func:`run_cached` (load or compute and store); the
farm calls :func:`plan` for every object and frame and runs the tasks on Dask
workers before rendering.
"""

import importlib
import sys

from .cache import Cache
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
    """The ``(kind, task_params)`` list a scene object with ``obj_params`` needs at ``frame``."""
    kind = obj_params.get("kind")
    if kind not in PLANNERS:
        load_all()
    fn = PLANNERS.get(kind)
    return [] if fn is None else list(fn(obj_params, frame))
