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


@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size)``: a folder on a tmpfs of ``size`` (e.g. ``"2m"``), unmounted afterwards.

    Needs root (mount).  Under CI (``CI`` set) a failure to mount fails the
    test loudly; elsewhere, without root, the test is skipped with the reason.
    """
    import os
    import subprocess

    mounted = []

    def make(size, name="disk"):
        where = tmp_path / name
        where.mkdir()
        if os.geteuid() != 0:
            if os.environ.get("CI"):
                pytest.fail("mounting a tmpfs for the disk-full tests needs root, and CI runs as root")
            pytest.skip("mounting a small tmpfs for the disk-full tests needs root")
        run = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True, text=True)
        if run.returncode:
            message = f"cannot mount a tmpfs ({run.stderr.strip()})"
            pytest.fail(message) if os.environ.get("CI") else pytest.skip(message)
        mounted.append(where)
        return where

    def remount(where, options):
        subprocess.run(["mount", "-o", f"remount,{options}", str(where)], check=True)

    make.remount = remount
    yield make
    for where in reversed(mounted):
        subprocess.run(["umount", "-l", str(where)], check=False)
