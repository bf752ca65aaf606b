"""The compiled kernels built for every platform from this Linux machine, and what runs them here.

``native/build.py`` builds the Linux library (this machine's cc) and the Windows and macOS ones
(zig, pip-installed into ``build/toolchain`` on first use); ``native/tests/harness.c`` is built
against the Linux and the Windows library; ``wine64`` (Debian) runs the Windows one, installed with
apt-get when missing (root).  Where a tool cannot be had the tests skip, saying why; with ``CI``
set they fail with that one line instead, so a green CI never hides an unchecked platform.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from cross_tools import HARNESS, MACOS, WIN_START, WINE, build_module, ensure_wine, unavailable  # noqa: E402


@pytest.fixture(scope="session")
def build():
    return build_module()


@pytest.fixture(scope="session")
def cross(build, tmp_path_factory):
    """target -> built nephele_native package folder (the macOS ones for their oldest zip's minos)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the cross builds are checked from Linux")
    try:
        build.zig()
    except (OSError, subprocess.CalledProcessError) as e:
        unavailable(f"the ziglang cross-compiler could not be installed from PyPI: {e}")
    out = tmp_path_factory.mktemp("cross")
    return {t: build.package(out / t, target=t, macos=MACOS.get(t)) for t in build.TARGETS}


@pytest.fixture(scope="session")
def linux_lib(cross, build):
    return cross["linux-x64"] / build.TARGETS["linux-x64"][0]


@pytest.fixture(scope="session")
def windows_lib(cross, build):
    return cross["windows-x64"] / build.TARGETS["windows-x64"][0]


@pytest.fixture(scope="session")
def harnesses(build, linux_lib, windows_lib, tmp_path_factory):
    """(Linux harness, Windows harness.exe beside its DLL)."""
    out = tmp_path_factory.mktemp("harness")
    flags = ["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror"]
    linux = out / "harness"
    subprocess.run(["cc", *flags, str(HARNESS), str(linux_lib), f"-Wl,-rpath,{linux_lib.parent}", "-o", str(linux)],
                   check=True)
    win = out / "win"
    win.mkdir()
    shutil.copy2(windows_lib, win / windows_lib.name)
    # Linked as the DLL is, against the UCRT alone, its start-up from win_start.c (build.WINDOWS_LINK)
    exe = build.zig()
    zig, env = [str(exe), "cc", "-target", "x86_64-windows-gnu"], build._zig_env(exe)
    objs = [str(out / (src.stem + ".o")) for src in (HARNESS, WIN_START)]
    for src, obj in zip((HARNESS, WIN_START), objs):
        subprocess.run([*zig, *flags, "-c", str(src), "-o", obj], check=True, env=env)
    subprocess.run([*zig, *build.WINDOWS_LINK, "-Wl,--entry=mainCRTStartup", "-Wl,--subsystem,console", *objs,
                    str(win / windows_lib.name), "-o", str(win / "harness.exe")], check=True, env=env)
    return linux, win / "harness.exe"


@pytest.fixture(scope="session")
def wine(tmp_path_factory):
    """A command prefix that runs a Windows program here, in its own wine prefix."""
    runner = ensure_wine()
    if runner is None:
        unavailable(f"wine64 is not installed ({WINE}) and apt-get could not install it (needs root)")
    prefix = tmp_path_factory.mktemp("wineprefix")
    env = {**os.environ, "WINEPREFIX": str(prefix), "WINEDEBUG": "-all", "WINEDLLOVERRIDES": "mscoree,mshtml="}
    return [runner], env
