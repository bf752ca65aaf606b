"""A content-addressed cache of per-frame results, written atomically, no pickle.

Heavy per-time-step work (contour meshes, volume grids, texture start
coordinates, scattering solves) is stored under a key made from the kind of
work and every parameter that determines it, so the farm can compute it ahead
on any worker and a render only loads it.  Entries are ``.npz`` files of plain
arrays (read with ``allow_pickle=False``) or any file a writer produces under
:meth:`Cache.file`.
"""

import hashlib
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from ..files import atomic_write, cache_root, file_stamp, process_alive
from . import registry

CACHE_VERSION = 1
"""Bump when the meaning of cached arrays changes; old entries are then ignored."""
_WINDOWS = os.name == "nt"


def canonical(params):
    """Canonical JSON of ``params`` (sorted keys, no whitespace); numpy scalars allowed."""

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"cache parameter of type {type(o).__name__} is not JSON-serialisable")

    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=default)


def cache_key(kind, params):
    """Hex sha256 of the kind, the parameters, :data:`CACHE_VERSION` and the hash of
    the code the task depends on (:func:`.registry.code_stamp`), so changed code never
    serves results made by the old code."""
    text = canonical({"kind": kind, "params": params, "version": CACHE_VERSION, "code": registry.code_stamp(kind)})
    return hashlib.sha256(text.encode()).hexdigest()


def source_stamp(source):
    """Identity of a data source for cache keys: a file's path, size and mtime, or the name itself.

    A file read with overrides (``path?key=value&...``, see
    :func:`nephele.core.climate.readers.override_source`) is the file's identity
    now plus the overrides: the ``file=`` part its name got when it was
    imported would not notice the file changing afterwards.
    """
    text = str(source)
    p = Path(text)
    if p.is_file():
        return file_stamp(p)
    base, sep, query = text.partition("?")
    if sep and Path(base).is_file():
        kept = "&".join(q for q in query.split("&") if not q.startswith("file="))
        return f"{source_stamp(base)}?{kept}"
    return text


def default_cache_dir(blend_path=None):
    """``<dir>/<stem>_nephele_cache`` beside a .blend, else Nephele's cache (:func:`~nephele.core.files.cache_root`).

    The shared folder (no .blend) suits content-addressed entries only (their
    names are their contents' keys); files a scene links by name belong in
    :func:`session_cache_dir` until the scene is saved.
    """
    if blend_path:
        p = Path(blend_path)
        return p.parent / f"{p.stem}_nephele_cache"
    return cache_root()


_SESSION = {}
"""``str(base) -> (pid, folder)`` of :func:`session_cache_dir`."""


def session_cache_dir(base=None, *, create=True):
    """A folder of this process alone: ``<base>/sessions/<pid>-<random token>``.

    For an unsaved scene's files (baked sequences, scattering views): two
    Blender sessions never share it, so neither can overwrite or delete the
    other's frames.  Created on first call (``mkdir`` without ``exist_ok``: a
    name another process already holds is never reused) and the same for the
    rest of the process.  ``base``: default :func:`default_cache_dir`.
    ``create=False``: None instead of making one when the process has none yet.
    """
    import secrets

    base = Path(base) if base is not None else default_cache_dir()
    pid, path = _SESSION.get(str(base), (None, None))
    if pid != os.getpid():  # a forked worker gets its own folder too
        if not create:
            return None
        while True:
            path = base / "sessions" / f"{os.getpid()}-{secrets.token_hex(6)}"
            try:
                path.mkdir(parents=True, exist_ok=False)
                break
            except FileExistsError:
                continue
        _SESSION[str(base)] = (os.getpid(), path)
    return path


def prune_sessions(base=None, max_age_days=7.0):
    """Remove session folders (:func:`session_cache_dir`) whose process has ended and
    which are empty or untouched for ``max_age_days`` (kept that long because
    Blender's autosave of an unsaved file still points into them).  Another
    live session's folder is never touched.  Returns the folders removed.
    """
    import shutil
    import time

    root = (Path(base) if base is not None else default_cache_dir()) / "sessions"
    if not root.is_dir():
        return []
    gone = []
    for d in root.iterdir():
        pid, _, token = d.name.partition("-")
        if not (pid.isdigit() and token) or int(pid) == os.getpid() or process_alive(int(pid)):
            continue
        try:
            newest = max((p.stat().st_mtime for p in d.rglob("*")), default=d.stat().st_mtime)
        except OSError:
            continue
        if not any(d.iterdir()) or time.time() - newest > max_age_days * 86400.0:
            shutil.rmtree(d, ignore_errors=True)
            gone.append(d)
    return gone


def tree_size(path):
    """Bytes and number of files under ``path`` (0, 0 when absent)."""
    total = count = 0
    for root, _dirs, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
                count += 1
            except OSError:
                pass
    return total, count


class Cache:
    """Content-addressed store rooted at ``root`` (created on first write).

    Layout: ``root/<kind>/<key[:2]>/<key><suffix>``.
    """

    def __init__(self, root):
        self.root = Path(root)

    def __repr__(self):
        return f"Cache({str(self.root)!r})"

    def file(self, kind, params, suffix=".npz"):
        """Path of the entry for ``kind`` and ``params`` (it may not exist yet)."""
        key = cache_key(kind, params)
        return self.root / kind / key[:2] / f"{key}{suffix}"

    def __contains__(self, item):
        kind, params = item
        return self.file(kind, params).is_file()

    def load(self, kind, params):
        """The stored arrays, or None when absent or unreadable (a damaged entry is removed)."""
        path = self.file(kind, params)
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files if k != "__params__"}
        except FileNotFoundError:
            return None
        except (zipfile.BadZipFile, ValueError, EOFError, OSError, KeyError):
            path.unlink(missing_ok=True)
            return None

    def store(self, kind, params, arrays):
        """Write ``arrays`` (a dict of ndarrays) atomically; returns the entry's path."""
        path = self.file(kind, params)
        # No fsync: a torn entry fails to load and is recomputed.
        with atomic_write(path, fsync=False) as tmp, open(tmp, "wb") as f:
            np.savez(f, __params__=np.array(canonical(params)), **{k: np.asarray(v) for k, v in arrays.items()})
        return path
