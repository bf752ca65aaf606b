"""GrADS gridded binary files: a ``.ctl`` descriptor and its ``.dat`` data, read lazily.

Understood descriptor entries: ``DSET`` (``^`` = the descriptor's directory),
``UNDEF``, ``TITLE``, ``OPTIONS`` (``little_endian``, ``big_endian``,
``yrev``, ``zrev``), ``XDEF``/``YDEF`` (``LINEAR`` or ``LEVELS``), ``ZDEF``
(``LEVELS`` or ``LINEAR``), ``TDEF n LINEAR start step`` (``mn``, ``hr``,
``dy``, ``mo``, ``yr``), ``VARS``…``ENDVARS`` and ``FILEHEADER``.  The data is
sequential float32 records of ``nx × ny`` (x fastest): per time, per
variable, one record per level (``0`` levels = one surface record).

Levels are taken as pressure in hPa when ``ZDEF`` decreases upward (the
usual GrADS model output), as heights in metres when it increases (or as
chosen with ``vertical=``).  Pressure levels get heights from the mean of a
geopotential-height variable ``Z``/``HGT`` in the first step when there is
one, else from the standard atmosphere; they are flat, not terrain
following, so values below the ground are ``UNDEF`` in the file and NaN
here.  A variable with fewer levels than ``ZDEF`` (the sample's ``Q``: 5 of 7)
holds the lowest ones; the rest are NaN.  2-D variables (``levs = 0``) are
listed in ``skipped``.

References
----------
.. [1] GrADS documentation, "Elements of a GrADS Data Descriptor File",
   http://cola.gmu.edu/grads/gadoc/descriptorfile.html
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import re
from pathlib import Path

import numpy as np

from ..errors import DataError
from .grid import GlobeGrid
from .gridfile import FileDataset, standard_name, tidy_lonlat
from .humidity import RH_CRIT, standard_height

_MONTHS = {m: i + 1 for i, m in enumerate("jan feb mar apr may jun jul aug sep oct nov dec".split())}
_STEP_SECONDS = {"mn": 60, "hr": 3600, "dy": 86400}
_UNITS = {"u": "m/s", "v": "m/s", "w": "m/s", "temperature": "K", "q": "kg/kg", "z": "m", "hgt": "m", "rh": "1",
          "cloud": "1"}


MAX_AXIS = 10**7
"""Most values one axis may claim: a global grid at 4 m spacing has fewer; more is a damaged descriptor,
refused before an axis of that length is allocated."""


def _count(words, i, path, field, low=1):
    """The whole number ``words[i]`` within ``low..MAX_AXIS``; DataError otherwise."""
    try:
        n = int(words[i])
    except (IndexError, ValueError):
        raise DataError(f"expected a whole number after {field.upper()}, got {' '.join(words)!r}", path=path,
                        field=field) from None
    if not low <= n <= MAX_AXIS:
        raise DataError(f"claims {n} values; expected {low} to {MAX_AXIS:,}", path=path, field=field)
    return n


def _axis(words, n, path, field):
    """Coordinates from ``XDEF n LINEAR start step`` or ``... LEVELS v1 v2 ...``."""
    kind = words[0].lower() if words else ""
    try:
        if kind == "linear":
            start, step = float(words[1]), float(words[2])
            return start + step * np.arange(n)
        if kind == "levels":
            vals = np.array([float(w) for w in words[1:]], dtype=np.float64)
            if vals.size < n:
                raise DataError(f"lists {vals.size} levels, expected {n}", path=path, field=field)
            return vals[:n]
    except (IndexError, ValueError) as exc:
        raise DataError(f"cannot read {' '.join(words)!r} ({exc})", path=path, field=field) from exc
    raise DataError(f"mapping {kind or '(none)'!r} is not supported (LINEAR or LEVELS)", path=path, field=field)


def parse_time(text, path, field="tdef"):
    """A GrADS absolute time: ``[hh[:mm]Z][dd]mmmyyyy``, e.g. ``00Z02JAN1987``, ``02JAN1987``, ``JAN1987``."""
    m = re.fullmatch(r"(?:(\d{1,2})(?::(\d{2}))?z)?(\d{1,2})?([a-z]{3})(\d{4}|\d{2})", text.strip().lower())
    if not m or m.group(4) not in _MONTHS:
        raise DataError(f"cannot read the time {text!r}", path=path, field=field)
    hh, mm, dd, mon, yy = m.groups()
    year = int(yy) if len(yy) == 4 else (1900 + int(yy) if int(yy) >= 50 else 2000 + int(yy))
    return np.datetime64(f"{year:04d}-{_MONTHS[mon]:02d}-{int(dd or 1):02d}T{int(hh or 0):02d}:{int(mm or 0):02d}", "s")


def grads_times(n, start, step, path):
    """``n`` times from a GrADS start and step such as ``6hr``, ``1dy``, ``1mo``."""
    t0 = parse_time(start, path)
    m = re.fullmatch(r"(\d+)(mn|hr|dy|mo|yr)", step.strip().lower())
    if not m:
        raise DataError(f"cannot read the time step {step!r} (e.g. 6hr, 1dy, 1mo)", path=path, field="tdef")
    k, unit = int(m.group(1)), m.group(2)
    if k <= 0:
        raise DataError(f"time step {step!r} must be positive", path=path, field="tdef")
    if unit in _STEP_SECONDS:
        return t0 + np.arange(n) * np.timedelta64(k * _STEP_SECONDS[unit], "s")
    months = np.arange(n) * k * (12 if unit == "yr" else 1)
    within = t0 - t0.astype("datetime64[M]").astype("datetime64[s]")
    return (t0.astype("datetime64[M]") + months).astype("datetime64[s]") + within


def parse_ctl(path):
    """Read a ``.ctl`` descriptor into a dict (see the module docstring for the entries)."""
    path = Path(path)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise DataError(f"cannot read ({exc.strerror})", path=path) from exc
    ctl = {"options": set(), "vars": [], "fileheader": 0}
    it = iter(lines)
    for line in it:
        words = line.split()
        if not words or words[0].startswith("*") or words[0].startswith("@"):
            continue
        key = words[0].lower()
        if key == "dset":
            if len(words) < 2:
                raise DataError("DSET names no data file", path=path, field="dset")
            name = line.split(None, 1)[1].strip()
            ctl["dset"] = path.parent / name[1:].lstrip("/") if name.startswith("^") else Path(name)
        elif key == "undef":
            try:
                ctl["undef"] = float(words[1])
            except (IndexError, ValueError):
                raise DataError(f"cannot read {line.strip()!r}", path=path, field="undef") from None
        elif key == "title":
            ctl["title"] = line.split(None, 1)[1].strip() if len(words) > 1 else ""
        elif key == "options":
            ctl["options"].update(w.lower() for w in words[1:])
        elif key == "fileheader":
            if len(words) < 2 or not words[1].isdigit():
                raise DataError(f"expected a byte count, got {line.strip()!r}", path=path, field="fileheader")
            ctl["fileheader"] = int(words[1])
        elif key in ("xdef", "ydef", "zdef"):
            n = _count(words, 1, path, key)
            rest = words[2:]
            # LEVELS may continue on the next lines.
            if rest and rest[0].lower() == "levels":
                while len(rest) - 1 < n:
                    more = next(it, None)
                    if more is None:
                        break
                    rest += more.split()
            ctl[key] = _axis(rest, n, path, key)
        elif key == "tdef":
            if len(words) < 5 or words[2].lower() != "linear":
                raise DataError(f"expected 'TDEF n LINEAR start step', got {line.strip()!r}", path=path, field="tdef")
            ctl["tdef"] = grads_times(_count(words, 1, path, "tdef"), words[3], words[4], path)
        elif key == "vars":
            count = _count(words, 1, path, "vars")
            for _ in range(count):
                vline = next(it, None)
                if vline is None or not vline.split() or vline.split()[0].lower() == "endvars":
                    raise DataError(f"VARS says {count} variables but fewer are listed", path=path, field="vars")
                v = vline.split()
                try:
                    levs = int(v[1].split(",")[0])
                except (IndexError, ValueError) as exc:
                    raise DataError(f"cannot read variable line {vline.strip()!r}", path=path, field=v[0]) from exc
                ctl["vars"].append((v[0], levs, " ".join(v[3:]) if len(v) > 3 else ""))
        elif key in ("pdef", "chsub", "xyheader", "theader", "unpack", "stnmap"):
            raise DataError(f"descriptor entry {words[0].upper()} is not supported", path=path, field=key)
    for key in ("dset", "xdef", "ydef", "zdef", "tdef"):
        if key not in ctl:
            raise DataError(f"descriptor has no {key.upper()} entry", path=path, field=key)
    if not ctl["vars"]:
        raise DataError("descriptor lists no variables (VARS ... ENDVARS)", path=path, field="vars")
    bad = {"template", "sequential", "365_day_calendar"} & ctl["options"]
    if bad:
        raise DataError(f"OPTIONS {', '.join(sorted(bad))} not supported", path=path, field="options")
    return ctl


class GradsDataset(FileDataset):
    """A GrADS ``.ctl``/``.dat`` pair, memory-mapped and read one step at a time.

    Parameters
    ----------
    path : path to the ``.ctl``
    vertical : {"auto", "pressure", "height"}
        How to read ``ZDEF`` (see the module docstring).
    rh_crit : float or (nk,) array
        Critical humidity of the derived Sundqvist cloud fraction.
    """

    def __init__(self, path, *, vertical="auto", rh_crit=RH_CRIT, cache_steps=8):
        path = Path(path)
        ctl = parse_ctl(path)
        self.ctl = ctl
        self.title = ctl.get("title", "")
        data = ctl["dset"]
        if not data.is_file():
            raise DataError(f"data file {data} (DSET) not found", path=path, field="dset")
        nx, ny, nz, nt = ctl["xdef"].size, ctl["ydef"].size, ctl["zdef"].size, ctl["tdef"].size
        endian = ">" if "big_endian" in ctl["options"] else "<"
        self._records = {}
        rec = 0
        for name, levs, _ in ctl["vars"]:
            if levs > nz:
                raise DataError(f"has {levs} levels but ZDEF has {nz}", path=path, field=name)
            self._records[name] = (rec, levs)
            rec += max(levs, 1)
        per_time = rec
        need = ctl["fileheader"] + 4 * nx * ny * per_time * nt
        size = data.stat().st_size
        if size < need:
            raise DataError(f"is {size} bytes, the descriptor needs {need} (wrong dimensions?)", path=data,
                            field="dset")
        self._data = np.memmap(data, dtype=endian + "f4", mode="r", offset=ctl["fileheader"],
                               shape=(nt, per_time, ny, nx))
        self._undef = ctl.get("undef")
        lat_file = ctl["ydef"][::-1] if "yrev" in ctl["options"] else ctl["ydef"]
        lon, lat, lon_index, lat_index = tidy_lonlat(ctl["xdef"], lat_file, path, "xdef", "ydef")
        z = ctl["zdef"]
        if nz < 2:
            raise DataError(f"needs at least 2 levels, got {nz}", path=path, field="zdef")
        if not np.all(np.isfinite(z)):
            raise DataError("has NaN levels", path=path, field="zdef")
        d = np.diff(z)
        if not (np.all(d > 0) or np.all(d < 0)):
            raise DataError("levels are not monotonic (non-monotonic levels)", path=path, field="zdef")
        kind = vertical if vertical != "auto" else ("pressure" if d[0] < 0 else "height")
        if kind not in ("pressure", "height"):
            raise DataError(f"vertical must be 'auto', 'pressure' or 'height', got {vertical!r}", path=path,
                            field="zdef")
        upward = -z if kind == "pressure" else z
        level_index = np.arange(nz) if upward[1] > upward[0] else np.arange(nz)[::-1]
        self._zrev = "zrev" in ctl["options"]
        if self._zrev and any(0 < levs < nz for _, levs, _ in ctl["vars"]):
            raise DataError("OPTIONS zrev with variables on fewer levels than ZDEF is not supported", path=path,
                            field="options")
        fields, skipped = {}, {}
        for name, levs, desc in ctl["vars"]:
            if levs == 0:
                skipped[name] = "2-D (surface) variable"
                continue
            std = standard_name(name)
            if std in fields:
                skipped[name] = f"another variable already gives {std!r}"
                continue
            fields[std] = (name, _UNITS.get(std.lower(), ""), desc)
        self._nz = nz
        order = (level_index, lat_index, lon_index)
        z = z[level_index]
        if kind == "pressure":
            p = z * 100.0
            heights, source = self._mean_heights(fields, order), "mean geopotential height"
            if heights is None:
                heights, source = standard_height(p), "standard atmosphere"
            p3 = np.broadcast_to(p[:, None, None], (nz, lat.size, lon.size)).astype(np.float32)
            pressure, desc = (lambda t: p3), f"pressure levels, heights from the {source} (not terrain following)"
        else:
            heights, pressure, desc = z, None, "height levels (flat)"
        grid = GlobeGrid(lon, lat,
                         np.broadcast_to(np.asarray(heights)[:, None, None], (nz, lat.size, lon.size))).validate(path)
        super().__init__(path, grid, ctl["tdef"], fields, order, pressure=pressure, rh_crit=rh_crit, vertical=desc,
                         skipped=skipped, cache_steps=cache_steps)

    def _mean_heights(self, fields, order):
        for std in ("z", "hgt", "Z"):
            if std in fields:
                raw = self._raw(fields[std][0], 0)[np.ix_(*order)]
                if np.isnan(raw).all(axis=(1, 2)).any():
                    return None
                with np.errstate(invalid="ignore"):
                    mean = np.nanmean(raw.reshape(raw.shape[0], -1), axis=1)
                return mean if np.all(np.diff(mean) > 0) else None
        return None

    def _raw(self, name, t):
        rec, levs = self._records[name]
        nt, _, ny, nx = self._data.shape
        out = np.full((self._nz, ny, nx), np.nan, dtype=np.float32)
        block = np.array(self._data[t, rec : rec + levs], dtype=np.float32)
        if self._undef is not None:
            block[np.isclose(block, self._undef, rtol=1e-6, atol=0.0)] = np.nan
        out[:levs] = block[::-1] if self._zrev else block  # in ZDEF order; FileDataset reorders
        return out


def open_grads(path, **kw):
    """Open a GrADS ``.ctl`` descriptor as a lazy :class:`GradsDataset`."""
    return GradsDataset(path, **kw)


__all__ = ["GradsDataset", "open_grads", "parse_ctl", "parse_time"]
