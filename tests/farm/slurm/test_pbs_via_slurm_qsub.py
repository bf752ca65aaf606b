"""``--cluster pbs`` end to end through Slurm's Torque/PBS compatibility commands (Debian's ``slurm-wlm-torque``).

No PBS server is packaged for this Debian (OpenPBS and Torque are not in bookworm), so the PBS
path runs against the test Slurm cluster: dask-jobqueue's ``PBSCluster`` writes a ``#PBS`` job
script and submits it with ``qsub``, Slurm's ``qsub`` wrapper hands it to ``sbatch``, which reads
the ``#PBS`` lines, and ``qdel`` ends the job.  This proves the farm's PBS side (job script,
``-l select=1:ncpus=N:mem=M`` and walltime as a PBS server reads them, qsub's job id, qdel, a
worker joining and rendering) but not PBS Pro itself: there threads come from ``NCPUS``, which
Slurm does not set (here they come from ``SLURM_CPUS_PER_TASK``), and ``#PBS -o/-e DIR`` job logs
are not honoured by sbatch.
"""

import json
import shutil
import time
from pathlib import Path

import pytest
from slurm_local import Unavailable, ensure_installed, only_frames, render_args

from nephele.farm import cli

SCENE = Path(__file__).resolve().parents[1] / "cube_scene.py"


@pytest.fixture
def torque_wrappers(slurm_jobs):
    try:
        ensure_installed(packages=("slurm-wlm-torque",), commands=("qsub", "qdel", "qstat"))
    except Unavailable as exc:
        pytest.skip(f"no qsub: {exc}")
    qsub = Path(shutil.which("qsub"))
    if b"slurm" not in qsub.read_bytes()[:20000].lower():
        pytest.skip(f"{qsub} is not Slurm's qsub wrapper: it would submit to a real PBS server, not the test cluster")
    return slurm_jobs


def test_render_with_pbs_job_scripts(torque_wrappers, tmp_path, capsys, monkeypatch):
    slurm = torque_wrappers
    # Slurm's qsub ignores the scripts' #PBS -o/-e and writes the job's output where it was submitted.
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    args = ["pbs" if a == "slurm" else a for a in render_args(slurm, "--job-cpus", "2")]
    assert args[:2] == ["--cluster", "pbs"]
    rc = cli.main(["render", str(SCENE), "--frames", "1-3", "--out", str(out), "--quiet", *args])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "3/3 frames valid" in err
    only_frames(out, range(1, 4))
    m = json.loads((out / "manifest.json").read_text())
    job = {m["frames"][str(f)]["job"] for f in (1, 2, 3)}
    assert len(job) == 1
    job = job.pop()
    assert m["run"]["worker_scene"]["threads"] == 2
    # What the scheduler made of the #PBS lines: name, 2 CPUs, 1500MB (1431 MiB), 10 min; then qdel ended it.
    deadline = time.monotonic() + 15
    while True:
        name, state, cpus, mem, limit = slurm.run("squeue", "-h", "-t", "all", "-j", job, "-o",
                                                  "%j %T %C %m %l").split()
        if state not in ("RUNNING", "COMPLETING") or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert (name, cpus, mem, limit) == ("nephele", "2", "1431M", "10:00")
    assert state in ("CANCELLED", "COMPLETED")
