"""How many threads core work may use on this machine, and a map over them."""

import os
from concurrent.futures import ThreadPoolExecutor


def default_threads():
    """``OMP_NUM_THREADS`` where set (Dask workers set it to 1, since they run
    tasks side by side), else the CPUs this process may use, at most 8."""
    env = os.environ.get("OMP_NUM_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cpus, 8))


def thread_map(fn, items, threads=None):
    """``[fn(x) for x in items]`` on up to ``threads`` threads (default :func:`default_threads`);
    in this thread when one would do.  NumPy releases the GIL in its loops, so array work overlaps."""
    items = list(items)
    n = max(1, min(int(threads or default_threads()), len(items)))
    if n == 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, items))


def split_map(fn, n, threads=None, chunk=1 << 16):
    """``fn(s)`` for the slices ``s`` of ``range(n)`` of ``chunk`` items, on threads: elementwise
    work on whole grids that would otherwise run in one thread between parallel steps.
    Returns the list of results."""
    return thread_map(fn, [slice(s, min(s + chunk, n)) for s in range(0, n, chunk)], threads)
