"""Shared machinery of the file readers (NetCDF, GrADS): names, axis order, units, derived fields.

A file's fields are mapped onto Nephele's standard names (see
:mod:`nephele.core.climate.dataset`), its axes put into the ``(level, lat, lon)``
order with level 0 at the bottom, latitude ascending and longitude ascending
in [0, 360), and missing fields derived where possible:

* ``pressure`` (Pa) from the vertical coordinate (pressure or hybrid levels);
* ``rh`` from ``temperature``, ``q`` and ``pressure`` (:func:`~nephele.core.climate.humidity.relative_humidity`);
* ``cloud`` from ``rh`` by the Sundqvist (1989) scheme (:func:`~nephele.core.climate.humidity.sundqvist_cloud`).

Relative humidity, read or derived, is clipped to [0, 1]: files on pressure
levels hold values outside it (ECHAM5's ``rhumidity`` spans −0.14…1.26)
because of vertical interpolation and supersaturation over ice; a fraction of
the sky cannot be negative or above one.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
.. [2] H. Sundqvist et al., Mon. Wea. Rev. 117 (1989) 1641–1657.
"""

import abc
import re

import numpy as np

from ..errors import DataError
from .dataset import Dataset, Variable
from .humidity import RH_CRIT, relative_humidity, sundqvist_cloud

# Lower-case file names (CF, ECMWF/ERA, ECHAM, NCEP, GrADS, CMIP, MERRA-2, WRF, CAM) → standard name.
ALIASES = {
    "cloud": ("cloud", "cc", "clc", "cl", "aclcac", "cldfrac", "cldfra", "cloud_fraction", "cloudiness", "cfrac",
              "tcc"),
    "cloud_water": ("cloud_water", "clwmr", "clwc", "clw", "ql", "qcloud", "qc", "cldliq", "cloud_liquid_water"),
    "cloud_ice": ("cloud_ice", "icmr", "ciwc", "cli", "qi", "qice", "cldice", "cloud_ice_water"),
    "temperature": ("t", "ta", "temp", "air", "temperature", "air_temperature", "tk"),
    "u": ("u", "ua", "uwnd", "u_wind", "uas3d", "eastward_wind"),
    "v": ("v", "va", "vwnd", "v_wind", "northward_wind"),
    "w": ("w", "wa", "upward_air_velocity"),
    "omega": ("omega", "wap", "vvel"),
    "rh": ("rh", "hur", "rhum", "rhumidity", "relhum", "relative_humidity", "r"),
    "q": ("q", "hus", "shum", "qv", "specific_humidity"),
}
STANDARD_NAMES = {
    "cloud_area_fraction_in_atmosphere_layer": "cloud",
    "mass_fraction_of_cloud_liquid_water_in_air": "cloud_water",
    "cloud_liquid_water_mixing_ratio": "cloud_water",
    "mass_fraction_of_cloud_ice_in_air": "cloud_ice",
    "cloud_ice_mixing_ratio": "cloud_ice",
    "air_temperature": "temperature",
    "eastward_wind": "u",
    "northward_wind": "v",
    "upward_air_velocity": "w",
    "lagrangian_tendency_of_air_pressure": "omega",
    "relative_humidity": "rh",
    "specific_humidity": "q",
}
UNITS = {"cloud": "1", "cloud_water": "kg/kg", "cloud_ice": "kg/kg", "temperature": "K", "u": "m/s", "v": "m/s",
         "w": "m/s", "omega": "Pa/s", "rh": "1", "q": "kg/kg", "pressure": "Pa"}
_PER_TIME_PRESSURE = ("pas-1", "pa/s", "pas**-1", "pa.s-1", "hpas-1", "hpa/s", "mb/s")


def standard_name(name, attrs=None):
    """Nephele's name for a file variable (its CF ``standard_name`` first, then known aliases), or the name itself.

    A vertical velocity in pressure per time (``w`` in Pa/s, as in ECMWF and
    NCEP files) is ``omega``, not the upward wind ``w``.
    """
    attrs = attrs or {}
    std = str(attrs.get("standard_name", "")).strip().lower()
    if std in STANDARD_NAMES:
        return STANDARD_NAMES[std]
    low = name.lower()
    for std_name, names in ALIASES.items():
        if low in names:
            if std_name == "w" and str(attrs.get("units", "")).strip().lower().replace(" ", "") in _PER_TIME_PRESSURE:
                return "omega"
            return std_name
    return name


def meaning_aliases(std):
    """Every name a field of standard name ``std`` answers to: its known file names and CF standard names."""
    return tuple(ALIASES.get(std, ())) + tuple(cf for cf, s in STANDARD_NAMES.items() if s == std)


def unit_conversion(std, units):
    """``(scale, offset)`` turning a file's ``units`` into Nephele's units for field ``std``."""
    u = (units or "").strip().lower().replace(" ", "")
    if std == "temperature":
        if u in ("c", "degc", "celsius", "deg_c", "degreesc", "degrees_celsius"):
            return 1.0, 273.15
        return 1.0, 0.0
    if std in ("rh", "cloud") and u in ("%", "percent"):
        return 0.01, 0.0
    if std in ("q", "cloud_water", "cloud_ice") and u in ("g/kg", "gkg-1", "gkg**-1"):
        return 0.001, 0.0
    if std == "pressure" and u in ("hpa", "mb", "mbar", "millibar", "millibars"):
        return 100.0, 0.0
    return 1.0, 0.0


def plausible_units(std, units, sample):
    """``(units, note)``: the units a field's values really have when the stated ones are implausible.

    A temperature labelled Celsius whose median is above 150 is kelvin (NCL's
    ``nc4uvt.nc`` labels 200–300 values ``C``); a fraction whose maximum is
    above 2 is percent.  ``note`` is ``None`` when the stated units stand.
    """
    a = np.asarray(sample, dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return units, None
    scale, offset = unit_conversion(std, units)
    if std == "temperature" and offset != 0.0 and np.median(a) > 150.0:
        return "K", f"{std}: units {units!r} but values {a.min():.4g}..{a.max():.4g} are kelvin; read as K"
    if std in ("rh", "cloud") and scale == 1.0 and np.max(a) > 2.0:
        return "%", f"{std}: units {units or 'none'!r} but values reach {a.max():.4g}; read as percent"
    return units, None


def pressure_scale(units, path, field):
    """Factor from pressure ``units`` to Pa; :class:`DataError` for non-pressure units."""
    u = (units or "").strip().lower()
    if u in ("pa", "pascal", "pascals"):
        return 1.0
    if u in ("hpa", "mb", "mbar", "millibar", "millibars", "hectopascal", "hectopascals"):
        return 100.0
    if u in ("kpa",):
        return 1000.0
    raise DataError(f"has units {units!r}, not a pressure (Pa or hPa)", path=path, field=field)


def tidy_lonlat(lon, lat, path, lon_name="lon", lat_name="lat"):
    """Index arrays that put latitudes ascending and longitudes ascending in [0, 360).

    Returns ``lon_sorted, lat_sorted, lon_index, lat_index``; a repeated seam
    column (the same meridian at both ends) is left out.
    """
    lon = np.asarray(lon, dtype=np.float64)
    lat = np.asarray(lat, dtype=np.float64)
    for name, c in ((lon_name, lon), (lat_name, lat)):
        if c.ndim != 1:
            raise DataError(f"is {c.ndim}-D; only rectilinear longitude × latitude grids are read", path=path,
                            field=name)
        if c.size < 2:
            raise DataError(f"needs at least 2 values, got {c.size}", path=path, field=name)
        if not np.all(np.isfinite(c)):
            raise DataError("has NaN coordinates", path=path, field=name)
    d = np.diff(lat)
    if np.all(d > 0):
        lat_index = np.arange(lat.size)
    elif np.all(d < 0):
        lat_index = np.arange(lat.size)[::-1]
    else:
        raise DataError("latitudes are not monotonic", path=path, field=lat_name)
    wrapped = np.mod(lon, 360.0)
    lon_index = np.argsort(wrapped, kind="stable")
    sorted_lon = wrapped[lon_index]
    step = np.median(np.diff(sorted_lon)) if lon.size > 1 else 0.0
    keep = np.concatenate([[True], np.diff(sorted_lon) > 1e-6 * max(step, 1e-9)])
    lon_index, sorted_lon = lon_index[keep], sorted_lon[keep]
    if sorted_lon.size > 2 and sorted_lon[-1] - sorted_lon[0] > 360.0 - 1e-6 * step:
        lon_index, sorted_lon = lon_index[:-1], sorted_lon[:-1]
    # A regional grid crossing 0° (e.g. 350..10 °E) stays contiguous: start after the widest gap.
    gaps = np.diff(np.concatenate([sorted_lon, [sorted_lon[0] + 360.0]]))
    start = (int(np.argmax(gaps)) + 1) % sorted_lon.size
    if gaps.max() > 1.5 * step and start != 0:
        lon_index = np.roll(lon_index, -start)
        sorted_lon = np.roll(sorted_lon, -start)
        sorted_lon = np.where(np.arange(sorted_lon.size) >= sorted_lon.size - start, sorted_lon + 360.0, sorted_lon)
        sorted_lon = sorted_lon - 360.0 * (sorted_lon[0] >= 180.0)
    return sorted_lon, lat[lat_index], lon_index, lat_index


class FileDataset(Dataset):
    """A dataset read from a file: subclasses provide :meth:`_raw`, this class the rest.

    Parameters
    ----------
    path : path
    grid : GlobeGrid
    times : datetime64 array
    fields : dict
        standard name → ``(file name, units in the file[, description])``: the 3-D fields.
    order : (level_index, lat_index, lon_index)
        Index arrays from file order to Nephele's order.
    pressure : callable or None
        ``pressure(t)`` → Pa, ``(nk, nj, ni)`` in Nephele's order, for
        pressure-based vertical coordinates.
    rh_crit : float or (nk,) array
        Critical relative humidity for the derived cloud fraction.
    vertical : str
        Kind of levels, for ``nephele info``.
    skipped : dict
        File variables that are not 3-D fields on the grid → reason.
    notes : list of str
        What the reader assumed where the file was silent or implausible
        (a default ``P0``, step indices for a non-CF time axis, a ``degC``
        field holding kelvin); ``nephele info`` prints them.

    Every field can also be read by the file's own name (``ds.read("T", 0)``
    is ``ds.read("temperature", 0)``).
    """

    def __init__(self, path, grid, times, fields, order, *, pressure=None, rh_crit=RH_CRIT, vertical="", skipped=None,
                 notes=(), cache_steps=8):
        self.path = str(path)
        self.notes = list(notes)
        self._fields = dict(fields)
        self._order = tuple(np.asarray(o) for o in order)
        self._take = _take(self._order)
        self._pressure = pressure
        self.vertical = vertical
        self.skipped = dict(skipped or {})
        self.derived = {}
        variables = []
        self.file_names = {}
        for std, (raw, units, *about) in self._fields.items():
            units_out = UNITS.get(std, units or "")
            variables.append(Variable(std, units_out, about[0] if about else ""))
            self.file_names[std] = raw
        names = set(self._fields)
        if pressure is not None:
            variables.append(Variable("pressure", "Pa", "from the vertical coordinate"))
            self.derived["pressure"] = "vertical coordinate"
            names.add("pressure")
        if "rh" not in names and {"temperature", "q", "pressure"} <= names:
            variables.append(Variable("rh", "1", "relative humidity from T, q, p (Bolton 1980)"))
            self.derived["rh"] = "T, q, p (Bolton 1980)"
            names.add("rh")
        if "cloud" not in names and "rh" in names:
            variables.append(Variable("cloud", "1", "cloud fraction from RH (Sundqvist 1989)"))
            self.derived["cloud"] = f"rh, Sundqvist (1989), RH_crit={_fmt_crit(rh_crit)}"
        nk = grid.shape[0]
        self.rh_crit = (np.broadcast_to(np.asarray(rh_crit, dtype=np.float64), (nk,)).reshape(nk, 1, 1)
                        if np.ndim(rh_crit)
                        else float(rh_crit))
        super().__init__(grid, times, variables, path, cache_steps)
        # A file name that is another standard name (GRIB's w in Pa/s is omega) never stands for it: code asking
        # for "w" means the upward wind in m/s.
        self.aliases = {raw: std for std, raw in self.file_names.items() if raw != std and raw not in self.variables
                        and raw not in UNITS}
        for std in self.variables:  # by meaning: --var clwmr and --var cloud_water reach the same field in any file
            for alias in meaning_aliases(std):
                if alias not in self.variables:
                    self.aliases.setdefault(alias, std)

    @abc.abstractmethod
    def _raw(self, name, t):
        """Step ``t`` of file variable ``name`` in file order, float, missing values as NaN."""

    def _read(self, name, t):
        if name in self._fields:
            raw, units = self._fields[name][:2]
            a = np.asarray(self._raw(raw, t), dtype=np.float32)
            a = a[self._take]
            scale, offset = unit_conversion(name, units)
            if scale != 1.0 or offset != 0.0:
                a = a * np.float32(scale) + np.float32(offset)
            if name in ("rh", "cloud"):
                a = np.clip(a, 0.0, 1.0)
            return a
        if name == "pressure":
            return self._pressure(t)
        if name == "rh":
            with np.errstate(invalid="ignore", over="ignore"):
                rh = relative_humidity(self.read("temperature", t), self.read("q", t), self.read("pressure", t))
            return np.clip(rh, 0.0, 1.0)
        if name == "cloud":
            return sundqvist_cloud(self.read("rh", t), self.rh_crit)
        raise DataError("no such variable", path=self.path, field=name)


def _take(order):
    """An index into ``(level, lat, lon)`` putting a file's array in Nephele's order: slices where each
    order is a run up or down (a view, no copy: a 0.25 degree step is 150 MB), else ``np.ix_``."""
    slices = []
    for o in order:
        if o.size and np.all(np.diff(o) == 1):
            slices.append(slice(int(o[0]), int(o[-1]) + 1))
        elif o.size and np.all(np.diff(o) == -1):
            slices.append(slice(int(o[0]), None if o[-1] == 0 else int(o[-1]) - 1, -1))
        else:
            return np.ix_(*order)
    return tuple(slices)


def _fmt_crit(rh_crit):
    a = np.asarray(rh_crit)
    return f"{float(a):g}" if a.ndim == 0 else f"{a.min():g}..{a.max():g}"


_TIME_UNITS = {
    "s": 1, "sec": 1, "secs": 1, "second": 1, "seconds": 1,
    "mn": 60, "min": 60, "mins": 60, "minute": 60, "minutes": 60,
    "h": 3600, "hr": 3600, "hrs": 3600, "hour": 3600, "hours": 3600,
    "d": 86400, "dy": 86400, "day": 86400, "days": 86400,
}  # fmt: skip


def step_times(n):
    """``n`` steps one hour apart from 1970-01-01: the time axis of a file whose times cannot be read."""
    return np.datetime64("1970-01-01T00:00:00", "s") + np.arange(n) * np.timedelta64(3600, "s")


def cf_times_or_steps(values, units, calendar, path, field="time"):
    """``(times, note)``: CF times, or step indices (one hour apart) with a note when the units are not CF."""
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    try:
        return cf_times(values, units, calendar, path, field), None
    except DataError as exc:
        if "calendar" in exc.problem or "NaN" in exc.problem:
            raise
        return step_times(values.size), (f"{field}: {exc.problem}; the {values.size} step(s) are numbered "
                                         f"0..{values.size - 1}, one hour apart")


_CALENDARS = ("standard", "gregorian", "proleptic_gregorian", "noleap", "365_day", "all_leap", "366_day", "360_day",
              "julian", "none")


def cf_times(values, units, calendar, path, field="time"):
    """datetime64[s] from CF ``"<unit> since <date>"`` numbers.

    Units up to days are the same length in every CF calendar, so a
    non-standard calendar (``noleap``, ``360_day``…) keeps its exact elapsed
    times from the reference date; its later calendar labels differ from the
    Gregorian ones shown (only the spacing of the steps matters for a film).
    """
    cal = (calendar or "standard").strip().lower()
    if cal not in _CALENDARS:
        raise DataError(f"calendar {calendar!r} is not a CF calendar ({', '.join(_CALENDARS)})", path=path, field=field)
    m = re.match(r"\s*(\w+)\s+since\s+(.+?)\s*$", units or "")
    if not m or m.group(1).lower() not in _TIME_UNITS:
        raise DataError(f"time units {units!r} are not '<seconds|minutes|hours|days> since <date>'", path=path,
                        field=field)
    ref = parse_iso(m.group(2), path, field)
    values = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise DataError("has NaN times", path=path, field=field)
    secs = np.rint(values * _TIME_UNITS[m.group(1).lower()]).astype(np.int64)
    return ref + secs.astype("timedelta64[s]")


def parse_iso(text, path, field):
    """A CF reference date such as ``2001-1-1 00:00:00``, ``1987-01-02T06:00Z`` or ``2001-01-01 0:0:0.0 UTC``."""
    m = re.match(r"(-?\d{1,4})-(\d{1,2})-(\d{1,2})(?:[ "
                 r"T](\d{1,2}):(\d{1,2})(?::(\d{1,2})(?:\.\d*)?)?)?\s*(?:Z|UTC|GMT|[+-]00:?00)?\s*$", text.strip())
    if not m:
        raise DataError(f"cannot read the reference date {text!r}", path=path, field=field)
    y, mo, d, hh, mm, ss = (int(g) if g else 0 for g in m.groups())
    return np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{hh:02d}:{mm:02d}:{ss:02d}", "s")


__all__ = ["ALIASES", "FileDataset", "meaning_aliases", "cf_times", "cf_times_or_steps", "plausible_units",
           "standard_name", "step_times", "tidy_lonlat"]
