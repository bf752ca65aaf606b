"""Faults on a real Slurm cluster: refused and impossible jobs, an unreachable scheduler, scancel of a
working job, a run killed and resumed, a worker past its wall time.  No frame lost, none half-written."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from slurm_local import only_frames, render_args

from nephele.farm import cli
from nephele.farm.frames import TMP_DIR

FARM = Path(__file__).resolve().parents[1]
SCENE = FARM / "cube_scene.py"
GATED = Path(__file__).resolve().parent / "gated_scene.py"
ROOT = FARM.parents[1]


def _kwargs(slurm, *extra):
    from nephele.farm.cmd_render import cluster_kwargs

    args = cli.build_parser().parse_args(["render", str(SCENE), "--frames", "1", "--out", "unused",
                                          *render_args(slurm, *extra)])
    return cluster_kwargs(args)


def _jobs_with_frames(out):
    """Jobs named in the logs of the frames already in ``out`` (each log starts with '... job N) ...')."""
    import re

    jobs = set()
    for png in out.glob("frame_*.png"):
        log = out / "logs" / f"{png.stem}.log"
        if log.is_file():
            jobs.update(re.findall(r"job (\d+)\)", log.read_text(errors="replace")))
    return jobs


@pytest.fixture
def background():
    """``start(run, gate=None)`` runs ``run()`` in a thread: ``(thread, box)``, its result in ``box["res"]``.

    At teardown, also after a failed assertion, the gate (a file whose presence keeps frames slow) is removed and
    the thread waited for: a failed test's render must not run on into the next test, holding a job there.
    """
    started = []

    def start(run, gate=None):
        box = {}
        t = threading.Thread(target=lambda: box.update(res=run()))
        t.start()
        started.append((t, gate))
        return t, box

    yield start
    for t, gate in started:
        if gate is not None:
            gate.unlink(missing_ok=True)
        t.join(180)


@pytest.mark.parametrize("extra, option, words", [
    (["--queue", "nope"], "--queue", "invalid partition"),
    (["--job-mem", "5000GB"], "--job-mem", "Memory specification can not be satisfied"),
    (["--job-cpus", "64"], "--job-cpus", "PartitionConfig"),  # accepted by sbatch, can never start
    (["--python", "/nonexistent/bin/python"], "--python", "No such file or directory"),
])
def test_job_that_cannot_start_is_a_clear_error(slurm_jobs, tmp_path, capsys, extra, option, words):
    out = tmp_path / "out"
    t0 = time.monotonic()
    rc = cli.main(["render", str(SCENE), "--frames", "1-3", "--out", str(out), *render_args(slurm_jobs, *extra)])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert (len(lines) == 1 and lines[0].startswith("nephele render: error: ") and option in lines[0]
            and words in lines[0])
    assert time.monotonic() - t0 < 30  # no hang: refusals are immediate, a dead job is seen within a second
    assert not list(out.glob("frame_*"))
    assert slurm_jobs.wait_gone()


def test_scheduler_unreachable_from_the_jobs(slurm_jobs, tmp_path, capsys):
    """Jobs told to reach the scheduler at an unroutable address: exit 2 naming it, jobs cancelled."""
    rc = cli.main(["render", str(SCENE), "--frames", "1", "--out", str(tmp_path / "out"),
                   *render_args(slurm_jobs, "--contact-address", "192.0.2.1", "--start-timeout", "6")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "--interface/--contact-address" in err and "tcp://192.0.2.1:" in err and "within 6 s" in err
    assert slurm_jobs.wait_gone()


def test_scancel_of_a_working_job(slurm_jobs, tmp_path, background):
    """scancel of one of two jobs mid-sequence: its frame is retried, a new job is submitted, nothing lost."""
    from nephele.farm.render import render_sequence

    out = tmp_path / "out"

    def run():
        return render_sequence(SCENE, "1-16", out, progress=False, scene_options={"delay": 0.5}, retries=2,
                               **_kwargs(slurm_jobs, "--jobs", "2"))

    t, box = background(run)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:  # 3 frames, and a running job that has rendered one of them
        running = [j for j, st in slurm_jobs.jobs().items() if st == "RUNNING"]
        rendered = [j for j in running if j in _jobs_with_frames(out)]
        if len(list(out.glob("frame_*.png"))) >= 3 and rendered:
            break
        time.sleep(0.05)
    assert len(running) == 2 and rendered
    victim = rendered[0]  # under load the other job's worker may still be starting: it would have no frame
    slurm_jobs.run("scancel", victim)
    t.join(180)
    assert not t.is_alive()
    res = box["res"]
    assert res.ok and res.rendered == list(range(1, 17))
    only_frames(out, range(1, 17))
    assert not (out / TMP_DIR).exists()
    entries = res.manifest["frames"].values()
    assert any(e["attempts"] >= 2 or e.get("recovered") for e in entries)  # the victim's frame went elsewhere
    submitted = slurm_jobs.run("squeue", "-h", "-t", "all", "-n", "nephele", "-o", "%i").split()
    assert len(submitted) >= 3 and max(map(int, submitted)) > max(map(int, running))  # a replacement job
    victim_frames = [e for e in entries if e.get("job") == victim]
    assert victim_frames  # the victim did render before it was cancelled
    log = (out / "logs" / "jobs" / f"nephele-{victim}.err").read_text()
    assert f"JOB {victim} ON" in log and "CANCELLED" in log


def test_resume_after_the_whole_run_was_killed(slurm_jobs, tmp_path):
    """kill -9 of the client (and its scheduler); scancel of the orphaned jobs; the resume renders only what
    is missing."""
    from nephele.farm.render import render_sequence

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "nephele.farm", "render", str(SCENE), "--frames", "1-12", "--out", str(out),
           "--set", "delay=0.3", "--quiet", *render_args(slurm_jobs)]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while len(list(out.glob("frame_*.png"))) < 3 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    # The orphaned worker job would end by itself after its death timeout; a user cancels it at once.
    slurm_jobs.run("scancel", "--name", "nephele")
    assert slurm_jobs.wait_gone()
    done = sorted(int(p.stem[6:]) for p in out.glob("frame_*.png"))
    assert 3 <= len(done) < 12
    res = render_sequence(SCENE, "1-12", out, progress=False, **_kwargs(slurm_jobs))
    assert res.ok and res.skipped == done and sorted(res.rendered) == sorted(set(range(1, 13)) - set(done))
    only_frames(out, range(1, 13))
    m = json.loads((out / "manifest.json").read_text())
    assert sorted(map(int, m["frames"])) == list(range(1, 13))


def test_job_killed_at_its_time_limit_mid_sequence(slurm_jobs, tmp_path, background):
    """Slurm itself ends the only worker job at its time limit mid-sequence; a new job finishes the sequence.

    A real wall time is at least one minute and slurmctld checks limits every 30 s, so waiting for one
    costs 60-90 s.  Instead the running job's limit is cut to what it has already used
    (``scontrol update TimeLimit=0``, as an operator may do): slurmctld's own time-limit check then
    times the job out exactly as at the end of its wall time (state TIMEOUT, reason TimeLimit,
    SIGTERM, SIGKILL after KillWait, "DUE TO TIME LIMIT" in its log), within 30 s.  The worker's
    --lifetime (8 min for 00:10:00) does not retire it first: this is the hard case of a job that
    outlives its margin, e.g. a frame longer than the 20% the lifetime leaves.  Frames are held
    slow (~1 s) until the job is gone, so the kill always lands mid-sequence, then run at full speed.
    """
    from nephele.farm.cluster import worker_lifetime
    from nephele.farm.render import render_sequence

    assert worker_lifetime("00:10:00") == 480
    out = tmp_path / "out"
    gate = tmp_path / "slow"
    gate.touch()
    n = 80  # held slow, the victim could not finish them within the 30 s the kill may take

    def run():
        return render_sequence(GATED, f"1-{n}", out, progress=False, retries=2,
                               scene_options={"gate": str(gate), "slow": 0.3}, **_kwargs(slurm_jobs))

    t, box = background(run, gate)
    deadline = time.monotonic() + 90
    while len(list(out.glob("frame_*.png"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    running = [j for j, st in slurm_jobs.jobs().items() if st == "RUNNING"]
    assert len(running) == 1
    victim = running[0]
    slurm_jobs.run("scontrol", "update", f"JobId={victim}", "TimeLimit=0")
    deadline = time.monotonic() + 60
    while slurm_jobs.jobs().get(victim) == "RUNNING" and time.monotonic() < deadline:
        time.sleep(0.2)
    gate.unlink()
    t.join(120)
    assert not t.is_alive()
    res = box["res"]
    assert res.ok and res.rendered == list(range(1, n + 1))  # each frame once
    only_frames(out, range(1, n + 1))  # whole PNGs only, no temp or partial file
    assert not (out / TMP_DIR).exists()
    state = slurm_jobs.run("squeue", "-h", "-t", "all", "-j", victim, "-o", "%T %r").split()
    assert state == ["TIMEOUT", "TimeLimit"]
    log = (out / "logs" / "jobs" / f"nephele-{victim}.err").read_text()
    assert "DUE TO TIME LIMIT" in log
    by_job = {}
    for f, e in res.manifest["frames"].items():
        by_job.setdefault(e.get("job"), []).append(int(f))
    assert victim in by_job and len(by_job) >= 2  # the victim rendered, then a replacement job
    later = [j for j in by_job if j != victim]
    assert all(int(j) > int(victim) for j in later)
    assert max(by_job[victim]) < n and min(min(by_job[j]) for j in later) > min(by_job[victim])  # killed mid-sequence


@pytest.mark.slow
def test_worker_reaching_its_wall_time_hands_over(slurm_jobs, tmp_path, background):
    """--walltime 00:01:00: the worker retires at 48 s (before Slurm's kill) and a new job finishes the sequence.

    About 70 s (the wall time cannot be shorter than a minute), so it is left out of ``make test``;
    the time-limit kill itself is covered by the test above.
    """
    from nephele.farm.cluster import worker_lifetime
    from nephele.farm.render import render_sequence

    assert worker_lifetime("00:01:00") == 48
    out = tmp_path / "out"
    gate = tmp_path / "slow"
    gate.touch()
    n = 80  # held slow (~1 s each) until the first job has retired: it cannot finish them in 48 s

    def run():
        return render_sequence(GATED, f"1-{n}", out, progress=False, retries=2,
                               scene_options={"gate": str(gate), "slow": 0.3},
                               **_kwargs(slurm_jobs, "--walltime", "00:01:00"))

    t, box = background(run, gate)
    deadline = time.monotonic() + 90
    jobs = {}
    while not jobs and time.monotonic() < deadline:
        jobs = slurm_jobs.jobs()  # (the fixture left none of an earlier test's)
        time.sleep(0.2)
    assert jobs, "no job submitted within 90 s"
    first = min(jobs, key=int)
    while slurm_jobs.jobs().get(first) in ("PENDING", "RUNNING") and time.monotonic() < deadline:
        time.sleep(0.2)
    gate.unlink()
    t.join(120)
    assert not t.is_alive()
    res = box["res"]
    assert res.ok and res.rendered == list(range(1, n + 1))
    only_frames(out, range(1, n + 1))
    jobs = sorted({e["job"] for e in res.manifest["frames"].values()}, key=int)
    assert jobs[0] == first and len(jobs) >= 2  # the sequence outlived the first job
    state = slurm_jobs.run("squeue", "-h", "-t", "all", "-j", first, "-o", "%T").split()
    # It left by itself (dask-jobqueue then cancels the finished job); Slurm did not time it out.
    assert state in (["COMPLETED"], ["CANCELLED"])
    log = (out / "logs" / "jobs" / f"nephele-{first}.err").read_text()
    assert "lifetime" in log
