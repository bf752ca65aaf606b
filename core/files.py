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
import uuid
from pathlib import Path


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
            fsync_path(tmp, os.O_RDWR)  # Windows flushes only a handle open for writing
        os.replace(tmp, path)
    except BaseException as exc:
        if made or not isinstance(exc, FileExistsError):  # (that one: the name was not ours)
            tmp.unlink(missing_ok=True)
        raise
    if fsync and os.name == "posix":  # the rename itself; folders cannot be opened on Windows
        fsync_path(path.parent)


def fsync_path(path, flags=os.O_RDONLY):
    """Flush ``path`` (a file or, on POSIX, a folder) to disk."""
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


__all__ = ["atomic_write", "fsync_path"]
