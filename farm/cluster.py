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

from ..core.errors import UsageError

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


def walltime_seconds(walltime):
    """Seconds of a Slurm/PBS wall time ``[D-]HH:MM:SS`` or ``HH:MM``; :class:`UsageError` otherwise."""
    text = str(walltime).strip()
    days, _, clock = text.rpartition("-")
    parts = clock.split(":")
    try:
        if len(parts) not in (2, 3) or (days and not days.isdigit()) or not all(p.isdigit() for p in parts):
            raise ValueError
        h, m, s = (int(v) for v in (parts + ["0"])[:3]) if len(parts) == 2 else (int(v) for v in parts)
    except ValueError:
        raise UsageError(f"--walltime must be [D-]HH:MM:SS or HH:MM, got {walltime!r}") from None
    seconds = (int(days or 0) * 24 + h) * 3600 + m * 60 + s
    if seconds < 60:
        raise UsageError(f"--walltime must be at least one minute (the schedulers count minutes), got {walltime!r}")
    return seconds


def worker_lifetime(walltime):
    """Seconds after which a job's worker retires itself: the wall time less 20% (at most 5 min).

    The worker leaves the scheduler cleanly (its frame goes to another job)
    before Slurm or PBS kill the job at its wall time.
    """
    total = walltime_seconds(walltime)
    return total - min(300, total // 5)


def jobqueue_cluster(system, *, queue=None, account=None, walltime="01:00:00", job_cpus=1, job_mem="4GB",
                     interface=None, security=None, log_dir=None, python=None, prologue=(), contact_host=None):
    """A dask-jobqueue ``SLURMCluster`` or ``PBSCluster`` running one bpy worker per job (not scaled yet).

    Parameters
    ----------
    system : {"slurm", "pbs"}
    queue, account : str, optional
        Slurm partition / PBS queue, and the account (Slurm) or project (PBS).
    walltime : str
        Job wall time ``[D-]HH:MM:SS``; the worker retires itself at :func:`worker_lifetime`.
    job_cpus : int
        CPUs of each job: the render threads of its one bpy.
    job_mem : str
        Memory of each job, requested per node (Slurm ``--mem``).
    interface : str, optional
        Network interface the scheduler listens on and workers use (e.g. ``ib0``).
    security : distributed.security.Security, optional
    log_dir : path, optional
        Where each job's stdout/stderr go (``NAME-JOBID.out/.err``).
    python : str, optional
        The Python the jobs run (default: this one).  It must import ``nephele``
        and ``bpy`` on the compute nodes, at the same path.
    prologue : sequence of str
        Shell lines run in the job before the worker (``module load ...``,
        ``source /path/venv/bin/activate``).
    contact_host : str, optional
        The address jobs use to reach this machine's scheduler when it differs from
        the one it listens on (NAT, several networks).
    """
    if system not in JOBQUEUE:
        raise UsageError(f"unknown job system {system!r}; expected one of {JOBQUEUE}")
    if job_cpus < 1:
        raise UsageError(f"--job-cpus must be >= 1, got {job_cpus}")
    lifetime = worker_lifetime(walltime)
    if python is not None and (not python or any(c.isspace() for c in python)):
        raise UsageError(f"--python must be a path without spaces, got {python!r}")
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
        python=python or sys.executable,
        name="nephele",
        job_name="nephele",  # the job logs are nephele-JOBID.out/.err; `scancel --name nephele` ends them all
        worker_extra_args=["--lifetime", f"{lifetime}s"],
        job_script_prologue=list(prologue or ()),
        # The dashboard stays on this machine (ssh -L to see it); the scheduler port is what jobs need.
        scheduler_options={"dashboard_address": "127.0.0.1:0"},
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
        kwargs["scheduler_options"]["interface"] = interface
    if contact_host:
        port = _free_port()
        scheme = "tls" if security is not None else "tcp"
        kwargs["scheduler_options"].update(port=port, contact_address=f"{scheme}://{contact_host}:{port}")
    if log_dir:
        os.makedirs(log_dir, exist_ok=True)
        kwargs["log_directory"] = str(log_dir)
    if security is not None:
        kwargs.update(security=security, protocol="tls://")
    with _scheduler_config():
        return cls(**kwargs)


def _free_port():
    import socket

    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


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

    The client is not made the process's default Dask scheduler: the farm submits to it by hand,
    and a default client changes ``dask.config``'s scheduler for everything else in the process
    (xarray's writers, the user's own dask arrays) until the last default client closes; with two
    clients closed out of order the setting outlived both ("Requested dask.distributed scheduler but
    no Client active").

    Parameters
    ----------
    workers : int, optional
        Local workers (default :func:`default_workers`).
    scheduler : str, optional
        Address of a running scheduler; nothing is started then.
    security : distributed.security.Security, optional
        TLS settings for ``scheduler`` (or for a jobqueue cluster).
    jobqueue : dict, optional
        Keyword arguments of :func:`jobqueue_cluster` including ``system``, and optionally
        ``adapt=(minimum, maximum)`` (adaptive scaling instead of ``jobs`` fixed jobs) and
        ``start_timeout`` (seconds to wait for the first worker; None or 0: no limit).
        ``jobs`` jobs are submitted; one that ends (``scancel``, wall time, node failure) is
        replaced.
    env : dict, optional
        Extra environment of local worker processes.
    """
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, security=security, timeout="30s", set_as_default=False)
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
        with _jobqueue_client(jobqueue, security, jobs) as client:
            yield client
        return
    cluster = local_cluster(workers, env)
    try:
        client = Client(cluster, set_as_default=False)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


# sbatch/qsub error text -> the option at fault (first match wins; memory before node configuration).
_REFUSALS = (("partition", "--queue"), ("queue", "--queue"), ("account", "--account"), ("memory", "--job-mem"),
             ("time", "--walltime"), ("processor", "--job-cpus"), ("cpu", "--job-cpus"),
             ("node configuration", "--job-cpus/--job-mem"))
# Slurm pending reasons that no amount of waiting resolves -> the option at fault.
_NEVER_STARTS = {"PartitionConfig": "--job-cpus/--job-mem", "PartitionNodeLimit": "--job-cpus/--job-mem",
                 "BadConstraints": "--job-cpus/--job-mem", "PartitionTimeLimit": "--walltime",
                 "InvalidAccount": "--account", "AccountNotAllowed": "--account", "InvalidQOS": "--account",
                 "QOSMaxWallDurationPerJobLimit": "--walltime", "PartitionDown": "--queue",
                 "PartitionInactive": "--queue", "DependencyNeverSatisfied": "--job-prologue"}


@contextlib.contextmanager
def _jobqueue_client(jobqueue, security, jobs):
    import dask
    from distributed import Client

    params = dict(jobqueue)
    system = params.pop("system")
    adapt = params.pop("adapt", None)
    start_timeout = params.pop("start_timeout", None)
    if adapt is not None and not (0 <= adapt[0] <= adapt[1] and adapt[1] >= 1):
        raise UsageError(f"--adapt must be MIN:MAX with 0 <= MIN <= MAX and MAX >= 1, got {adapt[0]}:{adapt[1]}")
    # A job that vanished (scancel, wall time) is dropped after 2 s instead of 15 s, so its replacement comes sooner.
    with dask.config.set({"distributed.deploy.lost-worker-timeout": "2s"}):
        cluster = jobqueue_cluster(system, security=security, **params)
        try:
            client = Client(cluster, set_as_default=False)
            try:
                start_jobs(cluster, client, system, jobs=jobs, adapt=adapt, timeout=start_timeout,
                           log_dir=params.get("log_dir"))
                yield client
            finally:
                client.close()
        finally:
            cluster.close()


def start_jobs(cluster, client, system, *, jobs=1, adapt=None, timeout=None, log_dir=None):
    """Submit the jobs, wait until one worker has joined, then keep the jobs going.

    ``sbatch``/``qsub`` refusing a job, or a job that can never start or ends
    before its worker reaches the scheduler, raise :class:`UsageError` naming
    the option at fault (the CLI exits 2).  Then ``adapt=(minimum, maximum)``
    hands the number of jobs to :meth:`~distributed.deploy.Cluster.adapt`;
    either way a job that ends is resubmitted while its slot is still wanted.
    """
    first = max(1, adapt[0] if adapt else jobs)
    try:
        cluster.sync(_submit, cluster, first)
    except RuntimeError as exc:
        raise UsageError(_refused(system, exc)) from None
    wait_for_worker(cluster, client, system, timeout, log_dir)
    if adapt:
        cluster.adapt(minimum=adapt[0], maximum=adapt[1])
    _keep_jobs(cluster)


async def _submit(cluster, n):
    # What scale(jobs=n) records, but the submission is awaited here so that sbatch's refusal raises here.
    from distributed.core import Status

    while len(cluster.worker_spec) < n:
        cluster.worker_spec.update(cluster.new_worker_spec())
    try:
        await cluster._correct_state()
    except RuntimeError:
        # Forget the refused jobs (never submitted: closing them would fail) and want no others.
        cluster.worker_spec.clear()
        for name, job in list(cluster.workers.items()):
            if job.status == Status.created:
                del cluster.workers[name]
        for job in cluster._created:
            if job.status == Status.created:
                job.status = Status.failed
        raise


def _refused(system, exc):
    text = str(exc)
    stderr = text.split("stderr:", 1)[-1]
    lines = [ln.split("error:", 1)[-1].strip() for ln in stderr.splitlines() if ln.strip()]
    why = "; ".join(lines) or text.strip().splitlines()[0]
    low = why.lower()
    option = next((opt for word, opt in _REFUSALS if word in low), "the job options")
    submit = "sbatch" if system == "slurm" else "qsub"
    return f"{option}: {submit} refused the worker job: {why}"


def _keep_jobs(cluster, interval_ms=1000):
    """Resubmit the jobs whose workers left (scancel, wall time, node failure) while they are still wanted."""
    from distributed.core import Status
    from tornado.ioloop import PeriodicCallback

    def check():
        if cluster.status == Status.running and len(cluster.workers) < len(cluster.worker_spec):
            cluster._correct_state()

    pc = PeriodicCallback(check, interval_ms)
    cluster.periodic_callbacks["nephele-keep-jobs"] = pc  # stopped by cluster.close()
    cluster.loop.add_callback(pc.start)


def job_states(system, job_ids):
    """``{job id: (state, reason)}`` from ``squeue`` (Slurm; finished jobs too while Slurm keeps them); {} for PBS."""
    import subprocess

    if system != "slurm" or not job_ids:
        return {}
    try:
        r = subprocess.run(["squeue", "-h", "-t", "all", "-j", ",".join(job_ids), "-o", "%i|%T|%r"],
                           capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return {}
    out = {}
    for line in r.stdout.splitlines():
        parts = line.strip().split("|")
        if len(parts) == 3:
            out[parts[0]] = (parts[1], parts[2])
    return out


def _log_tail(log_dir, job_id):
    if not log_dir:
        return ""
    for suffix in (".err", ".out"):
        path = os.path.join(log_dir, f"nephele-{job_id}{suffix}")
        with contextlib.suppress(OSError):
            with open(path, errors="replace") as f:
                lines = [ln.strip() for ln in f if ln.strip()]
            if lines:
                return f"; its log {path} ends: {lines[-1]}"
    return ""


def wait_for_worker(cluster, client, system, timeout=None, log_dir=None, poll=0.5):
    """Block until a worker has joined; :class:`UsageError` when no job can deliver one.

    Slurm jobs are watched with ``squeue``: a pending reason that never clears
    (``PartitionConfig``: more CPUs or memory than a node has, ...) or a job
    that ended before its worker connected fail at once; otherwise the wait
    ends after ``timeout`` seconds with the jobs' states.
    """
    import time

    t0 = time.monotonic()
    address = getattr(cluster.scheduler, "contact_address", None) or cluster.scheduler_address
    while True:
        if client.nthreads():
            return
        ids = [job.job_id for job in list(cluster.workers.values()) if getattr(job, "job_id", None)]
        states = job_states(system, ids)
        for jid, (state, reason) in states.items():
            if state == "PENDING" and reason in _NEVER_STARTS:
                raise UsageError(f"{_NEVER_STARTS[reason]}: worker job {jid} can never start: Slurm says {reason} "
                                 "(more CPUs, memory or time than the partition allows, or a bad account/partition)")
        if ids and states and len(states) == len(ids) and all(st not in ("PENDING", "CONFIGURING", "RUNNING")
                                                                for st, _ in states.values()):
            jid = ids[0]
            raise UsageError(f"--python/--job-prologue: worker job {jid} ended ({states[jid][0]}) before its worker "
                             f"reached the scheduler at {address}{_log_tail(log_dir, jid)}")
        waited = time.monotonic() - t0
        if timeout and waited > timeout:
            running = [j for j, (st, _) in states.items() if st == "RUNNING"]
            if running:
                raise UsageError(f"--interface/--contact-address: worker job {running[0]} runs but its worker has not "
                                 f"reached the scheduler at {address} within {timeout:g} s: is that address reachable "
                                 f"from the compute nodes?{_log_tail(log_dir, running[0])}")
            what = ", ".join(f"job {j} {st} ({why})"
                             for j, (st, why) in states.items()) or f"{len(ids)} job(s) submitted"
            raise UsageError(f"--start-timeout: no worker job started within {timeout:g} s: {what}")
        time.sleep(poll)
