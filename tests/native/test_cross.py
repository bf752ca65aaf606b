"""The kernels built for every platform from this Linux machine: what each platform's loader will
find (file name, wheel tag), and, read from the files themselves, the Windows DLL's imports and the
macOS dylibs' architecture, minimum macOS and undefined symbols (nothing runs macOS code here)."""

import re
import shutil
import subprocess
import sys

import pytest
from cross_tools import MACOS, ROOT

from nephele.farm import cmd_build_extension as be


def test_loader_names_the_file_each_build_writes(build):
    path = ROOT / "native" / "nephele_native" / "__init__.py"
    ns = {"__file__": str(path)}
    exec(path.read_text().split("BUILD_ID =")[0], ns)  # the naming, without loading a library
    for target, plat in {"linux-x64": "linux", "windows-x64": "win32", "macos-arm64": "darwin",
                         "macos-x64": "darwin"}.items():
        assert ns["library_file"](plat) == build.TARGETS[target][0], target


def test_wheel_tags(build, tmp_path):
    assert build.platform_tag(None, "windows-x64") == "win_amd64"
    assert build.platform_tag(None, "macos-arm64", "14.0") == "macosx_14_0_arm64"
    assert build.platform_tag(None, "macos-x64", "12.0") == "macosx_12_0_x86_64"
    # build-extension builds the macOS kernels for the version its fetched wheels resolved to
    target = be.TARGETS["3.13"]
    folder = tmp_path / f"{target.abi}-macos-arm64"
    folder.mkdir()
    (folder / "tags.txt").write_text("macosx_15_0_arm64\n")
    assert be.macos_minimum(target, "macos-arm64", tmp_path) == "15.0"
    assert be.macos_minimum(target, "windows-x64", tmp_path) is None


def test_check_refuses_what_a_platform_cannot_load(build, monkeypatch, tmp_path):
    with pytest.raises(build.BuildError, match="neither"):
        build.describe(ROOT / "README.md")
    dll = {"format": "PE32+ DLL", "arch": "x86_64", "needs": ["KERNEL32.dll", "python313.dll"], "undefined": []}
    monkeypatch.setattr(build, "describe", lambda p: dll)
    with pytest.raises(build.BuildError, match="python313.dll"):
        build.check("k.dll", "windows-x64")
    dylib = {"format": "Mach-O dylib", "arch": "arm64", "minos": "15.0", "needs": [build.LIBSYSTEM],
             "undefined": [("_expf", build.LIBSYSTEM)]}
    monkeypatch.setattr(build, "describe", lambda p: dylib)
    with pytest.raises(build.BuildError, match="minimum macOS 15.0, not 14.0"):
        build.check("k.dylib", "macos-arm64", "14.0")
    with pytest.raises(build.BuildError, match="not a Mach-O x86_64"):
        build.check("k.dylib", "macos-x64", "15.0")
    assert build.check("k.dylib", "macos-arm64", "15.0") is dylib


def _file(path):
    return subprocess.run(["file", "-b", str(path)], capture_output=True, text=True, check=True).stdout


@pytest.mark.slow
def test_windows_dll_imports_only_system_dlls(cross, build):
    dll = cross["windows-x64"] / build.TARGETS["windows-x64"][0]
    if shutil.which("file"):
        assert _file(dll).startswith("PE32+ executable (DLL)") and "x86-64" in _file(dll)
    info = build.describe(dll)
    assert info["format"] == "PE32+ DLL" and info["arch"] == "x86_64"
    assert info["needs"] == ["ucrtbase.dll"]  # the C runtime alone (build.WINDOWS_LINK)
    assert all(build.system_dll(d) for d in info["needs"])
    assert not (cross["windows-x64"] / "nephele_kernels.pdb").exists()  # zig's by-product stays out
    if shutil.which("objdump"):  # binutils reads the same import table
        out = subprocess.run(["objdump", "-p", str(dll)], capture_output=True, text=True, check=True).stdout
        assert re.findall(r"DLL Name: (\S+)", out) == info["needs"]


@pytest.mark.slow
@pytest.mark.parametrize("target", sorted(MACOS))
def test_macos_dylib_arch_minos_and_libsystem_only(cross, build, target):
    lib = cross[target] / build.TARGETS[target][0]
    arch = build.TARGETS[target][2]
    if shutil.which("file"):
        assert _file(lib).startswith(f"Mach-O 64-bit {arch} dynamically linked shared library")
    info = build.describe(lib)
    assert (info["format"], info["arch"], info["minos"]) == ("Mach-O dylib", arch, MACOS[target])
    assert info["needs"] == [build.LIBSYSTEM]
    assert info["undefined"] and all(d == build.LIBSYSTEM for _, d in info["undefined"])
    assert {s for s in info["exports"] if s.startswith("blobby_")} >= {"blobby_project", "blobby_node_values"}
    objdump = shutil.which("llvm-objdump")
    if objdump:  # LLVM's reading agrees with ours
        out = subprocess.run([objdump, "--macho", "--private-headers", str(lib)], capture_output=True, text=True,
                             check=True).stdout
        assert re.search(r"minos (\S+)", out).group(1) == MACOS[target]
        assert re.findall(r"cmd LC_LOAD_DYLIB\n\s+cmdsize \d+\n\s+name (\S+)", out) == info["needs"]
        und = subprocess.run([objdump.replace("objdump", "nm"), "-u", str(lib)], capture_output=True, text=True,
                             check=True).stdout.split()
        assert sorted(und) == sorted(s for s, _ in info["undefined"])


@pytest.mark.slow
def test_build_id_covers_target_and_compiler(cross, build):
    ids = {t: (p / "BUILD_ID").read_text().strip() for t, p in cross.items()}
    assert len(set(ids.values())) == len(ids)
    assert build.build_id(target="macos-arm64", macos="15.0") != ids["macos-arm64"]
    assert ids["linux-x64"] == build.build_id()  # the Linux id is the one the installed wheel carries
    assert "zig 0.17.0" in build.compiler("windows-x64")[2] and sys.platform.startswith("linux")
