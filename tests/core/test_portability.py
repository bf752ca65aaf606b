"""Code that must run on Windows and macOS, run here with their behaviour simulated: a rename onto a file
another program holds open (Windows refuses it), msvcrt's byte-range locks instead of fcntl, a process
asked about through kernel32 (os.kill(pid, 0) would send it CTRL_C_EVENT), macOS's sysconf."""

import ctypes
import fcntl
import os
import subprocess
import sys
import types

import pytest

from nephele.core import files, memory
from nephele.core.files import atomic_write, locked
from nephele.core.pipeline import cache


@pytest.fixture
def windows(monkeypatch):
    """core.files on Windows: os.replace refuses to rename onto a file in ``held`` (as Windows does while
    another program has it open), msvcrt.locking is a byte-range lock, no waiting between tries."""
    held, real_replace, tries = set(), os.replace, []

    def replace(src, dst):
        tries.append(str(dst))
        if str(dst) in held:
            raise PermissionError(13, "Access is denied", str(dst))
        real_replace(src, dst)

    def locking(fd, mode, n):  # flock conflicts between two opens even in one process, as Windows' locks do
        assert n == 1 and os.lseek(fd, 0, os.SEEK_CUR) == 0  # the first byte
        if mode == msvcrt.LK_UNLCK:
            fcntl.flock(fd, fcntl.LOCK_UN)
        else:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise PermissionError(13, "Permission denied") from None  # what msvcrt raises

    msvcrt = types.SimpleNamespace(LK_UNLCK=0, LK_LOCK=1, LK_NBLCK=2, locking=locking)
    monkeypatch.setitem(sys.modules, "msvcrt", msvcrt)
    monkeypatch.setattr(files, "_WINDOWS", True)
    monkeypatch.setattr(files.os, "replace", replace)
    monkeypatch.setattr(files, "REPLACE_WAITS", (0.0,) * 6)
    return types.SimpleNamespace(held=held, tries=tries)


def test_rename_onto_an_open_file_is_retried_on_windows(windows, tmp_path, monkeypatch):
    out = tmp_path / "frame.json"
    out.write_text("old")
    windows.held.add(str(out))
    sleeps = []
    monkeypatch.setattr(files.time, "sleep", lambda s: (sleeps.append(s), sleeps[3:] and windows.held.clear()))
    with atomic_write(out) as tmp:  # the viewer closes the file during the fourth wait
        tmp.write_text("new")
    assert out.read_text() == "new" and len(windows.tries) == 5 and len(sleeps) == 4
    assert [p.name for p in tmp_path.iterdir()] == ["frame.json"]


def test_rename_onto_a_file_held_open_for_good_fails_cleanly(windows, tmp_path):
    out = tmp_path / "frame.json"
    out.write_text("old")
    windows.held.add(str(out))
    with pytest.raises(files.WriteError, match="frame.json: open in another program"):
        with atomic_write(out) as tmp:
            tmp.write_text("new")
    assert out.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["frame.json"]
    assert len(windows.tries) == 1 + len(files.REPLACE_WAITS)


def test_posix_rename_is_not_retried(tmp_path, monkeypatch):
    calls = []

    def refuse(src, dst):
        calls.append(dst)
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(files.os, "replace", refuse)
    with pytest.raises(PermissionError, match="Permission denied"):
        files.replace(tmp_path / "a", tmp_path / "b")
    assert len(calls) == 1  # a real permission problem there, not a reader


@pytest.mark.parametrize("platform", ["posix", "windows"])
def test_lock_excludes(platform, request, tmp_path):
    if platform == "windows":
        request.getfixturevalue("windows")
    path = tmp_path / "benchmarks.lock"
    with locked(path, wait=False):
        with pytest.raises(BlockingIOError):
            with locked(path, wait=False):
                pass
    with locked(path):  # free again
        pass


def test_farm_run_lock_on_windows(windows, monkeypatch, tmp_path):
    from nephele.core.errors import DataError

    monkeypatch.setattr(files, "_alive_windows", lambda pid: pid == os.getpid())  # kernel32, as Windows answers
    with files.lock_file(tmp_path / ".nephele.lock", "nephele render"):
        with pytest.raises(DataError, match="another nephele render .pid %d" % os.getpid()):
            with files.lock_file(tmp_path / ".nephele.lock", "nephele render"):
                pass
    assert not (tmp_path / ".nephele.lock").exists()
    (tmp_path / ".nephele.lock").write_text("999999 %s 2026-11-28T00:00:00+00:00" % __import__("socket").gethostname())
    with files.lock_file(tmp_path / ".nephele.lock", "nephele render"):  # its process ended: taken over
        pass


class FakeKernel32:
    """kernel32's OpenProcess / GetExitCodeProcess / CloseHandle over a table pid -> exit code."""

    def __init__(self, procs, denied=()):
        self.procs, self.denied, self.open = procs, denied, set()

    def OpenProcess(self, access, inherit, pid):
        assert access == 0x1000
        if pid in self.denied:
            ctypes.set_last_error(5)
            return None
        if pid not in self.procs:
            ctypes.set_last_error(87)
            return None
        self.open.add(pid)
        return pid

    def GetExitCodeProcess(self, handle, code):
        code._obj.value = self.procs[handle]
        return 1

    def CloseHandle(self, handle):
        self.open.discard(handle)


def test_session_owner_asked_of_windows(monkeypatch, tmp_path):
    if not hasattr(ctypes, "set_last_error"):
        last = [0]
        monkeypatch.setattr(ctypes, "set_last_error", lambda v: last.__setitem__(0, v), raising=False)
        monkeypatch.setattr(ctypes, "get_last_error", lambda: last[0], raising=False)
    k = FakeKernel32({10: 259, 11: 0}, denied={12})
    alive = files._alive_windows
    assert alive(10, k) and not alive(11, k)  # running; exited (code 0)
    assert alive(12, k) and not alive(13, k)  # another user's; no such pid
    assert not k.open  # every handle closed
    # prune_sessions on Windows: the ended session's folder goes, the running one's stays
    monkeypatch.setattr(files, "_WINDOWS", True)
    monkeypatch.setattr(files, "_alive_windows", lambda pid: alive(pid, k))
    for pid in (10, 11):
        (tmp_path / "sessions" / f"{pid}-abc").mkdir(parents=True)
    gone = cache.prune_sessions(tmp_path)
    assert [d.name for d in gone] == ["11-abc"] and (tmp_path / "sessions" / "10-abc").is_dir()


def test_memory_known_without_proc_and_avphys(monkeypatch):
    # macOS: no /proc/meminfo and no SC_AVPHYS_PAGES; its physical memory bounds a request
    real_open, real_sysconf = open, os.sysconf

    def no_proc(path, *a, **k):
        if str(path) == "/proc/meminfo":
            raise FileNotFoundError(path)
        return real_open(path, *a, **k)

    def sysconf(name):
        if name == "SC_AVPHYS_PAGES":
            raise ValueError("unrecognized configuration name")
        return real_sysconf(name)

    monkeypatch.setattr("builtins.open", no_proc)
    monkeypatch.setattr(memory.os, "sysconf", sysconf)
    assert memory._machine() == real_sysconf("SC_PHYS_PAGES") * real_sysconf("SC_PAGE_SIZE")


def test_no_posix_only_module_at_import():
    # The add-on, core and farm import on a system without fcntl, resource or signal.SIGKILL
    code = ("import sys; sys.modules['fcntl'] = None; sys.modules['resource'] = None\n"
            "import signal; del signal.SIGKILL\n"
            "import nephele.core.files, nephele.core.pipeline.cache, nephele.fileio\n"
            "import nephele.farm.render, nephele.farm.cli\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
