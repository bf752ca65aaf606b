"""``nephele render/precompute --cluster slurm``: frames rendered by sbatch jobs on a real slurmctld + slurmd."""

import json
import time
from pathlib import Path

import numpy as np
import pytest
from slurm_local import only_frames, render_args

from nephele.farm import cli

FARM = Path(__file__).resolve().parents[1]
SCENE = FARM / "cube_scene.py"


def test_render_sequence_on_slurm_jobs(slurm_jobs, tmp_path, capsys):
    out = tmp_path / "out"
    rc = cli.main(["render", str(SCENE), "--frames", "1-4", "--out", str(out), "--quiet",
                   *render_args(slurm_jobs, "--job-cpus", "2")])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "4/4 frames valid" in err
    only_frames(out, range(1, 5))
    m = json.loads((out / "manifest.json").read_text())
    jobs = {m["frames"][str(f)]["job"] for f in range(1, 5)}
    assert len(jobs) == 1  # one long-lived bpy in one job rendered them all
    assert m["run"]["worker_scene"]["threads"] == 2  # render.threads = the job's CPUs (SLURM_CPUS_PER_TASK)
    job = jobs.pop()
    log = (out / "logs" / "jobs" / f"nephele-{job}.err").read_text()
    assert "Registered to:" in log and "127.0.0.1" in log
    assert f"job {job})" in (out / "logs" / "frame_0003.log").read_text()
    # The frames are the scene's: the cube turns between frames 1 and 4.
    from nephele.farm.post import read_rgba

    a, b = read_rgba(out / "frame_0001.png"), read_rgba(out / "frame_0004.png")
    assert a.shape == (24, 32, 4) and np.abs(a[..., :3] - a[0, 0, :3]).max() > 0.1 and np.abs(a - b).max() > 0.05
    _no_jobs_left(slurm_jobs)


def test_adaptive_scaling_between_min_and_max(slurm_jobs, tmp_path):
    from nephele.farm.cmd_render import parse_adapt
    from nephele.farm.render import render_sequence

    out = tmp_path / "out"
    args = cli.build_parser().parse_args(["render", str(SCENE), "--frames", "1", "--out", str(out),
                                          *render_args(slurm_jobs, "--adapt", "0:2")])
    from nephele.farm.cmd_render import cluster_kwargs

    kwargs = cluster_kwargs(args)
    assert kwargs["jobqueue"]["adapt"] == parse_adapt("0:2") == (0, 2)
    res = render_sequence(SCENE, "1-8", out, progress=False, scene_options={"delay": 0.3}, **kwargs)
    assert res.ok and res.rendered == list(range(1, 9))
    only_frames(out, range(1, 9))
    jobs = {e["job"] for e in res.manifest["frames"].values()}
    assert 1 <= len(jobs) <= 2  # never more than MAX jobs
    _no_jobs_left(slurm_jobs)


def test_precompute_on_slurm(slurm_jobs, tmp_path, capsys):
    from nephele.core.pipeline import tasks
    from nephele.core.pipeline.cache import Cache

    scene = FARM / "contour_scene.py"
    cache = Cache(tmp_path / "cache")
    rc = cli.main(["precompute", str(scene), "--frames", "1-2", "--cache", str(cache.root), "--quiet",
                   *render_args(slurm_jobs)])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "2 computed, 0 already cached" in err
    params = {"kind": "contour", "source": "demo:small", "var": "cloud", "level": 0.15, "hours_per_frame": 6.0,
              "frame_start": 1}
    for f in (1, 2):
        (kind, p), = tasks.plan(params, f)
        assert cache.load(kind, p)["faces"].shape[0] > 100  # a real surface, computed in a Slurm job
    assert list((cache.root / "logs" / "jobs").glob("nephele-*.err"))
    _no_jobs_left(slurm_jobs)


def test_workers_python_option(slurm_jobs, tmp_path, capsys):
    """--python: the jobs run that interpreter (here a wrapper that marks its environment), the frame renders."""
    import sys

    wrapper = tmp_path / "venv-python"
    wrapper.write_text(f"#!/bin/sh\nexport NEPHELE_CACHE=/from/the/wrapper\nexec {sys.executable} \"$@\"\n")
    wrapper.chmod(0o755)
    rc = cli.main(["cluster-check", "--out", str(tmp_path / "check"),
                   *render_args(slurm_jobs, "--python", str(wrapper), "--job-prologue", "export MARK=prologue-ran")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert f"{wrapper} -m distributed.cli.dask_worker" in out  # the job script runs the given Python
    assert "export MARK=prologue-ran" in out
    assert "NEPHELE_CACHE: /from/the/wrapper" in out  # the worker ran inside the wrapper
    assert "SLURM_CPUS_PER_TASK: 1" in out and "render threads: 1" in out and "bpy: 5." in out
    assert "one-frame job: OK" in out
    from nephele.farm.frames import check_image

    assert check_image(tmp_path / "check" / "cluster_check.png") == (32, 24)
    _no_jobs_left(slurm_jobs)


def _no_jobs_left(slurm, timeout=15):
    """The run cancelled its jobs when it closed (they may still be completing)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(state not in ("PENDING", "RUNNING") for state in slurm.jobs().values()):
            return
        time.sleep(0.2)
    pytest.fail(f"jobs left running: {slurm.jobs()}")
