"""Writing files so that nothing is ever half-written.

:func:`atomic_write` is the one way Nephele writes a file: into a temporary
file beside the target, then :func:`os.replace` onto it.  A reader sees the
old file or the new one, never a torn one; an error or a kill while writing
leaves the old file and no temporary behind (a kill leaves at most a hidden
``.name.*.tmp`` file).  The file gets an ordinary file's mode (``0o666``
less the umask), not ``mkstemp``'s private ``0o600``: a render farm's other
users must read what one node wrote.
"""

import contextlib
import os
import time
import uuid
from pathlib import Path

_WINDOWS = os.name == "nt"
REPLACE_WAITS = (0.05, 0.1, 0.2, 0.4, 0.8, 1.6)
"""Seconds between tries of a Windows rename onto a file another program holds open
(a viewer, Blender reading a frame, a virus scanner): 3.15 s in all, then the error."""


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
    path.parent.mkdir(parents=True, exist_ok=True)
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
            _fsync(tmp, os.O_RDWR)  # Windows flushes only a handle open for writing
        replace(tmp, path)
    except BaseException as exc:
        if made or not isinstance(exc, FileExistsError):  # (that one: the name was not ours)
            tmp.unlink(missing_ok=True)
        raise
    if fsync and os.name == "posix":  # the rename itself; folders cannot be opened on Windows
        _fsync(path.parent, os.O_RDONLY)


def replace(src, dst):
    """:func:`os.replace`, retried on Windows while another program holds ``dst`` open.

    POSIX renames over an open file; Windows refuses (PermissionError) until every
    handle on it is closed.  After :data:`REPLACE_WAITS` the error says which file
    is held.
    """
    for wait in (*REPLACE_WAITS, None) if _WINDOWS else (None,):
        try:
            return os.replace(src, dst)
        except PermissionError as exc:
            if wait is None:
                if _WINDOWS:
                    raise PermissionError(exc.errno, f"{dst} is open in another program (Windows cannot replace an "
                                          "open file); close it and try again", str(dst)) from None
                raise
            time.sleep(wait)


@contextlib.contextmanager
def locked(path, *, wait=True, remove=False):
    """Hold an exclusive lock on the file ``path`` (made if missing) for the block.

    ``fcntl.flock`` on POSIX, ``msvcrt.locking`` of its first byte on Windows; the
    lock goes with the process, so a killed holder never leaves it taken.
    ``wait=False``: :class:`BlockingIOError` at once when another process holds it.
    ``remove``: delete the file when done (POSIX: while still holding it; Windows,
    which deletes no open file: once released, unless another process has it open).
    """
    f = open(path, "a+b")
    try:
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
            try:
                yield f
            finally:
                if remove:
                    Path(path).unlink(missing_ok=True)
    finally:
        f.close()
    if remove and _WINDOWS:
        with contextlib.suppress(OSError):
            Path(path).unlink(missing_ok=True)


def _fsync(path, flags):
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


__all__ = ["atomic_write", "locked", "replace"]
