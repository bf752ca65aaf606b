"""The compiled kernels' frame: the wheel the tests run is built from the sources here, it
runs on the glibc Blender needs, and without it the NumPy twins run."""

import importlib.util
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from nephele.core import native

ROOT = Path(__file__).resolve().parents[2]


def _build():
    spec = importlib.util.spec_from_file_location("nephele_native_build", ROOT / "native" / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _made_wheel():
    """make's wheel in build/native/dist when it was built from the sources here, else None."""
    want = _build().build_id()
    for whl in sorted((ROOT / "build" / "native" / "dist").glob("nephele_native-*.whl")):
        with zipfile.ZipFile(whl) as z:
            if z.read("nephele_native/BUILD_ID").decode().strip() == want:
                return whl
    return None


def test_without_the_library_the_numpy_twins_run(monkeypatch):
    monkeypatch.setattr(native, "_module", lambda: None)
    assert native.kernel("anything", None, []) is None
    assert native.identity() == "numpy"


def test_switched_off_by_the_environment():
    code = "from nephele.core import native; print(native.identity())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"NEPHELE_NATIVE": "0", "PATH": ""}).stdout
    assert out.strip() == "numpy"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="kernels are built for Linux only")
def test_installed_kernels_are_these_sources():
    # make installs the wheel; a stale one would test other code than the sources here
    nn = pytest.importorskip("nephele_native")
    assert native.identity() == nn.BUILD_ID == _build().build_id()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="kernels are built for Linux only")
def test_wheel_runs_where_blender_runs(tmp_path):
    # Blender 4.2+ needs glibc 2.28: the wheel may need no newer symbol, and says which it needs.
    # The wheel make built from these sources (its BUILD_ID) when there is one, else a new one (27 s).
    whl = _made_wheel() or _build().wheel(tmp_path)
    level = int(re.search(r"manylinux_2_(\d+)_x86_64", whl.name).group(1))
    assert level <= 28, whl.name
