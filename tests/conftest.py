"""Shared fixtures (the real files the project carries) and the strict mode of CI.

Strict mode (``CI`` set, as CI runs, or ``NEPHELE_STRICT=1``, as every ``make`` test target
sets): a test that would skip fails instead, with one line saying what is missing, so a broken
environment (no bpy, no compiled kernels, no Slurm, no trimesh) cannot pass green.  The only
skips left are the ones this machine truly cannot run: tests marked ``gpu``, and modules a tier
lacks by design, named in ``NEPHELE_OPTIONAL`` (the Python 3.11 tier has no bpy).
"""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
STRICT = os.environ.get("CI", "").lower() not in ("", "0", "false") or os.environ.get("NEPHELE_STRICT") == "1"
OPTIONAL = {m for m in os.environ.get("NEPHELE_OPTIONAL", "").split(",") if m}


def _one_blas_thread():
    """OpenBLAS on one thread, in this process and the ones it starts.

    The tests' matrices are small (least-squares Jacobians of 3000 x 40, 3 x 3 frames): a second
    OpenBLAS thread only spins, and on a loaded 2-core machine it made an SVD of 3000 x 40 cost
    0.086 CPU s instead of 0.004 (the actin fits' two tests: 27 CPU s, 14 with one thread).  Results
    are the same (each output element is summed the same way in one thread).  NumPy is already
    loaded by a plugin (zarr's) when this file runs, so the variable alone is too late here: the
    loaded libraries are told through their own ``*set_num_threads*`` (Linux: found in
    /proc/self/maps; elsewhere only the variable, for child processes).
    """
    import ctypes

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return
    libs = {line.split()[-1] for line in maps.splitlines() if "openblas" in line.rsplit("/", 1)[-1]}
    for lib in sorted(libs):
        try:
            dll = ctypes.CDLL(lib)
        except OSError:
            continue
        for name in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                     "openblas_set_num_threads64_", "openblas_set_num_threads"):
            if hasattr(dll, name):
                getattr(dll, name)(int(os.environ["OPENBLAS_NUM_THREADS"]))
                break


_one_blas_thread()


@pytest.fixture(scope="session")
def strict():
    """Whether this run is strict (see the module's docstring)."""
    return STRICT


@pytest.fixture(scope="session")
def shared_data():
    """``tests/data``: the real files (from Debian packages) described in its README."""
    return DATA


@pytest.fixture
def own_cache(tmp_path_factory, monkeypatch):
    """A Nephele cache of the test's own (``NEPHELE_CACHE``): GRIB indexes, unpacked zips."""
    cache = tmp_path_factory.mktemp("nephele-cache")
    monkeypatch.setenv("NEPHELE_CACHE", str(cache))
    return cache


@pytest.fixture(scope="session")
def grib_samples():
    """The folder of real GRIB products (``tests/data/fetch_grib_samples.py``, fetched once into build/)."""
    pytest.importorskip("eccodes")
    import importlib.util

    spec = importlib.util.spec_from_file_location("fetch_grib_samples",
                                                  ROOT / "tests" / "data" / "fetch_grib_samples.py")
    fetch = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fetch)
    try:
        return fetch.ensure()
    except Exception as exc:  # noqa: BLE001 - offline: say why these tests did not run
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        pytest.skip(f"real GRIB samples not available ({type(exc).__name__}: {first}); "
                    "run 'python tests/data/fetch_grib_samples.py' once with network access")


def pytest_collection_modifyitems(items):
    # Everything under tests/addon and tests/farm needs bpy.
    for item in items:
        parts = Path(str(item.fspath)).parts
        if "addon" in parts or "farm" in parts:
            item.add_marker(pytest.mark.bpy)


def _reason(report):
    longrepr = report.longrepr
    return longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)


def _allowed(reason):
    """A skip for a module the tier lacks by design (``NEPHELE_OPTIONAL``)."""
    return any(f"could not import '{m}'" in reason for m in OPTIONAL)


def _fail_skip(report, what):
    reason = _reason(report).removeprefix("Skipped: ")
    report.outcome = "failed"
    report.longrepr = f"{what} would skip in a strict run (CI / NEPHELE_STRICT=1): {reason}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if (STRICT and report.skipped and not hasattr(report, "wasxfail")
            and item.get_closest_marker("gpu") is None and not _allowed(_reason(report))):
        _fail_skip(report, item.nodeid)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    if STRICT and report.outcome == "skipped" and not _allowed(_reason(report)):
        _fail_skip(report, collector.nodeid)

@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size)``: a folder on a tmpfs of ``size`` (e.g. ``"2m"``), unmounted afterwards.

    Needs root (mount): without it the test skips with the reason, which a strict run
    (CI, make) turns into a failure.
    """
    import os
    import subprocess

    mounted = []

    def make(size, name="disk"):
        where = tmp_path / name
        where.mkdir()
        if os.geteuid() != 0:
            pytest.skip("mounting a small tmpfs for the disk-full tests needs root")  # fails when STRICT
        run = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True,
                             text=True)
        if run.returncode:
            pytest.skip(f"cannot mount a tmpfs ({run.stderr.strip()})")  # fails when STRICT
        mounted.append(where)
        return where

    def remount(where, options):
        subprocess.run(["mount", "-o", f"remount,{options}", str(where)], check=True)

    make.remount = remount
    yield make
    for where in reversed(mounted):
        subprocess.run(["umount", "-l", str(where)], check=False)
