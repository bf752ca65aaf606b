"""Bad input exits with code 2 and a clear message before any worker starts; job scripts."""

from pathlib import Path

import pytest

from nephele.farm import cli, cluster

SCENE = Path(__file__).with_name("cube_scene.py")


@pytest.fixture(autouse=True)
def no_cluster(monkeypatch):
    def refuse(**kwargs):
        raise AssertionError("a cluster was started for bad input")

    monkeypatch.setattr(cluster, "open_client", refuse)
    monkeypatch.setattr(cluster, "local_cluster", refuse)


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.blend", "--frames", "1-3"], "no such scene file"),
        (["{bad_blend}", "--frames", "1-3"], "not a Blender file"),
        (["{scene}", "--frames", "5-1"], "end before start"),
        (["{scene}", "--frames", "one-ten"], "cannot read frame range"),
        (["{scene}", "--frames", "1-3", "--engine", "POVRAY"], "unknown engine"),
        (["{scene}", "--frames", "1-3", "--format", "JPEG"], "unknown format"),
        (["{scene}", "--frames", "1-3", "--device", "TPU"], "unknown device"),
        (["{scene}", "--frames", "1-3", "--engine", "BLENDER_WORKBENCH", "--device", "CUDA"], "needs --engine CYCLES"),
        (["{scene}", "--frames", "1-3", "--retries", "-1"], "--retries"),
        (["{scene}", "--frames", "1-3", "--resolution", "wide"], "WxH"),
        (["{no_build}", "--frames", "1-3"], "no build"),
    ],
)
def test_bad_input_exit_2(tmp_path, capsys, args, message):
    bad_blend = tmp_path / "bad.blend"
    bad_blend.write_bytes(b"not a blend file")
    no_build = tmp_path / "nobuild.py"
    no_build.write_text("def main():\n    pass\n")
    args = [a.format(scene=SCENE, bad_blend=bad_blend, no_build=no_build) for a in args]
    rc = cli.main(["render", *args, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and "Traceback" not in err


def test_unwritable_output_dir(tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    rc = cli.main(["render", str(SCENE), "--frames", "1", "--out", str(blocker / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "output directory cannot be written" in err


def test_slurm_job_script(tmp_path, capsys, monkeypatch):
    monkeypatch.undo()  # the dry run starts a scheduler (no worker, no job)
    rc = cli.main(["render", str(SCENE), "--frames", "1-240", "--out", str(tmp_path / "o"), "--slurm",
                   "--queue", "gpu", "--account", "proj42", "--walltime", "02:00:00", "--job-cpus", "16",
                   "--job-mem", "64GB", "--dry-run"])
    out = capsys.readouterr().out
    assert rc == 0
    lines = out.splitlines()
    for want in ("#SBATCH -p gpu", "#SBATCH -A proj42", "#SBATCH -n 1", "#SBATCH --cpus-per-task=16",
                 "#SBATCH --mem=60G", "#SBATCH -t 02:00:00"):
        assert want in lines, want
    cmd = next(line for line in lines if "distributed.cli.dask_worker" in line)
    import sys

    assert cmd.startswith(sys.executable) and "--nthreads 1" in cmd and "--nanny" in cmd
    assert "--nworkers" not in cmd  # one worker process (one bpy) per job
    assert "to render: 1-240" in out
    assert not list((tmp_path / "o").glob("frame_*"))


def test_pbs_job_script(tmp_path, capsys, monkeypatch):
    monkeypatch.undo()
    rc = cli.main(["render", str(SCENE), "--frames", "1-10", "--out", str(tmp_path / "o"), "--pbs",
                   "--queue", "workq", "--account", "proj42", "--job-cpus", "8", "--job-mem", "32GB", "--dry-run"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "#PBS -q workq" in out and "#PBS -A proj42" in out
    assert "#PBS -l select=1:ncpus=8:mem=30GB" in out
    assert "--nthreads 1" in out


def test_bad_job_memory(tmp_path, capsys, monkeypatch):
    monkeypatch.undo()
    rc = cli.main(["render", str(SCENE), "--frames", "1", "--out", str(tmp_path / "o"), "--slurm",
                   "--job-mem", "lots", "--dry-run"])
    assert rc == 2 and "--job-mem" in capsys.readouterr().err


@pytest.mark.parametrize(
    "env, threads",
    [
        ({}, None),
        ({"SLURM_CPUS_PER_TASK": "16"}, 16),
        ({"NCPUS": "8"}, 8),
        ({"PBS_NUM_PPN": "4"}, 4),
        ({"NEPHELE_THREADS": "3", "SLURM_CPUS_PER_TASK": "16"}, 3),
        ({"SLURM_CPUS_PER_TASK": "0", "NCPUS": "bad"}, None),
    ],
)
def test_render_threads_from_the_allocation(monkeypatch, env, threads):
    from nephele.farm.worker import THREAD_VARS, render_threads

    for var in THREAD_VARS:
        monkeypatch.delenv(var, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert render_threads() == threads
