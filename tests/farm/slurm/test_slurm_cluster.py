"""The test cluster itself: a real slurmctld + slurmd that runs batch jobs."""

import time


def test_batch_job_runs_on_the_node(slurm_jobs, tmp_path):
    out = tmp_path / "hello.txt"
    job = slurm_jobs.run("sbatch", "--parsable", "-c", "1", "--mem=100M", "-o", str(out),
                         "--wrap", "echo cpus=$SLURM_CPUS_PER_TASK host=$(hostname -s)").strip()
    deadline = time.monotonic() + 30
    while job in slurm_jobs.jobs() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert out.read_text().split() == ["cpus=1", f"host={slurm_jobs.host}"]
    assert "idle" in slurm_jobs.run("sinfo", "-h", "-o", "%T")
