"""Shared fixtures: where the real data lives, and a skip when it is absent."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data():
    """``../shared/data`` (the real files described in its README)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


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

    spec = importlib.util.spec_from_file_location("fetch_grib_samples", ROOT / "tests" / "data" / "fetch_grib_samples.py")
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
