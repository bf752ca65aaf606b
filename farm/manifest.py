"""``OUT/manifest.json``: what a run produced, frame by frame, written atomically.

Layout::

    {"version": 1, "run": {...settings, started, finished, failed...},
     "frames": {"1": {"status": "ok", "file": "frame_0001.png", "seconds": 0.8,
                      "worker": "tcp://...", "size": 1551, "mtime_ns": ..., "sha256": "...",
                      "attempts": 1, "log": "logs/frame_0001.log"}, ...}}

A multi-view (stereo) frame has, instead of ``file``/``size``/``mtime_ns``/``sha256``,
``"views": {"_L": {"file": "frame_0001_L.png", "size": ..., "mtime_ns": ..., "sha256": ...},
"_R": {...}}``; ``run["views"]`` lists the run's view suffixes (``[""]`` for one view).

Only the client writes it (one writer), through a temp file and ``os.replace``,
so a crash leaves the previous complete manifest.
"""

import json
import os
import time
from pathlib import Path

from ..core.files import atomic_write
from .frames import InvalidFrame, check_image, frame_name, sha256_file

VERSION = 1
NAME = "manifest.json"


class Manifest:
    """The run manifest of an output directory."""

    def __init__(self, out_dir):
        self.out_dir = Path(out_dir)
        self.path = self.out_dir / NAME
        self.run = {}
        self.frames = {}
        self._saved = 0.0
        self.warning = None
        """What :meth:`load` had to do with a manifest it could not read (None when it read)."""

    @classmethod
    def load(cls, out_dir, move_aside=True):
        """Read ``OUT/manifest.json``; a missing one gives an empty manifest.

        One that cannot be read (damaged, or another version) is moved aside (``move_aside``) as
        ``manifest.json.bad-<UTC time>``, keeping its history, and
        :attr:`warning` says so; the frames on disk are then checked and adopted
        as :func:`classify` does for any frame the manifest does not list.
        """
        m = cls(out_dir)
        try:
            text = m.path.read_text()
        except FileNotFoundError:
            return m
        except (OSError, UnicodeDecodeError) as exc:
            problem = f"cannot be read ({exc})"
        else:
            problem = m._parse(text)
        if problem and not move_aside:
            m.warning = f"{m.path}: {problem}"
        elif problem:
            bad = m.path.with_name(f"{NAME}.bad-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}")
            try:
                os.replace(m.path, bad)
                kept = f"moved aside as {bad.name}"
            except OSError as exc:
                kept = f"left in place ({exc.strerror or exc})"
            m.warning = (f"{m.path}: {problem}; {kept}; the frames on disk are checked again and kept where whole")
        return m

    def _parse(self, text):
        """Fill from the manifest's text; the problem in words, or None when it reads."""
        try:
            data = json.loads(text)
        except ValueError as exc:
            return f"is not valid JSON ({exc})"
        if not isinstance(data, dict) or data.get("version") != VERSION:
            version = data.get("version") if isinstance(data, dict) else None
            return f"has version {version!r}, this Nephele reads version {VERSION}"
        try:
            self.run = dict(data.get("run") or {})
            self.frames = {str(int(k)): dict(v) for k, v in (data.get("frames") or {}).items()}
        except (TypeError, ValueError, AttributeError) as exc:
            self.run, self.frames = {}, {}
            return f"has a damaged frame list ({exc})"
        return None

    def entry(self, frame):
        return self.frames.get(str(frame))

    def set(self, frame, entry):
        self.frames[str(frame)] = entry

    def to_dict(self):
        frames = dict(sorted(self.frames.items(), key=lambda kv: int(kv[0])))
        return {"version": VERSION, "run": self.run, "frames": frames}

    def save(self, min_interval=0.0):
        """Write atomically; with ``min_interval`` skip if saved less than that many seconds ago."""
        now = time.monotonic()
        if min_interval and now - self._saved < min_interval:
            return
        with atomic_write(self.path) as tmp, open(tmp, "w") as f:
            json.dump(self.to_dict(), f, indent=1)
        self._saved = now


def file_entry(path, **extra):
    """A manifest entry for a frame file already on disk and valid."""
    return {"status": "ok", **_file_record(path), **extra}


def _file_record(path):
    st = os.stat(path)
    return {"file": os.path.basename(path), "size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": sha256_file(path)}


def views_entry(paths, views, **extra):
    """A manifest entry for a multi-view frame whose files (one per view suffix) are on disk and valid."""
    return {"status": "ok", "views": {v: _file_record(p) for v, p in zip(views, paths)}, **extra}


def entry_files(entry, views):
    """``[(view, record)]`` of an ``ok`` entry for ``views``; None when the entry is not for them."""
    if not entry or entry.get("status") != "ok":
        return None
    if tuple(views) == ("",):
        return [("", entry)] if "file" in entry else None
    recorded = entry.get("views") or {}
    if set(recorded) != set(views):
        return None
    return [(v, recorded[v]) for v in views]


def _matches(record, name, st, path, verify):
    return (
        record.get("file") == name
        and record.get("size") == st.st_size
        and record.get("mtime_ns") == st.st_mtime_ns
        and st.st_size > 0
        and (not verify or record.get("sha256") == sha256_file(path))
    )


def classify(manifest, frames, fmt, verify=False, views=("",)):
    """Split ``frames`` into those already valid on disk and those to render.

    A frame is valid when, for every view (``views``: file suffixes, ``("",)``
    for one view, ``("_L", "_R")`` for stereo), the manifest records the file
    as ``ok`` and its size and mtime match (``verify`` also compares the
    sha256).  A frame whose files are all on disk but not (or no longer)
    matching the manifest is checked with
    :func:`~nephele.farm.frames.check_image` and adopted when every file is
    whole.  A frame with any view missing, zero-byte or corrupt is to render
    (all its views).  The manifest is updated in memory: adopted frames get
    an entry, re-rendered ones lose theirs.

    Returns
    -------
    done, todo : list of int
    """
    views = tuple(views)
    done, todo = [], []
    for f in frames:
        paths = [manifest.out_dir / frame_name(f, fmt, v) for v in views]
        try:
            stats = [os.stat(p) for p in paths]
        except FileNotFoundError:
            todo.append(f)
            manifest.frames.pop(str(f), None)
            continue
        records = entry_files(manifest.entry(f), views)
        if records and all(_matches(r, p.name, st, p, verify) for (_, r), p, st in zip(records, paths, stats)):
            done.append(f)
            continue
        try:
            for p in paths:
                check_image(p)
        except (InvalidFrame, OSError):
            todo.append(f)
            manifest.frames.pop(str(f), None)
            continue
        extra = dict(seconds=None, worker=None, attempts=0, adopted=True)
        manifest.set(f, file_entry(paths[0], **extra) if views == ("",) else views_entry(paths, views, **extra))
        done.append(f)
    return done, todo
