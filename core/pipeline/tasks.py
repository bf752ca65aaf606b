"""Running per-frame tasks, with or without the cache, and planning what a frame needs.

Tasks and planners are registered in :mod:`.registry`.  The Blender updater
calls :func:`run_cached` (load or compute and store); the farm calls
:func:`plan` for every object and frame and runs the tasks on Dask workers
before rendering.
"""

from .cache import Cache
from .registry import PLANNERS, TASKS, load_all


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
