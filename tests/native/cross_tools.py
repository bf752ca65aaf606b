"""Paths and helpers of the cross-platform kernel tests (conftest.py's fixtures use them)."""

import importlib.util
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HARNESS = ROOT / "native" / "tests" / "harness.c"
WIN_START = ROOT / "native" / "tests" / "win_start.c"  # harness.exe's start-up without MinGW-w64's C runtime
WINE = "/usr/lib/wine/wine64"  # Debian's runner, not on PATH
# The minimum macOS each macOS zip states (build-extension reads it from the wheels it fetched;
# README's install table): the Python 3.11 zips', the oldest.
MACOS = {"macos-arm64": "14.0", "macos-x64": "12.0"}


def unavailable(why):
    """Skip, or fail in CI: a platform check that cannot run is a failure there."""
    if os.environ.get("CI"):
        pytest.fail(why, pytrace=False)
    pytest.skip(why)


def build_module():
    """native/build.py as a module."""
    spec = importlib.util.spec_from_file_location("nephele_native_build", ROOT / "native" / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def ensure_wine(timeout=600):
    """Debian's wine64 runner, apt-installed when missing (root); None if it cannot be had."""
    if Path(WINE).exists():
        return WINE
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        return None
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-qq"],
                ["apt-get", "install", "-y", "-qq", "-o", "DPkg::Lock::Timeout=120", "wine64"]):
        if subprocess.run(cmd, env=env, capture_output=True, timeout=timeout).returncode:
            return None
    return WINE if Path(WINE).exists() else None
