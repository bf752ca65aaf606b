"""Where the frames render: a local Dask cluster, a running scheduler, or Slurm/PBS jobs.

* **Local** (default): :class:`distributed.LocalCluster` with worker
  *processes*, one thread each (one bpy per process), scheduler and dashboard
  bound to 127.0.0.1 only.  Each worker renders with ``cpu_count // workers``
  threads (``NEPHELE_THREADS``).
* **Running scheduler**: ``scheduler="tls://host:8786"`` with an optional
  :class:`distributed.security.Security` (CA, certificate, key).  The workers
  must run in an environment where ``nephele`` and ``bpy`` import (the same
  venv, ``pip install -e .``).
* **Slurm / PBS** through dask-jobqueue: one job = one Dask worker = one bpy
  (``cores=1, processes=1``) that owns ``job_cpus`` CPUs (render threads are
  read from ``SLURM_CPUS_PER_TASK`` / ``NCPUS`` in the job) and ``job_mem``
  memory per node (Slurm's ``--mem``, not per CPU: a per-core limit kills
  Blender).

The scheduler runs in the client process for local and jobqueue clusters; it
is configured with ``allowed-failures = 0`` so that a worker death (a crash,
``kill -9``, a frame timeout) fails the task at once and the client's own
retry limit counts it.
"""

import contextlib
import logging
import os
import sys

from .cli import UsageError

JOBQUEUE = ("slurm", "pbs")


def security(ca_file=None, cert=None, key=None):
    """A :class:`distributed.security.Security` for TLS, or None when no file is given."""
    if not (ca_file or cert or key):
        return None
    for label, path in (("--tls-ca-file", ca_file), ("--tls-cert", cert), ("--tls-key", key)):
        if path and not os.path.isfile(path):
            raise UsageError(f"{label}: no such file {path}")
    if not (ca_file and cert):
        raise UsageError("TLS needs at least --tls-ca-file and --tls-cert")
    from distributed.security import Security

    return Security(
        tls_ca_file=ca_file,
        tls_client_cert=cert,
        tls_client_key=key,
        require_encryption=True,
    )


def default_workers():
    """One local worker per 8 cores (at least 1, at most 4).

    Cycles uses every thread it is given; a second worker only pays off when
    there are enough cores for its single-threaded parts (scene sync, file
    output) to overlap.  On 2 cores, 2 workers of 1 thread were ~20% slower
    per frame than 1 worker of 2 threads (docs/benchmarks.md, farm).
    """
    return max(1, min(4, (os.cpu_count() or 1) // 8))


def jobqueue_cluster(system, *, queue=None, account=None, walltime="01:00:00", job_cpus=1, job_mem="4GB",
                     interface=None, security=None, log_dir=None):
    """A dask-jobqueue ``SLURMCluster`` or ``PBSCluster`` running one bpy worker per job (not scaled yet)."""
    if system not in JOBQUEUE:
        raise UsageError(f"unknown job system {system!r}; expected one of {JOBQUEUE}")
    if job_cpus < 1:
        raise UsageError(f"--job-cpus must be >= 1, got {job_cpus}")
    import dask_jobqueue
    from dask.utils import parse_bytes

    try:
        parse_bytes(job_mem)
    except (ValueError, TypeError):
        raise UsageError(f"--job-mem must be a size like 32GB, got {job_mem!r}") from None

    cls = dask_jobqueue.SLURMCluster if system == "slurm" else dask_jobqueue.PBSCluster
    kwargs = dict(
        cores=1,
        processes=1,
        memory=job_mem,
        walltime=walltime,
        python=sys.executable,
        name="nephele",
    )
    if system == "slurm":
        kwargs["job_cpu"] = job_cpus
    else:  # PBS Pro: one chunk with all the job's CPUs and its memory
        from dask_jobqueue.pbs import pbs_format_bytes_ceil

        kwargs["resource_spec"] = f"select=1:ncpus={job_cpus}:mem={pbs_format_bytes_ceil(parse_bytes(job_mem))}"
    if queue:
        kwargs["queue"] = queue
    if account:
        kwargs["account"] = account
    if interface:
        kwargs["interface"] = interface
    if log_dir:
        kwargs["log_directory"] = str(log_dir)
    if security is not None:
        kwargs.update(security=security, protocol="tls://")
    with _scheduler_config():
        return cls(**kwargs)


@contextlib.contextmanager
def _scheduler_config():
    import dask

    # allowed-failures 0: a worker death fails its task at once, the client's --retries count it.
    # No pre-spawn environment (MALLOC_TRIM_THRESHOLD_, OMP_NUM_THREADS=1): bpy runs as in Blender.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.nanny.pre-spawn-environ": {}}):
        yield


def local_cluster(workers=None, env=None):
    """A :class:`distributed.LocalCluster` of bpy-ready worker processes on 127.0.0.1 only."""
    from distributed import LocalCluster

    n = workers or default_workers()
    threads = max(1, (os.cpu_count() or 1) // n)
    with _scheduler_config():
        return LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            # Also without bokeh the scheduler serves HTTP (health, metrics): keep it local too.
            dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
            env={"NEPHELE_THREADS": str(threads), **(env or {})},
        )


@contextlib.contextmanager
def open_client(*, workers=None, scheduler=None, security=None, jobqueue=None, jobs=1, env=None):
    """Yield a :class:`distributed.Client` on the chosen cluster; closes what it started.

    Parameters
    ----------
    workers : int, optional
        Local workers (default :func:`default_workers`).
    scheduler : str, optional
        Address of a running scheduler; nothing is started then.
    security : distributed.security.Security, optional
        TLS settings for ``scheduler`` (or for a jobqueue cluster).
    jobqueue : dict, optional
        Keyword arguments of :func:`jobqueue_cluster` including ``system``; ``jobs`` jobs are submitted.
    env : dict, optional
        Extra environment of local worker processes.
    """
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, security=security, timeout="30s")
        except (OSError, TimeoutError, TypeError, ValueError) as exc:
            from ..core.errors import DataError

            hint = " (a tls:// scheduler needs --tls-ca-file, --tls-cert and --tls-key)" if "TLS" in str(exc) else ""
            raise DataError(f"cannot connect to the Dask scheduler: {exc}{hint}", path=scheduler,
                            field="--scheduler") from None
        try:
            yield client
        finally:
            client.close()
        return
    if jobqueue:
        params = dict(jobqueue)
        cluster = jobqueue_cluster(params.pop("system"), security=security, **params)
        cluster.scale(jobs=jobs)
    else:
        cluster = local_cluster(workers, env)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()
