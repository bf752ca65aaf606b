"""Time-varying fields on a :class:`~nephele.core.climate.grid.GlobeGrid`, read one time step at a time.

A 320×160×19 grid with 240 hourly steps and several fields is gigabytes, so a
:class:`Dataset` never loads everything: :meth:`Dataset.read` returns one
``(nk, nj, ni)`` float32 step of one field and keeps a few recent steps.

Standard field names (readers map their files' names onto these and keep the
others under their own names):

=============== ======= =====================================
name            units   meaning
=============== ======= =====================================
``cloud``       1       cloud fraction, 0..1
``cloud_water`` kg/kg   cloud liquid water (mixing ratio or
                        mass fraction: NCEP ``clwmr``, ECMWF
                        ``clwc``, CMIP ``clw``, MERRA ``QL``)
``cloud_ice``   kg/kg   cloud ice (``icmr``, ``ciwc``, ``cli``)
``temperature`` K       air temperature
``u``           m/s     eastward wind
``v``           m/s     northward wind
``w``           m/s     upward wind (zero when a file has none)
``omega``       Pa/s    vertical velocity in pressure per time
``rh``          1       relative humidity, fraction
``q``           kg/kg   specific humidity
``pressure``    Pa      air pressure
=============== ======= =====================================
"""

import abc
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from .grid import EARTH_RADIUS, GlobeGrid


@dataclass(frozen=True)
class Variable:
    """Description of one field of a dataset."""

    name: str
    units: str = ""
    long_name: str = ""


class Dataset(abc.ABC):
    """Base class: a grid, an hourly (or other) time axis and named fields.

    Subclasses implement ``_read(name, t)`` returning the step as an array of
    shape ``grid.shape`` (any float dtype; missing values as NaN).

    Parameters
    ----------
    grid : GlobeGrid
    times : (nt,) array of datetime64
        Strictly increasing.
    variables : iterable of Variable
    source : str
        The file path, or ``"demo"``; used in every error message.
    cache_steps : int
        How many (field, step) arrays to keep in memory.

    Attributes
    ----------
    levels_follow_air : bool
        True where the levels are material surfaces (air stays on its level,
        ``w`` is only the lift of riding it), as in the synthetic demo; the
        texture advection then keeps points on their levels by default.
    """

    levels_follow_air = False
    calendar = "standard"
    """CF calendar of the time axis; readers of model output set others (``"360_day"``, ``"noleap"``)."""
    time_origin = None
    """The time axis' reference date (``datetime64[s]``): times are elapsed time from it, so in a model
    calendar the dates shown are it plus that time in the calendar (:mod:`nephele.core.annotate`)."""
    aliases = {}
    """File names of fields → their standard names (readers fill it)."""
    earth_radius = EARTH_RADIUS
    """Planet radius in metres for geometry and winds → angular speed (readers take it from the file)."""

    def __init__(self, grid, times, variables, source, cache_steps=8):
        self.grid = grid
        self.source = str(source)
        self.times = np.asarray(times, dtype="datetime64[s]")
        if self.times.ndim != 1 or self.times.size < 1:
            raise DataError(f"needs a 1-D time axis, got shape {self.times.shape}", path=source, field="time")
        if self.times.size > 1 and not np.all(np.diff(self.times) > np.timedelta64(0, "s")):
            raise DataError("times are not strictly increasing", path=source, field="time")
        self.variables = {v.name: v for v in variables}
        self._cache = OrderedDict()
        self._cache_steps = cache_steps
        # Reads may come from a read-ahead thread (the advection's next wind step).
        self._lock = threading.RLock()

    def __repr__(self):
        nk, nj, ni = self.grid.shape
        return (
            f"<{type(self).__name__} {self.source!r} {ni}x{nj}x{nk} lon×lat×level, "
            f"{self.times.size} times, fields {sorted(self.variables)}>"
        )

    def __contains__(self, name):
        return self.resolve(name) in self.variables

    def resolve(self, name):
        """The dataset's name for ``name``: a standard name, the file's own name, or another name of the
        same meaning (GRIB ``shortName``, CF standard name; any case)."""
        if name in self.variables:
            return name
        low = str(name).lower()
        return self.aliases.get(name) or (low if low in self.variables else self.aliases.get(low, name))

    @property
    def hours(self):
        """Time of each step in hours since the first step (float64)."""
        return (self.times - self.times[0]).astype(np.float64) / 3600.0

    def _check(self, name, t):
        name = self.resolve(name)
        if name not in self.variables:
            raise DataError(
                f"no such variable (available: {', '.join(sorted(self.variables)) or 'none'})",
                path=self.source,
                field=name,
            )
        nt = self.times.size
        if not (isinstance(t, (int, np.integer)) and -nt <= t < nt):
            raise DataError(f"time index {t!r} is outside 0..{nt - 1}", path=self.source, field=name)
        return name, int(t) % nt

    def read(self, name, t):
        """One time step of one field as float32 ``(nk, nj, ni)``; NaN where missing.

        ``name`` is a standard name or the file's own name for the field.
        """
        name, t = self._check(name, t)
        key = (name, t)
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
            try:
                a = np.asarray(self._read(name, t), dtype=np.float32)
            except (DataError, MemoryError):
                raise
            except Exception as exc:  # a damaged file fails here, in its library's own types (HDF, ecCodes, zarr)
                first = (str(exc).strip().splitlines() or [""])[0][:200]
                raise DataError(f"cannot read step {t} ({type(exc).__name__}: {first})", path=self.source,
                                field=name) from exc
            if a.shape != self.grid.shape:
                raise DataError(f"step {t} has shape {a.shape}, grid is {self.grid.shape}", path=self.source,
                                field=name)
            a.setflags(write=False)
            self._cache[key] = a
            while len(self._cache) > self._cache_steps:
                self._cache.popitem(last=False)
            return a

    def locate_time(self, hours):
        """Steps around ``hours`` (since the first step) and the weight of the later one."""
        h = self.hours
        hours = float(hours)
        if not np.isfinite(hours) or hours < h[0] - 1e-9 or hours > h[-1] + 1e-9:
            raise DataError(f"time {hours} h is outside the data range 0..{h[-1]:g} h", path=self.source, field="time")
        i1 = int(np.clip(np.searchsorted(h, hours, side="right"), 1, max(h.size - 1, 1)))
        if h.size == 1:
            return 0, 0, 0.0
        i0 = i1 - 1
        w = (hours - h[i0]) / (h[i1] - h[i0])
        return i0, i1, float(np.clip(w, 0.0, 1.0))

    def read_at(self, name, hours):
        """A field at any time within the data, linear between the two nearest steps."""
        i0, i1, w = self.locate_time(hours)
        a = self.read(name, i0)
        if w == 0.0:
            return a
        b = self.read(name, i1)
        if w == 1.0:
            return b
        return ((1.0 - w) * a + w * b).astype(np.float32)

    def wind(self, t):
        """``(u, v, w)`` in m/s at step ``t``; ``w`` is zero where the data has none."""
        u, v = self.read("u", t), self.read("v", t)
        w = self.read("w", t) if "w" in self.variables else np.zeros_like(u)
        return u, v, w

    @abc.abstractmethod
    def _read(self, name, t):
        """Return step ``t`` of field ``name`` (no caching, no checks)."""


class ArrayDataset(Dataset):
    """A dataset held in memory: ``fields[name]`` has shape ``(nt, nk, nj, ni)``.

    For tests and small data; real files use the lazy readers in
    :mod:`nephele.core.climate.readers`.
    """

    def __init__(self, grid, times, fields, source="<memory>", units=None):
        units = units or {}
        super().__init__(grid, times, [Variable(n, units.get(n, "")) for n in fields], source)
        nt = self.times.size
        self._fields = {}
        for name, a in fields.items():
            a = np.asarray(a)
            if a.shape != (nt,) + grid.shape:
                raise DataError(f"shape {a.shape} is not (times, levels, lat, lon) = {(nt,) + grid.shape}", path=source,
                                field=name)
            self._fields[name] = a

    def _read(self, name, t):
        return self._fields[name][t]


def hourly(start, n):
    """``n`` hourly datetime64 times from ``start`` (a string such as ``"1987-01-01"``)."""
    return np.datetime64(start, "s") + np.arange(n) * np.timedelta64(3600, "s")


__all__ = ["ArrayDataset", "Dataset", "GlobeGrid", "Variable", "hourly"]
