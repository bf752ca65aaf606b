"""core/files.py: one atomic_write: all or nothing, an ordinary file's mode, no temporary left behind."""

import errno
import os
import stat
import subprocess
import sys

import pytest

from nephele.core.files import atomic_write, remove_temporaries


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_writes_and_replaces(tmp_path):
    p = tmp_path / "sub" / "a.txt"
    with atomic_write(p) as tmp:
        assert tmp.parent == p.parent and tmp.suffix == ".txt" and tmp.is_file()
        tmp.write_text("one")
    assert p.read_text() == "one"
    with atomic_write(p, fsync=False) as tmp:
        tmp.write_text("two")
    assert p.read_text() == "two"
    assert sorted(x.name for x in p.parent.iterdir()) == ["a.txt"]


def test_an_error_while_writing_leaves_the_old_file(tmp_path):
    p = tmp_path / "a.json"
    p.write_text("old")
    with pytest.raises(RuntimeError, match="disk on fire"):
        with atomic_write(p) as tmp, open(tmp, "w") as f:
            f.write("half of the new")
            raise RuntimeError("disk on fire")
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["a.json"]


def test_a_killed_writer_leaves_the_old_file(tmp_path):
    # A process killed in the middle of the write (no exception handler runs).
    p = tmp_path / "a.bin"
    p.write_bytes(b"old")
    code = (
        "import os, sys\n"
        "from nephele.core.files import atomic_write\n"
        f"with atomic_write({str(p)!r}) as tmp:\n"
        "    open(tmp, 'wb').write(b'new, half written')\n"
        "    os._exit(9)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ), capture_output=True)
    assert out.returncode == 9, out.stderr
    assert p.read_bytes() == b"old"
    # What a kill leaves is the hidden temporary; the next writer (holding the lock) clears it, nothing else.
    left = [x.name for x in tmp_path.iterdir() if x.name != "a.bin"]
    assert len(left) == 1 and left[0].startswith(".a.") and left[0].endswith(".tmp.bin")
    others = [".b.0123456789ab.tmp.bin", ".a.notatemporary.tmp.bin", ".a.0123456789ab.tmp.json", "a.bin.tmp"]
    for name in others:
        (tmp_path / name).write_bytes(b"someone else's")
    assert remove_temporaries(p) == left
    assert sorted(x.name for x in tmp_path.iterdir()) == sorted(["a.bin", *others])
    assert remove_temporaries(tmp_path / "missing" / "a.bin") == []


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_the_mode_is_the_umasks(tmp_path, umask):
    old = os.umask(umask)
    try:
        p = tmp_path / f"f{umask:o}.npz"
        with atomic_write(p) as tmp:
            tmp.write_bytes(b"x")
        ref = tmp_path / f"ref{umask:o}"
        ref.write_bytes(b"x")  # what an ordinary open() makes under this umask
    finally:
        os.umask(old)
    assert _mode(p) == _mode(ref) == 0o666 & ~umask


def test_a_writer_that_recreates_the_file_keeps_the_mode(tmp_path):
    old = os.umask(0o022)
    try:
        p = tmp_path / "a.txt"
        with atomic_write(p) as tmp:
            tmp.unlink()
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT, 0o600)
            os.write(fd, b"private")
            os.close(fd)
    finally:
        os.umask(old)
    assert p.read_bytes() == b"private" and _mode(p) == 0o644


def test_a_writer_that_removes_its_file_is_an_error(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    with pytest.raises(FileNotFoundError, match="a.txt"):
        with atomic_write(p) as tmp:
            tmp.unlink()
    assert p.read_text() == "old"


@pytest.mark.parametrize("when", ["open", "stat"])
def test_an_interrupt_as_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch, when):
    # Ctrl-C (KeyboardInterrupt) landing right after the temporary file was created, before the
    # writer got it: the farm's SIGINT test once found a .manifest.*.tmp.json left this way
    p = tmp_path / "a.json"
    real = {"open": os.close, "stat": type(p).stat}

    def interrupted(*a, **kw):
        out = real[when](*a, **kw)
        if when == "open" or a[0].name.startswith(".a."):  # the temporary file's stat
            raise KeyboardInterrupt
        return out

    if when == "open":
        monkeypatch.setattr(os, "close", interrupted)
    else:
        monkeypatch.setattr(type(p), "stat", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(p) as tmp:
            tmp.write_text("never")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


# --- a full disk, a read-only folder, a lock (issue 41) ---------------------------------------------


def test_a_full_disk_is_one_line_naming_the_file_and_leaves_nothing(small_disk):
    from nephele.core.files import WriteError

    disk = small_disk("64k")
    (disk / "keep.bin").write_bytes(b"x" * 1000)
    with pytest.raises(WriteError) as err:
        with atomic_write(disk / "big.bin") as tmp:
            tmp.write_bytes(b"y" * 200_000)
    text = str(err.value)
    assert text.startswith(f"{disk / 'big.bin'}: no space left on the disk") and "\n" not in text
    assert err.value.errno == errno.ENOSPC
    assert sorted(p.name for p in disk.iterdir()) == ["keep.bin"]  # no temporary, no torn file


def test_a_read_only_folder_is_one_line(small_disk):
    from nephele.core.files import WriteError

    disk = small_disk("64k")
    small_disk.remount(disk, "ro")
    with pytest.raises(WriteError) as err:
        with atomic_write(disk / "a.txt") as tmp:
            tmp.write_text("x")
    assert str(err.value) == f"{disk / 'a.txt'}: the file system is read-only"


def test_check_space(tmp_path):
    from nephele.core.files import WriteError, check_space, free_bytes

    free = free_bytes(tmp_path / "not" / "yet")
    assert free == free_bytes(tmp_path) > 0
    assert check_space(tmp_path, 1000, "a frame") == free
    with pytest.raises(WriteError, match=r"40 frames need about .* free: free some space, or pass --force"):
        check_space(tmp_path, 2 * free, "40 frames")
    check_space(tmp_path, 2 * free, "40 frames", force=True)


def test_lock_file_refuses_a_live_holder_and_takes_over_a_dead_one(tmp_path):
    import socket
    import subprocess
    import sys

    from nephele.core.errors import DataError
    from nephele.core.files import lock_file

    lock = tmp_path / ".nephele.lock"
    with lock_file(lock, "nephele render"):
        assert lock.read_text().split()[:2] == [str(os.getpid()), socket.gethostname()]
        with pytest.raises(DataError, match=rf"another nephele render \(pid {os.getpid()} on .*remove .nephele.lock"):
            with lock_file(lock, "nephele render"):
                pass
    assert not lock.exists()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock.write_text(f"{dead.stdout.strip()} {socket.gethostname()} 2026-01-01T00:00:00+00:00\n")
    with lock_file(lock, "nephele render"):  # its process has ended: stale, taken over
        assert lock.read_text().split()[0] == str(os.getpid())
    lock.write_text("123 another-host 2026-01-01T00:00:00+00:00\n")  # cannot be checked from here: refused
    with pytest.raises(DataError, match="pid 123 on another-host"):
        with lock_file(lock, "nephele render"):
            pass


def test_a_writer_failing_without_an_errno_on_a_full_disk_is_a_disk_error(small_disk):
    """OpenImageIO, OpenVDB and Blender report a full disk in their own words; with the disk (nearly) full
    that is what the one line says, and nothing is left behind."""
    from nephele.core.files import WriteError

    disk = small_disk("64k")
    with pytest.raises(WriteError, match=r"image.png: no space left on the disk \(.* free; the writer said: "
                                         r"cannot write image: write failed\)"):
        with atomic_write(disk / "image.png"):
            raise RuntimeError("cannot write image: write failed")
    assert list(disk.iterdir()) == []
