"""A real single-node Slurm cluster on this machine, for tests and benchmarks.

Debian's ``slurm-wlm`` and ``munge`` run as root without systemd: ``munged``
with a generated key and its own socket, ``slurmctld`` and ``slurmd`` with a
generated ``slurm.conf`` in a private directory, loopback only, free ports,
one node with this machine's CPUs and memory (``slurmd -C``).  Every daemon is
stopped by the PID in its pid file.  Nothing under ``/etc`` is used or changed.
"""

import contextlib
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

PACKAGES = ("slurm-wlm", "munge")
DAEMONS = ("slurmctld", "slurmd", "munged")
PARTITION = "debug"


class Unavailable(RuntimeError):
    """Slurm cannot run here (not root, no apt, install failed); the message says why."""


def ensure_installed(timeout=600, packages=PACKAGES, commands=(*DAEMONS, "sbatch", "sinfo")):
    """Install ``packages`` (slurm-wlm and munge) with apt-get when a command is missing (needs root)."""
    if all(shutil.which(d) for d in commands):
        return
    if os.geteuid() != 0:
        raise Unavailable(f"{'/'.join(packages)} not installed and installing needs root")
    if not shutil.which("apt-get"):
        raise Unavailable(f"{'/'.join(packages)} not installed and there is no apt-get to install them")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    # One installer at a time (parallel test sessions); apt's own lock is waited for too.
    with open("/tmp/nephele-apt-slurm.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if all(shutil.which(d) for d in commands):
            return
        for cmd in (["apt-get", "update", "-qq"],
                    ["apt-get", "install", "-y", "-qq", "-o", "DPkg::Lock::Timeout=120",
                     "--no-install-recommends", *packages]):
            try:
                r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                raise Unavailable(f"{' '.join(cmd)} took more than {timeout} s") from None
            if r.returncode:
                tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["?"]
                raise Unavailable(f"{' '.join(cmd)} failed: {tail[0]}")
    missing = [d for d in commands if not shutil.which(d)]
    if missing:
        raise Unavailable(f"apt-get installed {packages} but these are still missing: {missing}")


def _free_ports(n):
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _node():
    """``(hostname, cpus, memory MB)`` as slurmd sees this machine."""
    out = subprocess.run(["slurmd", "-C"], capture_output=True, text=True, timeout=30).stdout
    fields = dict(kv.split("=", 1) for kv in out.split() if "=" in kv)
    return socket.gethostname().split(".")[0], int(fields.get("CPUs", os.cpu_count() or 1)), \
        int(fields.get("RealMemory", 1024))


class LocalSlurm:
    """A started cluster: ``conf`` (path of slurm.conf), ``env`` (SLURM_CONF), ``cpus``, ``memory_mb``,
    ``partition``."""

    def __init__(self, root):
        self.root = Path(root)
        self.conf = self.root / "slurm.conf"
        self.env = {"SLURM_CONF": str(self.conf)}
        self.partition = PARTITION
        self.pids = {}
        self.pid_files = {}

    def run(self, *cmd, check=True, timeout=30):
        """Run a Slurm client command against this cluster; returns its stdout."""
        r = subprocess.run(cmd, env={**os.environ, **self.env}, capture_output=True, text=True, timeout=timeout)
        if check and r.returncode:
            raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")
        return r.stdout

    def jobs(self):
        """``{job id: state}`` of the jobs squeue lists."""
        out = self.run("squeue", "-h", "-o", "%i %T")
        return dict(line.split() for line in out.splitlines() if line.strip())

    def cancel_all(self):
        self.run("scancel", "--full", "-p", self.partition, check=False)

    def wait_gone(self, timeout=20):
        """Wait until squeue lists no job, not even one COMPLETING (its processes may still be ending,
        and writing); False after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while self.jobs():
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.2)
        return True

    def start(self, timeout=60):
        ensure_installed()
        root = self.root
        for d in ("state", "spool", "munge"):
            (root / d).mkdir(parents=True, exist_ok=True)
        os.chmod(root, 0o700)
        os.chmod(root / "munge", 0o700)
        key = root / "munge" / "munge.key"
        key.write_bytes(os.urandom(1024))
        os.chmod(key, 0o400)
        sock = root / "munge" / "munge.sock"
        host, self.cpus, self.memory_mb = _node()
        self.host = host
        ctld_port, d_port = _free_ports(2)
        self.conf.write_text(f"""\
ClusterName=nephele
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={d_port}
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket={sock}
SlurmUser=root
SlurmdUser=root
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
KillWait=3
MinJobAge=120
MessageTimeout=10
SlurmdTimeout=60
NodeName={host} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={self.memory_mb} State=UNKNOWN
PartitionName={PARTITION} Nodes={host} Default=YES MaxTime=INFINITE State=UP
""")
        env = {**os.environ, **self.env}
        subprocess.run(["munged", "--force", f"--socket={sock}", f"--key-file={key}",
                        f"--pid-file={root}/munge/munged.pid", f"--log-file={root}/munge/munged.log",
                        f"--seed-file={root}/munge/munged.seed"], env=env, check=True, capture_output=True, timeout=30)
        self._pid("munged", root / "munge" / "munged.pid")
        # -i: ignore any saved state (a fresh directory has none anyway).
        subprocess.run(["slurmctld", "-i", "-f", str(self.conf)], env=env, check=True, capture_output=True, timeout=30)
        self._pid("slurmctld", root / "slurmctld.pid")
        subprocess.run(["slurmd", "-f", str(self.conf)], env=env, check=True, capture_output=True, timeout=30)
        self._pid("slurmd", root / "slurmd.pid")
        deadline = time.monotonic() + timeout
        state = ""
        while time.monotonic() < deadline:
            state = self.run("sinfo", "-h", "-o", "%T", check=False).strip()
            if state == "idle":
                return self
            time.sleep(0.2)
        raise Unavailable(f"the Slurm node is not idle after {timeout} s (sinfo: {state!r}); "
                          f"logs in {root}: {self.log_tail()}")

    def log_tail(self, n=3):
        lines = []
        for name in ("slurmctld.log", "slurmd.log"):
            p = self.root / name
            if p.is_file():
                lines += [f"{name}: {line}" for line in p.read_text(errors="replace").splitlines()[-n:]]
        return " | ".join(lines)

    def _pid(self, name, path, timeout=10):
        self.pid_files[name] = path  # stop() reads it again if it was not readable here
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            # IndexError: the daemon has created its pid file but not written it yet.
            with contextlib.suppress(OSError, ValueError, IndexError):
                self.pids[name] = int(path.read_text().split()[0])
                return
            time.sleep(0.05)
        raise Unavailable(f"{name} wrote no pid file {path}")

    def stop(self, timeout=20):
        """Cancel every job, then stop slurmd, slurmctld and munged by their PIDs (SIGKILL after ``timeout``)."""
        if "slurmctld" in self.pids:
            # Jobs first, while slurmd can still end their steps (KillWait=3 s).
            with contextlib.suppress(Exception):
                self.cancel_all()
                self.wait_gone(timeout)
        for name in DAEMONS:
            pid = self.pids.pop(name, None)
            if pid is None and name in self.pid_files:
                with contextlib.suppress(OSError, ValueError, IndexError):
                    pid = int(self.pid_files[name].read_text().split()[0])
            if pid is None:
                continue
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
            deadline = time.monotonic() + timeout
            while _alive(pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            if _alive(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie of ours counts as gone (daemons fork away, so this is rare).
    with contextlib.suppress(OSError):
        if Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] == "Z":
            return False
    return True


@contextlib.contextmanager
def local_slurm(root):
    """Start a cluster in ``root`` and stop it afterwards (also when starting fails half-way)."""
    cluster = LocalSlurm(root)
    try:
        yield cluster.start()
    finally:
        cluster.stop()


def render_args(slurm, *extra):
    """Options of ``nephele render/precompute`` for this cluster: loopback, 1 CPU and 1.5 GB per job, 10 minutes."""
    return ["--cluster", "slurm", "--queue", slurm.partition, "--interface", "lo", "--job-cpus", "1",
            "--job-mem", "1500MB", "--walltime", "00:10:00", "--start-timeout", "60", *extra]


def only_frames(out, frames):
    """OUT holds exactly these whole PNG frames (no temp, partial or duplicate files), the logs and the manifest."""
    from nephele.farm.frames import check_image, frame_name

    names = {p.name for p in Path(out).iterdir()}
    want = {frame_name(f, "PNG") for f in frames} | {"logs", "manifest.json"}
    # (no pytest assertion rewriting in a helper module: the message says what differs)
    assert names == want, f"in {out}: unexpected {sorted(names - want)}, missing {sorted(want - names)}"
    for f in frames:
        check_image(Path(out) / frame_name(f, "PNG"))
