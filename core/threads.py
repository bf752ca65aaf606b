"""How many threads core work may use on this machine, and a map over them."""

import os
import threading
from concurrent.futures import ThreadPoolExecutor

_POOLS = {}  # threads -> (pid, executor): kept, since starting threads cost 0.8 ms a map
_LOCK = threading.Lock()
_LOCAL = threading.local()


def default_threads():
    """``OMP_NUM_THREADS`` where set (Dask workers set it to 1, since they run
    tasks side by side), else the CPUs this process may use, at most 8."""
    env = os.environ.get("OMP_NUM_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cpus, 8))


def thread_map(fn, items, threads=None):
    """``[fn(x) for x in items]`` on up to ``threads`` threads (default :func:`default_threads`),
    this one among them; in this thread alone when one would do.  NumPy releases the GIL in its
    loops, so array work overlaps.  The other threads are kept from call to call (starting them
    cost 0.8 ms a call, 0.36 s of a 2.6 s scattering solve); each takes the next item until none
    are left, so an item may share a thread with another, one after the other."""
    items = list(items)
    n = max(1, min(int(threads or default_threads()), len(items)))
    if n == 1:
        return [fn(x) for x in items]
    out, order, lock = [None] * len(items), [iter(range(len(items)))], threading.Lock()

    def drain():
        while True:
            with lock:
                i = next(order[0], None)
            if i is None:
                return
            try:
                out[i] = fn(items[i])
            except BaseException:
                order[0] = iter(())  # (no more items for anyone: the error is raised once all stop)
                raise

    if getattr(_LOCAL, "worker", False):  # a map inside a map: its own threads (a kept pool's
        with ThreadPoolExecutor(n - 1) as pool:  # workers, all waiting on it, could wait forever)
            return _join(pool, n - 1, drain, out)
    return _join(_pool(n - 1), n - 1, drain, out)


def _join(pool, others, drain, out):
    """Run ``drain`` on ``others`` threads of ``pool`` and here, wait for them, raise the first error."""
    futures = [pool.submit(drain) for _ in range(others)]
    try:
        drain()
    finally:
        errors = [f.exception() for f in futures]
    for e in errors:
        if e is not None:
            raise e
    return out


def _pool(n):
    """The kept pool of ``n`` threads of this process (a forked child starts its own)."""
    with _LOCK:
        pid, pool = _POOLS.get(n, (None, None))
        if pid != os.getpid():
            pool = ThreadPoolExecutor(n, thread_name_prefix=f"nephele-map{n}", initializer=_worker)
            _POOLS[n] = (os.getpid(), pool)
        return pool


def _worker():
    _LOCAL.worker = True


def split_map(fn, n, threads=None, chunk=1 << 16):
    """``fn(s)`` for the slices ``s`` of ``range(n)`` of ``chunk`` items, on threads: elementwise
    work on whole grids that would otherwise run in one thread between parallel steps.
    Returns the list of results."""
    return thread_map(fn, [slice(s, min(s + chunk, n)) for s in range(0, n, chunk)], threads)
