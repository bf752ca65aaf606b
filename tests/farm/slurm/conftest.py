"""A real single-node Slurm cluster (slurmctld + slurmd + munged) for the whole test session.

It is installed with apt-get when missing (root on Debian) and started once
(see :mod:`slurm_local`); where that is impossible the tests skip with the reason, or,
in a strict run (CI, ``make test-full``), the session stops with that one line.  ``SLURM_CONF`` points every
Slurm command of the session (dask-jobqueue's ``sbatch``/``scancel`` too) at it.  Each test's jobs are
cancelled after it, and gone before the next test, so one test's leftovers never hold the next one's CPUs.
"""

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from slurm_local import LocalSlurm, Unavailable  # noqa: E402


@pytest.fixture(scope="session")
def slurm(tmp_path_factory, strict):
    pytest.importorskip("bpy")
    pytest.importorskip("dask_jobqueue")
    cluster = LocalSlurm(tmp_path_factory.mktemp("slurm"))
    old = os.environ.get("SLURM_CONF")
    try:
        try:
            cluster.start()
        except Unavailable as exc:
            if strict:
                pytest.exit(f"no Slurm cluster here: {exc}", returncode=1)
            pytest.skip(f"no Slurm cluster here: {exc}")
        os.environ["SLURM_CONF"] = str(cluster.conf)
        yield cluster
    finally:
        cluster.stop()
        if old is None:
            os.environ.pop("SLURM_CONF", None)
        else:
            os.environ["SLURM_CONF"] = old


@pytest.fixture
def slurm_jobs(slurm):
    """The session cluster, with every job cancelled after the test and gone from squeue before the next one.

    A job still COMPLETING (KillWait) is listed: a test that takes the queue's first job for its own must
    not see it.
    """
    yield slurm
    slurm.cancel_all()
    assert slurm.wait_gone(30), f"jobs still in the queue 30 s after scancel: {slurm.jobs()}"
