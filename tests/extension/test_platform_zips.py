"""Every platform's zip carries that platform's compiled kernels, built here (zig for Windows and
macOS) and read back from the zip: a PE32+ x86-64 DLL importing only system DLLs, Mach-O arm64 /
x86_64 dylibs for the minimum macOS of the zip, the ELF library for Linux.  The third-party wheels
are left out (test_extension.py builds the Linux zips with them; the README's table says what the
full zips measure)."""

import importlib.util
import io
import re
import zipfile
from pathlib import Path

import pytest

from nephele.farm import cmd_build_extension as be

pytestmark = [pytest.mark.bpy, pytest.mark.slow]
pytest.importorskip("bpy")  # the builder is the one inside the bpy wheel

ROOT = Path(__file__).resolve().parents[2]
MACOS = {"macos-arm64": "14.0", "macos-x64": "12.0"}  # what the Python 3.11 zips' wheels need


def _build_module():
    spec = importlib.util.spec_from_file_location("nephele_native_build", ROOT / "native" / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_each_zip_carries_its_platforms_kernels(tmp_path, monkeypatch):
    monkeypatch.setattr(be, "fetch_wheels", lambda *a, **k: [])
    monkeypatch.setattr(be, "macos_minimum", lambda target, platform, cache: MACOS.get(platform))
    build = _build_module()
    zips = be.build(out=tmp_path, pythons=["3.11"])
    assert len(zips) == 4
    for z in zips:
        platform = re.search(r"-(linux_x64|windows_x64|macos_arm64|macos_x64)\.zip$", z.name).group(1).replace("_", "-")
        zf = zipfile.ZipFile(z)
        wheels = [n for n in zf.namelist() if n.startswith("wheels/")]
        assert len(wheels) == 1 and wheels[0].startswith("wheels/nephele_native-"), (z.name, wheels)
        tag = wheels[0].removesuffix(".whl").split("-")[-1]
        assert tag == ({"windows-x64": "win_amd64", "linux-x64": "manylinux_2_27_x86_64"}.get(platform)
                       or build.platform_tag(None, platform, MACOS[platform])), z.name
        generated = zf.read("blender_manifest.toml").decode().split("[build.generated]")[1]
        assert f'platforms = ["{platform}"]' in generated
        lib_name = build.TARGETS[platform][0]
        wheel = zipfile.ZipFile(io.BytesIO(zf.read(wheels[0])))
        assert sorted(n.split("/")[-1] for n in wheel.namelist() if n.startswith("nephele_native/")) == \
            sorted(["BUILD_ID", "__init__.py", lib_name])
        lib = tmp_path / platform / lib_name
        lib.parent.mkdir()
        lib.write_bytes(wheel.read(f"nephele_native/{lib_name}"))
        if platform == "linux-x64":
            assert lib.read_bytes()[:4] == b"\x7fELF"
        else:
            build.check(lib, platform, MACOS.get(platform))  # format, arch, minos, imports
