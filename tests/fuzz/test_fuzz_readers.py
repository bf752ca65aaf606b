"""Every reader, fed mutated and truncated real files: only DataError may escape, within 10 s and 2 GiB.

The quick tier runs 12 cases per reader and every seed unmutated (about 100 in all), the full tier
(``-m slow``) 150 per reader; both are derandomized, so CI sees the same
cases each run.  ``make fuzz N=100000`` runs the long random campaign
(``tests/fuzz/run.py``).
"""

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fuzzlib import BAD, ROOT, Runner, build_seeds, describe, ops_strategy  # noqa: E402

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

READERS = ("netcdf", "grib", "zarr", "grads", "relief", "pqr", "vtu")
QUICK, FULL = 12, 150


@pytest.fixture(scope="module")
def runner():
    r = Runner()
    yield r
    r.close()


@pytest.fixture(scope="module")
def seeds(shared_data, tmp_path_factory):
    return build_seeds([ROOT / "tests" / "data", shared_data], tmp_path_factory.mktemp("seeds"))


def _fuzz(seeds, runner, reader, n):
    mine = [s for s in seeds if s.target == reader]
    if not mine:
        pytest.skip(f"no seed file for the {reader} reader (its library or data is missing)")
    counts = {}

    @settings(max_examples=n, derandomize=True, database=None, deadline=None, phases=(Phase.explicit, Phase.generate),
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def case(data):
        seed = data.draw(st.sampled_from(mine))
        pick = seed.text if seed.text and data.draw(st.booleans()) else seed.mutable
        mutated = data.draw(st.sampled_from(pick))
        ops = data.draw(ops_strategy(text=mutated in seed.text))
        out = runner.run(seed, mutated, ops)
        counts[out["status"]] = counts.get(out["status"], 0) + 1
        assert out["status"] not in BAD, describe(seed, mutated, ops, out)

    case()
    assert sum(counts.values()) >= n // 2, counts  # the cases really ran
    return counts


@pytest.mark.parametrize("reader", READERS)
def test_fuzz_quick(seeds, runner, reader):
    _fuzz(seeds, runner, reader, QUICK)


@pytest.mark.slow
@pytest.mark.parametrize("reader", READERS)
def test_fuzz_full(seeds, runner, reader):
    _fuzz(seeds, runner, reader, int(os.environ.get("NEPHELE_FUZZ_CASES", FULL)))


# Seeds that hold no 3-D field (2-D relief or satellite images, one-level GRIB samples): each is
# refused in one DataError line, unmutated.
NO_3D = {"orog_mod1_rectilinear_grid_2D.nc", "toa_brightness_stereographic.nc", "polar_stereo.grib2",
         "lambert_grid.grib", "reduced_gg.grib", "regular_gg_ml.grib", "t_on_different_level_types.grib"}


def test_unmutated_seeds_read(seeds, runner):
    """The seeds themselves read (or give their one known DataError): a harness that failed every case would pass."""
    outcomes = {s.name: runner.run(s)["status"] for s in seeds}
    assert {"grib", "netcdf", "grads", "relief", "pqr", "vtu"} <= {s.target for s in seeds}
    assert {n: v for n, v in outcomes.items() if v != "ok"} == {n: "data_error" for n in NO_3D if n in outcomes}
    assert all(any(outcomes[s.name] == "ok" for s in seeds if s.target == t) for t in {s.target for s in seeds})


def test_the_harness_sees_hangs_crashes_and_memory(tmp_path):
    """A case past the time limit, one that kills its worker and one past the memory limit are all findings."""
    from fuzzlib import Seed

    r = Runner(timeout=1.0)
    try:
        for text, status in ((b"spin", "hang"), (b"crash", "crash"), (b"allocate", "memory"), (b"fine", "ok")):
            seed = Seed("selftest", "x", {"x.txt": text}, "x.txt", ("x.txt",))
            assert r.run(seed)["status"] == status, text
    finally:
        r.close()
