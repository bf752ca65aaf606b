"""How many threads core work may use on this machine."""

import os


def default_threads():
    """``OMP_NUM_THREADS`` where set (Dask workers set it to 1, since they run
    tasks side by side), else the CPUs this process may use, at most 8."""
    env = os.environ.get("OMP_NUM_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cpus, 8))
