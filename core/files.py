"""Writing files so that nothing is ever half-written.

:func:`atomic_write` is the one way Nephele writes a file: into a temporary
file beside the target, then :func:`os.replace` onto it.  A reader sees the
old file or the new one, never a torn one; an error or a kill while writing
leaves the old file and no temporary behind (a kill leaves at most a hidden
``.name.*.tmp`` file, which :func:`remove_temporaries` clears for the next
writer).  The file gets an ordinary file's mode (``0o666``
less the umask), not ``mkstemp``'s private ``0o600``: a render farm's other
users must read what one node wrote.
"""

import contextlib
import datetime
import errno
import os
import re
import shutil
import socket
import sys
import time
import uuid
from pathlib import Path

from .errors import DataError
from .memory import format_bytes

_WINDOWS = os.name == "nt"
REPLACE_WAITS = (0.05, 0.1, 0.2, 0.4, 0.8, 1.6)
"""Seconds between tries of a Windows rename onto a file another program holds open
(a viewer, Blender reading a frame, a virus scanner): 3.15 s in all, then the error."""

DISK_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG,
               getattr(errno, "EDQUOT", errno.ENOSPC)}
"""Errors of the place written to (full, read-only, not ours), not of the data."""
LOW_SPACE = 1 << 20
"""Below this many free bytes, a writer's failure of any kind is taken for a full disk."""


class WriteError(OSError):
    """A file could not be written because of where it goes: one line naming the path and the problem.

    An :class:`OSError` (``errno`` kept), so code that reports ``OSError`` reports this too.
    """

    def __init__(self, code, path, problem):
        super().__init__(code, problem, str(path))
        self.path, self.problem = str(path), problem

    def __str__(self):
        return f"{self.path}: {self.problem}"


def cache_root():
    """Nephele's own cache folder: ``$NEPHELE_CACHE``, else the system's place for a user's caches
    (``%LOCALAPPDATA%\\nephele\\cache`` on Windows, ``~/Library/Caches/nephele`` on macOS,
    ``$XDG_CACHE_HOME/nephele`` or ``~/.cache/nephele`` elsewhere)."""
    env = os.environ.get("NEPHELE_CACHE")
    if env:
        return Path(env)
    if _WINDOWS and os.environ.get("LOCALAPPDATA"):
        return Path(os.environ["LOCALAPPDATA"]) / "nephele" / "cache"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "nephele"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nephele"


def cache_folder(name):
    """``<cache>/<name>`` (:func:`cache_root`): where what is made from a user's file (GRIB indexes, unpacked
    zips) is kept, never beside the user's data, which may be read-only."""
    return cache_root() / name


def file_stamp(path):
    """A file's identity: its resolved path, size and modification time (a changed file gets a new stamp)."""
    p = Path(path).resolve()
    st = p.stat()
    return f"{p}|{st.st_size}|{st.st_mtime_ns}"


def free_bytes(path):
    """Free bytes on the file system holding ``path`` (or its nearest existing parent); None if unknown."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


def write_error(exc, path, *, low=0):
    """A :class:`WriteError` for ``exc`` raised while writing ``path`` when the place is at fault, else None.

    Disk full, quota, read-only file system, permission, file too large: by
    ``errno``.  A writer library that fails without one (OpenImageIO,
    OpenVDB, Blender) on a disk with less than :data:`LOW_SPACE` (or
    ``low``) bytes free also counts as a full disk.
    """
    if isinstance(exc, WriteError):
        return exc
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        free = free_bytes(path)
        left = f" ({format_bytes(free)} free)" if free is not None else ""
        return WriteError(errno.ENOSPC, path, f"no space left on the disk{left}; free some space and run the same "
                                              "command again to finish the rest")
    if code == errno.EROFS:
        return WriteError(code, path, "the file system is read-only")
    if code in (errno.EACCES, errno.EPERM):
        return WriteError(code, path, "permission denied")
    if code == errno.EFBIG:
        return WriteError(code, path, "file too large for this file system")
    free = free_bytes(path)
    if free is not None and free < max(LOW_SPACE, low):
        said = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return WriteError(errno.ENOSPC, path, f"no space left on the disk ({format_bytes(free)} free; the writer "
                                              f"said: {said})")
    return None


def check_space(path, need, what, *, force=False):
    """Raise :class:`WriteError` when ``need`` bytes will not fit on the disk holding ``path`` (unless ``force``)."""
    free = free_bytes(path)
    if force or free is None or need <= free:
        return free
    raise WriteError(errno.ENOSPC, path, f"{what} need about {format_bytes(need)}, the disk has "
                                         f"{format_bytes(free)} free: free some space, or pass --force to go on")


@contextlib.contextmanager
def atomic_write(path, *, fsync=True):
    """Context manager giving a temporary path to write; moved onto ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or Path
        The file to write.  Its folder is made if missing.
    fsync : bool
        Flush the file and the folder to disk before and after the rename, so a
        power cut cannot leave an empty file under the new name.  Caches whose
        entries are checked on reading may skip it.

    Yields
    ------
    Path
        A new, empty file beside ``path`` with the same suffix (writers that pick
        the format by extension, OpenImageIO, ffmpeg, ``np.savez``, keep working).
        Write it by name or ``open(tmp, "w")``; it is removed if the block raises.

    Examples
    --------
    >>> with atomic_write(out / "meta.json") as tmp:          # doctest: +SKIP
    ...     tmp.write_text(json.dumps(meta))
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise (write_error(exc, path.parent) or exc) from None
    tmp = path.parent / f".{path.stem}.{uuid.uuid4().hex[:12]}.tmp{path.suffix}"
    made = False
    try:
        # O_EXCL: never someone else's file; mode 0o666 so the umask alone decides (not 0o600).
        # Inside the try: a Ctrl-C just after the open must not leave the file behind.
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        made = True
        mode = tmp.stat().st_mode & 0o777
        yield tmp
        if not tmp.is_file():
            raise FileNotFoundError(f"{path}: the writer removed its temporary file {tmp.name}")
        if tmp.stat().st_mode & 0o777 != mode:  # a writer that re-created the file
            os.chmod(tmp, mode)
        if fsync:
            fsync_path(tmp, os.O_RDWR)  # Windows flushes only a handle open for writing
        replace(tmp, path)
    except BaseException as exc:
        if made or not isinstance(exc, FileExistsError):  # (that one: the name was not ours)
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        if isinstance(exc, Exception) and not isinstance(exc, DataError):
            problem = write_error(exc, path)
            if problem is not None and problem is not exc:
                raise problem from exc
        raise
    if fsync and os.name == "posix":  # the rename itself; folders cannot be opened on Windows
        fsync_path(path.parent)


def remove_temporaries(path):
    """Remove what killed :func:`atomic_write` calls left beside ``path``; the names removed.

    A kill (``kill -9``, a power cut, a job's time limit) between the
    temporary file's creation and its rename leaves ``.stem.<12 hex>.tmp.suffix``
    beside the target.  Only a caller that holds the target's one writer's
    lock (no live writer can own such a file) may call this.
    """
    path = Path(path)
    pattern = re.compile(rf"\.{re.escape(path.stem)}\.[0-9a-f]{{12}}\.tmp{re.escape(path.suffix)}")
    gone = []
    with contextlib.suppress(FileNotFoundError):
        for p in path.parent.iterdir():
            if pattern.fullmatch(p.name) and p.is_file():
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
                    gone.append(p.name)
    return sorted(gone)


def replace(src, dst):
    """:func:`os.replace`, retried on Windows while another program holds ``dst`` open.

    POSIX renames over an open file; Windows refuses (PermissionError) until every
    handle on it is closed.  After :data:`REPLACE_WAITS` a :class:`WriteError` says
    which file is held.
    """
    for wait in (*REPLACE_WAITS, None) if _WINDOWS else (None,):
        try:
            return os.replace(src, dst)
        except PermissionError as exc:
            if wait is None:
                if _WINDOWS:
                    raise WriteError(exc.errno, dst, "open in another program (Windows cannot replace an open "
                                                     "file); close it and try again") from None
                raise
            time.sleep(wait)


@contextlib.contextmanager
def locked(path, *, wait=True):
    """Hold an exclusive lock on the file ``path`` (made if missing) for the block.

    ``fcntl.flock`` on POSIX, ``msvcrt.locking`` of its first byte on Windows; the
    lock goes with the process, so a killed holder never leaves it taken.
    ``wait=False``: :class:`BlockingIOError` at once when another process holds it.
    (A folder claimed by one run, with its holder named, is :func:`lock_file`.)
    """
    with open(path, "a+b") as f:
        if _WINDOWS:
            import msvcrt

            f.seek(0)
            while True:  # LK_LOCK would give up after 10 s: wait as long as flock does
                try:
                    msvcrt.locking(f.fileno(), msvcrt.LK_NBLCK, 1)
                    break
                except OSError:
                    if not wait:
                        raise BlockingIOError(f"{path} is locked by another process") from None
                    time.sleep(0.1)
            try:
                yield f
            finally:
                f.seek(0)
                msvcrt.locking(f.fileno(), msvcrt.LK_UNLCK, 1)
        else:
            import fcntl

            fcntl.flock(f, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))  # BlockingIOError if held
            yield f


def fsync_path(path, flags=os.O_RDONLY):
    """Flush ``path`` (a file or, on POSIX, a folder) to disk."""
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def lock_file(path, what):
    """Hold ``path`` as a lock for the block: made with ``O_EXCL`` (every platform), holding pid, host and time.

    A lock left by a process that has ended on this host is taken over; one
    held by a live process, or by another host (a shared file system, where
    its process cannot be checked), raises :class:`~.errors.DataError`
    naming its holder.
    """
    path = Path(path)
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    me = f"{os.getpid()} {socket.gethostname()} {now}"
    for _ in range(3):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = _holder(path)
            if holder is None:  # ended on this host: stale
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                continue
            pid, host, since = holder
            raise DataError(f"another {what} (pid {pid} on {host}, since {since}) is writing here; wait for it to "
                            f"finish, or remove {path.name} if it no longer runs", path=path.parent) from None
        except OSError as exc:
            raise (write_error(exc, path) or exc) from None
        with os.fdopen(fd, "w") as f:
            f.write(me + "\n")
        break
    else:
        raise DataError(f"cannot take the lock {path.name}", path=path.parent)
    try:
        yield path
    finally:
        with contextlib.suppress(OSError):
            if path.read_text().strip() == me:
                path.unlink()


def _holder(path):
    """``(pid, host, since)`` of a live lock, None for a stale one (its process ended on this host)."""
    try:
        pid, host, since = path.read_text().split()
        pid = int(pid)
    except (OSError, ValueError):
        return ("?", "?", "?") if path.exists() else None  # being written this instant, or unreadable: not ours
    if host == socket.gethostname() and not process_alive(pid):
        return None
    return pid, host, since


def process_alive(pid):
    """Whether process ``pid`` runs on this host (someone else's live process counts)."""
    if _WINDOWS:  # os.kill(pid, 0) there sends CTRL_C_EVENT (0), it does not ask
        return _alive_windows(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # someone else's live process
    return True


def _alive_windows(pid, k=None):
    """Whether process ``pid`` runs, asked of Windows (``k``: kernel32, for tests)."""
    import ctypes

    if k is None:
        k = ctypes.WinDLL("kernel32", use_last_error=True)
        k.OpenProcess.restype = ctypes.c_void_p
        k.OpenProcess.argtypes = [ctypes.c_uint32, ctypes.c_int, ctypes.c_uint32]
        k.GetExitCodeProcess.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint32)]
        k.CloseHandle.argtypes = [ctypes.c_void_p]
    handle = k.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return ctypes.get_last_error() == 5  # access denied: someone else's live process
    try:
        code = ctypes.c_uint32()
        return bool(k.GetExitCodeProcess(handle, ctypes.byref(code))) and code.value == 259  # STILL_ACTIVE
    finally:
        k.CloseHandle(handle)


__all__ = ["DISK_ERRNOS", "WriteError", "atomic_write", "cache_folder", "cache_root", "check_space", "file_stamp",
           "free_bytes", "lock_file", "locked", "process_alive",
           "fsync_path", "replace", "write_error"]
