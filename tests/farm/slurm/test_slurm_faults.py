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
ROOT = FARM.parents[1]


def _kwargs(slurm, *extra):
    from nephele.farm.cmd_render import cluster_kwargs

    args = cli.build_parser().parse_args(["render", str(SCENE), "--frames", "1", "--out", "unused",
                                          *render_args(slurm, *extra)])
    return cluster_kwargs(args)


def _wait_jobs_gone(slurm, timeout=20):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(st not in ("PENDING", "RUNNING") for st in slurm.jobs().values()):
            return True
        time.sleep(0.2)
    return False


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
    assert len(lines) == 1 and lines[0].startswith("nephele render: error: ") and option in lines[0] and words in lines[0]
    assert time.monotonic() - t0 < 30  # no hang: refusals are immediate, a dead job is seen within a second
    assert not list(out.glob("frame_*"))
    assert _wait_jobs_gone(slurm_jobs)


def test_scheduler_unreachable_from_the_jobs(slurm_jobs, tmp_path, capsys):
    """Jobs told to reach the scheduler at an unroutable address: exit 2 naming it, jobs cancelled."""
    rc = cli.main(["render", str(SCENE), "--frames", "1", "--out", str(tmp_path / "out"),
                   *render_args(slurm_jobs, "--contact-address", "192.0.2.1", "--start-timeout", "6")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "--interface/--contact-address" in err and "tcp://192.0.2.1:" in err and "within 6 s" in err
    assert _wait_jobs_gone(slurm_jobs)


def test_scancel_of_a_working_job(slurm_jobs, tmp_path):
    """scancel of one of two jobs mid-sequence: its frame is retried, a new job is submitted, nothing lost."""
    from nephele.farm.render import render_sequence

    out = tmp_path / "out"
    box = {}

    def run():
        box["res"] = render_sequence(SCENE, "1-16", out, progress=False, scene_options={"delay": 0.5}, retries=2,
                                     **_kwargs(slurm_jobs, "--jobs", "2"))

    t = threading.Thread(target=run)
    t.start()
    deadline = time.monotonic() + 90
    while len(list(out.glob("frame_*.png"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    running = [j for j, st in slurm_jobs.jobs().items() if st == "RUNNING"]
    assert len(running) == 2
    victim = running[0]
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
    """kill -9 of the client (and its scheduler); scancel of the orphaned jobs; the resume renders only what is missing."""
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
    assert _wait_jobs_gone(slurm_jobs)
    done = sorted(int(p.stem[6:]) for p in out.glob("frame_*.png"))
    assert 3 <= len(done) < 12
    res = render_sequence(SCENE, "1-12", out, progress=False, **_kwargs(slurm_jobs))
    assert res.ok and res.skipped == done and sorted(res.rendered) == sorted(set(range(1, 13)) - set(done))
    only_frames(out, range(1, 13))
    m = json.loads((out / "manifest.json").read_text())
    assert sorted(map(int, m["frames"])) == list(range(1, 13))


@pytest.mark.slow
def test_worker_reaching_its_wall_time_hands_over(slurm_jobs, tmp_path):
    """--walltime 00:01:00: the worker retires at 48 s (before Slurm's kill) and a new job finishes the sequence."""
    from nephele.farm.cluster import worker_lifetime
    from nephele.farm.render import render_sequence

    assert worker_lifetime("00:01:00") == 48
    out = tmp_path / "out"
    res = render_sequence(SCENE, "1-24", out, progress=False, scene_options={"delay": 2.5}, retries=2,
                          **_kwargs(slurm_jobs, "--walltime", "00:01:00"))
    assert res.ok and res.rendered == list(range(1, 25))
    only_frames(out, range(1, 25))
    jobs = sorted({e["job"] for e in res.manifest["frames"].values()}, key=int)
    assert len(jobs) >= 2  # the sequence outlived the first job
    log = (out / "logs" / "jobs" / f"nephele-{jobs[0]}.err").read_text()
    assert "lifetime" in log
