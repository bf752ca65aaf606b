"""One pass over a GRIB file's message headers (ecCodes), kept as an index in Nephele's cache.

An operational GRIB file is a stream of messages, one 2-D field each: every
variable on every level, member and step of a GFS or IFS product, next to
surface, tropopause, cloud-layer and other single-level fields.  The
:class:`GribIndex` reads each message's header once (``headers_only``, the data
sections are skipped) and keeps, per message, where it is and which field,
level, time and member it holds, as plain arrays.  The names ecCodes derives by
looking up its tables (``shortName``, ``units``, ``typeOfLevel``'s relatives)
are costly, a few milliseconds per message and lookup; they are looked up once
per *group* of messages with the same raw product keys (parameter numbers,
kind of level, statistical processing, grid), and only for the groups asked
about.

The index is saved in Nephele's cache (``<cache>/grib-index``, see
:func:`index_folder`), never beside the user's data, under a name made from the
file's path, size and modification time and this module's
:data:`INDEX_VERSION`: a changed file gets a new index, and writing it removes
the old one.  It is a ``.npz`` of plain arrays and JSON text, read with
``allow_pickle=False``.

Multi-field messages (GRIB2 messages holding several fields, NCEP's ``u`` and
``v`` together) are read with ecCodes' multi-field support and addressed as
(offset, field number), as cfgrib does.

References
----------
.. [1] ECMWF, ecCodes: https://confluence.ecmwf.int/display/ECC (keys, concepts, multi-field messages).
.. [2] ECMWF, cfgrib: https://github.com/ecmwf/cfgrib (``messages.py``: random access to multi-field messages).
"""

import contextlib
import hashlib
import json
import threading
from pathlib import Path

import numpy as np

from ..errors import DataError

INDEX_VERSION = 2
"""Bump when what the index holds changes; older index files are then ignored."""

_LOCK = threading.RLock()
"""ecCodes' multi-field switch is global: one message is opened at a time."""

_KEYS_1 = ("centre", "table2Version", "indicatorOfParameter", "timeRangeIndicator")
_KEYS_2 = ("centre", "discipline", "parameterCategory", "parameterNumber", "productDefinitionTemplateNumber",
           "typeOfStatisticalProcessing", "typeOfSecondFixedSurface")
CONCEPTS = ("shortName", "name", "units", "cfName")
"""ecCodes' table look-ups made once per group of messages (each costs milliseconds: only those Nephele uses)."""
LEVEL_AXES = frozenset({"isobaricInhPa", "isobaricInPa", "hybrid", "sigma", "theta", "potentialVorticity",
                        "heightAboveSea",
                        "generalVertical", "generalVerticalLayer", "hybridHeight", "hybridPressure", "snow", "soil"})
"""Kinds of level whose level value never changes a field's name (``2t`` versus ``t`` at 2 m does change it
on ``heightAboveGround``, so other kinds keep the level in the group key)."""


NCEP_GRIB1 = {153: ("clwmr", "Cloud mixing ratio"), 154: ("o3mr", "Ozone mixing ratio"),
              170: ("rwmr", "Rain mixing ratio"),
              171: ("snmr", "Snow mixing ratio"), 178: ("icmr", "Ice water mixing ratio")}
"""NCEP's GRIB1 parameter table 2 (Office Note 388) entries ecCodes 2.50 has no name for (in kg/kg): the
hydrometeor mixing ratios of GFS GRIB1 files, which ecCodes calls ``unknown``."""


def index_folder():
    """``<cache>/grib-index``: where index files live (:func:`~nephele.core.files.cache_folder`)."""
    from ..files import cache_folder

    return cache_folder("grib-index")


def need_eccodes(path):
    """The ``eccodes`` module, or one line saying how to install it."""
    try:
        import eccodes
    except (ImportError, RuntimeError, OSError) as exc:  # the wheel's library missing raises RuntimeError
        raise DataError(f"reading GRIB needs ecCodes ('pip install eccodes'): {exc}", path=path) from None
    return eccodes


@contextlib.contextmanager
def _multi(eccodes, f):
    """ecCodes' multi-field support on, from a clean state, for file ``f`` (cfgrib's ``multi_enabled``)."""
    eccodes.codes_grib_multi_support_on()
    eccodes.codes_grib_multi_support_reset_file(f)
    try:
        yield
    finally:
        eccodes.codes_grib_multi_support_off()


def _stamp(path):
    """``(resolved path, identity)``: the file's path, size and modification time, and the reader's code
    (what the index keeps, level heights included, was made by this code from this file)."""
    from ..files import file_stamp
    from ..pipeline.codehash import code_stamp

    return (Path(path).resolve(),
            f"{file_stamp(path)}|v{INDEX_VERSION}|{code_stamp(Path(__file__).with_name('grib.py'))}")


def _datetime(dates, times):
    """datetime64[s] of ecCodes' ``YYYYMMDD`` dates and ``hhmm`` times."""
    out = np.empty(len(dates), dtype="datetime64[s]")
    pairs = np.stack([np.asarray(dates, np.int64), np.asarray(times, np.int64)], axis=1)
    for (d, t), rows in zip(*_unique_rows(pairs), strict=True):
        out[rows] = np.datetime64(f"{d // 10000:04d}-{d // 100 % 100:02d}-{d % 100:02d}T{t // 100:02d}:{t % 100:02d}",
                                  "s")
    return out


def _unique_rows(a):
    keys, inverse = np.unique(a, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    return keys, [np.flatnonzero(inverse == i) for i in range(len(keys))]


class GribIndex:
    """Where each message of a GRIB file is and what it holds (see the module docstring).

    Attributes
    ----------
    path : str
    offset, field : (n,) int64 arrays
        Byte offset of each message and the field's number inside it (0 unless multi-field).
    group : (n,) int32 array
        Index into :attr:`groups` (messages with the same raw product keys).
    level : (n,) float64
        ecCodes' ``level`` (hPa for ``isobaricInhPa``, Pa for ``isobaricInPa``, the model level number for
        ``hybrid``, metres for heights).
    valid, ref : (n,) datetime64[s]
        Validity time (reference time + step) and reference time.
    number : (n,) int64
        Ensemble member (-1 where the message has none).
    groups : list of dict
        ``typeOfLevel``, ``grid`` (ecCodes' ``md5GridSection``), ``gridType``, ``edition``, ``raw`` (the raw keys)
        and ``first`` (a message of the group).
    notes : list of str
        What the scan skipped (a message cut short).
    """

    def __init__(self, path, arrays, groups, concepts=None, extras=None, notes=()):
        self.path = str(path)
        for name in ("offset", "field", "group", "level", "valid", "ref", "number"):
            setattr(self, name, arrays[name])
        self.groups = groups
        self._concepts = {int(k): v for k, v in (concepts or {}).items()}
        self.extras = dict(extras or {})
        """Arrays other modules keep with the index (grid positions), ``{name: array}``."""
        self.notes = list(notes)
        self._dirty = False
        self._file = None

    def __len__(self):
        return int(self.offset.size)

    # ------------------------------------------------------------------ reading messages
    def handle(self, i, headers_only=False):
        """An ecCodes handle of message ``i`` (the caller releases it); ``_LOCK`` must be held."""
        eccodes = need_eccodes(self.path)
        if self._file is None:
            self._file = open(self.path, "rb")
        f, field = self._file, int(self.field[i])
        f.seek(int(self.offset[i]))
        if field == 0:
            h = eccodes.codes_grib_new_from_file(f, headers_only=headers_only)
        else:
            with _multi(eccodes, f):
                for _ in range(field + 1):
                    h = eccodes.codes_grib_new_from_file(f, headers_only=headers_only)
        if h is None:
            raise DataError(f"message at byte {int(self.offset[i])} is missing (the file changed while open?)",
                            path=self.path)
        return h

    def values(self, i):
        """The data values of message ``i`` (float64, NaN where the bitmap says missing), as stored.  (ecCodes'
        float32 decoding is not implemented for every packing, IEEE among them.)"""
        eccodes = need_eccodes(self.path)
        with _LOCK:
            h = None
            try:
                h = self.handle(i)
                v = eccodes.codes_get_values(h)
                if eccodes.codes_get_long(h, "bitmapPresent"):
                    v = np.where(v == eccodes.codes_get_double(h, "missingValue"), np.nan, v)
            except (eccodes.CodesInternalError, OSError) as exc:
                raise DataError(f"cannot decode the message at byte {int(self.offset[i])} "
                                f"({type(exc).__name__}: {exc})", path=self.path) from None
            finally:
                if h is not None:
                    eccodes.codes_release(h)
        return v

    def get(self, i, keys, headers_only=True):
        """``{key: value}`` of message ``i`` (``None`` for keys it lacks; arrays for array keys)."""
        eccodes = need_eccodes(self.path)
        out = {}
        with _LOCK:
            h = self.handle(i, headers_only=headers_only)
            try:
                for key in keys:
                    try:
                        size = eccodes.codes_get_size(h, key)
                        out[key] = eccodes.codes_get_array(h, key) if size > 1 else eccodes.codes_get(h, key)
                    except eccodes.CodesInternalError:
                        out[key] = None
            finally:
                eccodes.codes_release(h)
        return out

    def concept(self, g, keys=CONCEPTS):
        """ecCodes' names of group ``g`` (``keys``, by default :data:`CONCEPTS`), each looked up once and kept
        with the index."""
        have = self._concepts.setdefault(g, {})
        missing = [k for k in keys if k not in have]
        if missing:
            have.update({k: (None if v is None else str(v))
                         for k, v in self.get(self.groups[g]["first"], missing).items()})
            raw = self.groups[g]["raw"]
            if have.get("shortName") == "unknown" and self.groups[g]["edition"] == 1 and raw[0] in ("kwbc", "7") \
                    and raw[1] in ("1", "2", "3") and int(raw[2]) in NCEP_GRIB1:
                short, name = NCEP_GRIB1[int(raw[2])]
                have.update(shortName=short, name=name, units="kg kg**-1")
            self._dirty = True
        return have

    def short_name(self, g):
        """ecCodes' ``shortName`` of group ``g``."""
        return self.concept(g, ("shortName",))["shortName"]

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None

    # ------------------------------------------------------------------ the cache
    def save(self):
        """Write the index to its cache file if it changed; a failure (read-only cache) becomes a note."""
        if not self._dirty:
            return
        try:
            p, stamp = _stamp(self.path)
            target = _index_file(p, stamp)
            meta = {"stamp": stamp, "groups": self.groups, "concepts": self._concepts, "notes": self.notes}
            arrays = {n: getattr(self, n) for n in ("offset", "field", "group", "level", "number")}
            arrays.update(valid=self.valid.astype(np.int64), ref=self.ref.astype(np.int64))
            arrays.update({f"x_{k}": v for k, v in self.extras.items()})
            from ..files import atomic_write

            with atomic_write(target, fsync=False) as tmp:
                np.savez(tmp, meta=np.array(json.dumps(meta)), **arrays)
            for old in target.parent.glob(target.name.split("-")[0] + "-*.npz"):
                if old != target:
                    old.unlink(missing_ok=True)
            self._dirty = False
        except OSError as exc:
            note = f"index: not saved in the cache ({exc.strerror or exc}); the next open scans the file again"
            if note not in self.notes:
                self.notes.append(note)

    def keep(self, name, array):
        """Keep ``array`` with the index under ``name`` (saved with it)."""
        self.extras[name] = np.asarray(array)
        self._dirty = True


def _index_file(resolved, stamp):
    who = hashlib.sha256(str(resolved).encode()).hexdigest()[:16]
    what = hashlib.sha256(stamp.encode()).hexdigest()[:16]
    return index_folder() / f"{who}-{what}.npz"


def _load(path, resolved, stamp):
    target = _index_file(resolved, stamp)
    if not target.is_file():
        return None
    try:
        with np.load(target, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("stamp") != stamp:
                return None
            arrays = {n: z[n] for n in ("offset", "field", "group", "level", "number")}
            arrays.update(valid=z["valid"].astype("datetime64[s]"), ref=z["ref"].astype("datetime64[s]"))
            extras = {k[2:]: z[k] for k in z.files if k.startswith("x_")}
    except (OSError, ValueError, KeyError):  # a torn or foreign file: scan again
        return None
    return GribIndex(path, arrays, meta["groups"], meta.get("concepts"), extras, meta.get("notes", ()))


def open_index(path):
    """The :class:`GribIndex` of ``path``: from the cache when the file is unchanged, else by one scan.

    Raises
    ------
    DataError
        ecCodes missing, or no readable GRIB message (not GRIB, or cut short before the first ended).
    """
    need_eccodes(path)
    resolved, stamp = _stamp(path)
    index = _load(path, resolved, stamp)
    if index is None:
        index = scan(path)
        index._dirty = True
        index.save()
    return index


def scan(path):
    """Read every message header of ``path`` once into a :class:`GribIndex` (not cached; see :func:`open_index`)."""
    eccodes = need_eccodes(path)
    rows, groups, keys_of, notes = [], [], {}, []
    with _LOCK, open(path, "rb") as f, _multi(eccodes, f):
        last, damaged = None, []
        while True:
            at = f.tell()
            try:
                h = eccodes.codes_grib_new_from_file(f, headers_only=True)
            except eccodes.CodesInternalError as exc:  # a message cut short or corrupted: skip it, keep the rest
                damaged.append(f"{at} ({type(exc).__name__})")
                if f.tell() <= at:
                    break
                continue
            if h is None:
                break
            try:
                row, gkey, info = _message(eccodes, h)
            except eccodes.CodesInternalError as exc:
                notes.append(f"scan: skipped an unreadable message at field {len(rows)} ({type(exc).__name__})")
                continue
            finally:
                eccodes.codes_release(h)
            row["field"] = row["field"] if row["offset"] != last else rows[-1]["field"] + 1
            last = row["offset"]
            g = keys_of.get(gkey)
            if g is None:
                g = keys_of[gkey] = len(groups)
                groups.append({**info, "first": len(rows)})
            row["group"] = g
            rows.append(row)
    if damaged:
        notes.append(f"scan: skipped {len(damaged)} damaged message(s) at byte {', '.join(damaged[:3])}"
                     + (" ..." if len(damaged) > 3 else ""))
    if not rows:
        why = f"no readable GRIB message; {notes[0][6:]}" if notes else "no GRIB message found: not GRIB"
        raise DataError(f"cannot open as GRIB ({why})", path=path)
    col = {k: np.array([r[k] for r in rows]) for k in ("offset", "field", "group", "level", "number")}
    arrays = {"offset": col["offset"].astype(np.int64), "field": col["field"].astype(np.int64),
              "group": col["group"].astype(np.int32),
              "level": col["level"].astype(np.float64), "number": col["number"].astype(np.int64),
              "valid": _datetime([r["vdate"] for r in rows], [r["vtime"] for r in rows]),
              "ref": _datetime([r["rdate"] for r in rows], [r["rtime"] for r in rows])}
    return GribIndex(path, arrays, groups, notes=notes)


def _get(eccodes, h, key, default=None):
    try:
        return eccodes.codes_get(h, key)
    except eccodes.CodesInternalError:
        return default


def _message(eccodes, h):
    """``(row, group key, group info)`` of one message handle."""
    edition = eccodes.codes_get_long(h, "edition")
    raw = [_get(eccodes, h, k) for k in (_KEYS_1 if edition == 1 else _KEYS_2)]
    level_type = str(_get(eccodes, h, "typeOfLevel", "unknown"))
    level = float(_get(eccodes, h, "level", 0) or 0)
    grid = str(_get(eccodes, h, "md5GridSection", ""))
    info = {"typeOfLevel": level_type, "grid": grid, "gridType": str(_get(eccodes, h, "gridType", "unknown")),
            "edition": int(edition), "raw": [None if v is None else str(v) for v in raw]}
    gkey = (edition, tuple(info["raw"]), level_type, grid, None if level_type in LEVEL_AXES else level)
    number = _get(eccodes, h, "number")
    row = {"offset": int(eccodes.codes_get_long(h, "offset")), "field": 0, "level": level,
           "number": -1 if number is None else int(number),
           "vdate": int(_get(eccodes, h, "validityDate", 0)), "vtime": int(_get(eccodes, h, "validityTime", 0)),
           "rdate": int(_get(eccodes, h, "dataDate", 0)), "rtime": int(_get(eccodes, h, "dataTime", 0))}
    return row, gkey, info


__all__ = ["CONCEPTS", "GribIndex", "INDEX_VERSION", "LEVEL_AXES", "index_folder", "open_index", "scan"]
