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


def pytest_collection_modifyitems(items):
    # Everything under tests/addon and tests/farm needs bpy.
    for item in items:
        parts = Path(str(item.fspath)).parts
        if "addon" in parts or "farm" in parts:
            item.add_marker(pytest.mark.bpy)
