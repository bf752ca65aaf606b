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

from ..files import atomic_write

CACHE_VERSION = 1
"""Bump when the meaning of cached arrays changes; old entries are then ignored."""


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
    the code the task depends on (:func:`.tasks.code_stamp`), so changed code never
    serves results made by the old code."""
    from .tasks import code_stamp

    text = canonical({"kind": kind, "params": params, "version": CACHE_VERSION, "code": code_stamp(kind)})
    return hashlib.sha256(text.encode()).hexdigest()


def source_stamp(source):
    """Identity of a data source for cache keys: a file's path, size and mtime, or the name itself."""
    p = Path(str(source))
    if p.is_file():
        st = p.stat()
        return f"{p.resolve()}|{st.st_size}|{st.st_mtime_ns}"
    return str(source)


def default_cache_dir(blend_path=None):
    """``<dir>/<stem>_nephele_cache`` beside a .blend, else ``$NEPHELE_CACHE`` or ``~/.cache/nephele``."""
    if blend_path:
        p = Path(blend_path)
        return p.parent / f"{p.stem}_nephele_cache"
    env = os.environ.get("NEPHELE_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "nephele"


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
