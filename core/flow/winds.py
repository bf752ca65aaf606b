"""Winds as velocity fields on the unit sphere: gridded (:class:`WindField`) or analytic (:class:`AnalyticWind`).

Winds are turned into a Cartesian velocity on the unit sphere (per hour) and
a level-index rate, interpolated trilinearly in (level, latitude, longitude)
index (:mod:`._grid_index`) and linearly in time.  On a curvilinear grid the
winds, east/north at each column, are turned Cartesian with that column's own
east and north; a regional grid has calm air outside.  Missing winds (NaN)
raise :class:`~nephele.core.errors.DataError` by default; ``nan="zero"`` treats
them as calm air instead.

References
----------
.. [1] N. Max and R. Crawfis, "Visualizing wind velocities by advecting cloud
   textures", Proc. Visualization '92, 179-184.
"""

from collections import OrderedDict

import numpy as np

from ..climate.grid import EARTH_RADIUS, lonlat_to_xyz
from ..errors import DataError
from ..threads import default_threads
from ._grid_index import _column_spacing, _dot, _lonlat, grid_index
from .flows import tangent_velocity

HOUR = 3600.0


class WindField:
    """The winds of a :class:`~nephele.core.climate.dataset.Dataset` as a velocity field on the unit sphere.

    ``velocity(hours, xyz, s)`` gives the Cartesian velocity of unit vectors
    (per hour) and the rate of the level coordinate ``s`` (levels per hour):
    ``ds/dt = (w - u ∂h/∂x - v ∂h/∂y) / (∂h/∂s)``, which follows the
    terrain-following levels.  Space: trilinear in level/row/column index
    (a curvilinear grid's columns located, its slopes by the chain rule through
    the columns' positions); time: linear between steps.  ``u``, ``v`` are
    eastward and northward on every grid (readers turn grid-relative winds).
    Zero outside a regional grid (see the module notes).

    Parameters
    ----------
    dataset : Dataset
        Needs ``u`` and ``v`` (m/s); ``w`` (m/s) is optional.
    nan : {"error", "zero"}
        Missing winds raise :class:`DataError` naming the step, or count as calm.
    vertical : {"auto", "w", "levels"}
        ``"w"``: the level rate above; ``"levels"``: points keep their level
        (``ds/dt = 0``), right when the data's ``w`` is just the lift of air
        riding its terrain-following level (the demo's), whose finite-difference
        reconstruction would otherwise add spurious vertical motion;
        ``"auto"``: ``"levels"`` for a dataset whose ``levels_follow_air``
        says so, else ``"w"``.
    cache_steps : int
        Hourly steps kept converted (float32, ``nk × (nj+4) × (ni+3) × 4``
        values each: 16 MB on the 320×160×19 demo), least recently used dropped.  A
        restart strategy with period ``P`` frames reads back up to ``P`` frames
        of steps for its fallback traces: see :func:`steps_to_keep`.
    read_ahead : bool, optional
        After converting step ``t``, read and convert ``t + 1`` in a background
        thread (a film needs one new step per frame; reading it overlaps the
        tracing).  Default: when :func:`~nephele.core.threads.default_threads`
        allows more than one thread.
    radius : float, optional
        Planet radius (m) turning winds into angular speed; default the
        dataset's ``earth_radius`` (from the file), else
        :data:`~nephele.core.climate.grid.EARTH_RADIUS`.
    """

    def __init__(self, dataset, nan="error", cache_steps=6, vertical="auto", read_ahead=None, radius=None):
        if nan not in ("error", "zero"):
            raise ValueError(f"nan must be 'error' or 'zero', got {nan!r}")
        if vertical not in ("auto", "w", "levels"):
            raise ValueError(f"vertical must be 'auto', 'w' or 'levels', got {vertical!r}")
        if vertical == "auto":
            vertical = "levels" if getattr(dataset, "levels_follow_air", False) else "w"
        self.vertical = vertical
        self._read_ahead = default_threads() > 1 if read_ahead is None else bool(read_ahead)
        self._pending = {}
        self._executor = None
        for name in ("u", "v"):
            if name not in dataset:
                raise DataError(
                    "is needed to advect textures but the dataset has no such field", path=dataset.source, field=name
                )
        self.dataset = dataset
        self.grid = grid = dataset.grid
        self.radius = float(radius or getattr(dataset, "earth_radius", None) or EARTH_RADIUS)
        self.nan = nan
        self.index = grid_index(grid, pad=2, path=dataset.source)
        self.nk = grid.shape[0]
        self.hours = dataset.hours
        self.time_range = (float(self.hours[0]), float(self.hours[-1]))
        self._steps = OrderedDict()
        self._blends = OrderedDict()
        self._cache_steps = cache_steps
        self._speed = {}
        self.min_spacing = _column_spacing(grid) if grid.curvilinear else float(np.deg2rad(np.min(np.diff(grid.lat))))
        self._geometry()

    def _geometry(self):
        g = self.grid
        nk, nj, ni = g.shape
        # East and north unit vectors per column, scaled from m/s to unit-sphere radians per hour.
        if g.curvilinear:
            lam, phi = np.deg2rad(g.lon2d), np.deg2rad(g.lat2d)
        else:
            lam, phi = np.deg2rad(g.lon)[None, :], np.deg2rad(g.lat)[:, None]
        sl, cl, sp, cp = np.sin(lam), np.cos(lam), np.sin(phi), np.cos(phi)
        scale = HOUR / self.radius
        self._east = [(a * scale).astype(np.float32) for a in np.broadcast_arrays(-sl, cl, 0.0 * phi)]
        self._north = [(a * scale).astype(np.float32) for a in np.broadcast_arrays(-sp * cl, -sp * sl, cp + 0.0 * lam)]
        h = g.height
        dhds = np.gradient(h, axis=0) if nk > 1 else np.ones_like(h)
        self._sdot_scale = (HOUR / dhds).astype(np.float32)
        flat = np.all(h == h[:, :1, :1])
        if flat:
            self._dhdx = self._dhdy = None
        elif g.curvilinear:
            self._dhdx, self._dhdy = (a.astype(np.float32) for a in _curvilinear_slopes(g, h, self.radius))
        else:
            lam, phi = np.deg2rad(g.lon), np.deg2rad(g.lat)
            if g.periodic_lon:
                dl = np.deg2rad(np.mod(np.roll(g.lon, -1) - np.roll(g.lon, 1), 360.0))
                dhdl = (np.roll(h, -1, axis=2) - np.roll(h, 1, axis=2)) / dl
            else:
                dhdl = np.gradient(h, lam, axis=2)
            cos = np.cos(phi)[None, :, None]
            self._dhdx = np.where(cos > 1e-9, dhdl / (self.radius * np.maximum(cos, 1e-9)), 0.0).astype(np.float32)
            self._dhdy = (np.gradient(h, phi, axis=1) / self.radius).astype(np.float32)
        self.height_field = self.index.padded(h[..., None].astype(np.float64))

    def _read_wind(self, t):
        """``u``, ``v`` (and ``w`` unless levels are kept) of step ``t``, float32, NaN checked."""
        names = ("u", "v") if self.vertical == "levels" else ("u", "v", "w")
        uvw = self.dataset.wind(t) if len(names) == 3 else (self.dataset.read("u", t), self.dataset.read("v", t))
        out = []
        for name, a in zip(names, uvw):
            a = np.asarray(a, dtype=np.float32)
            bad = ~np.isfinite(a)
            if bad.any():
                if self.nan == "error":
                    raise DataError(
                        f"has {int(bad.sum())} NaN/infinite values at time step {t} "
                        "(pass nan='zero' to treat missing wind as calm air)",
                        path=self.dataset.source,
                        field=name,
                    )
                a = np.where(bad, np.float32(0.0), a)
            out.append(a)
        return out

    def _step(self, t):
        if t in self._steps:
            self._steps.move_to_end(t)
            return self._steps[t]
        pending = self._pending.pop(t, None)
        f, self._speed[t] = pending.result() if pending is not None else self._convert(t)
        self._steps[t] = f
        while len(self._steps) > self._cache_steps:
            self._steps.popitem(last=False)
        if self._read_ahead:
            self._prefetch(t + 1)
        return f

    def _prefetch(self, t):
        if t >= self.hours.size or t in self._steps or self._pending:
            return
        if self._executor is None:
            from concurrent.futures import ThreadPoolExecutor

            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="nephele-wind")
        self._pending[t] = self._executor.submit(self._convert, t)

    def _convert(self, t):
        """Step ``t`` read, checked and converted: ``(padded field, (speed, level rate))``.
        Touches no state of its own, so it may run in the read-ahead thread."""
        uvw = self._read_wind(t)
        u, v = uvw[0], uvw[1]
        f = np.empty(self.grid.shape + (4,), dtype=np.float32)
        for c in range(3):
            np.multiply(u, self._east[c], out=f[..., c])
            f[..., c] += v * self._north[c]
        if self.vertical == "levels":
            f[..., 3] = 0.0
        else:
            w = uvw[2]
            wz = w if self._dhdx is None else w - u * self._dhdx - v * self._dhdy
            np.multiply(wz, self._sdot_scale, out=f[..., 3])
        u64, v64 = u.astype(np.float64), v.astype(np.float64)
        speed = (float(np.sqrt(np.max(u64 * u64 + v64 * v64))) * HOUR / self.radius, float(np.max(np.abs(f[..., 3]))))
        return self.index.padded(f), speed

    def check_time(self, hours):
        lo, hi = self.time_range
        if not (np.isfinite(hours) and lo - 1e-9 <= hours <= hi + 1e-9):
            raise DataError(
                f"time {hours:g} h is outside the data range {lo:g}..{hi:g} h", path=self.dataset.source, field="time"
            )

    def _field_at(self, hours, points):
        """The padded field at ``hours`` as ``[(weight, step field), ...]``.

        Between steps, a set of ``points`` large enough to pay for it gets the
        two steps blended once (a few recent blends are kept); a small one
        (fallback traces) gets both steps, interpolated at its points and then
        blended, instead of a grid-sized blend per time it visits.
        """
        key = round(float(hours), 9)
        if key in self._blends:
            return [(1.0, self._blends[key])]
        i0, i1, w = self.dataset.locate_time(hours)
        if w <= 0.0 or i0 == i1:
            return [(1.0, self._step(i0))]
        if w >= 1.0:
            return [(1.0, self._step(i1))]
        if points * 16 < np.prod(self.grid.shape):
            return [(1.0 - w, self._step(i0)), (w, self._step(i1))]
        f = self._step(i0) * np.float32(1.0 - w)
        f += self._step(i1) * np.float32(w)
        self._blends[key] = f
        while len(self._blends) > 4:
            self._blends.popitem(last=False)
        return [(1.0, f)]

    def velocity(self, hours, xyz, s):
        """``(dxyz/dt, ds/dt)`` per hour at unit vectors ``xyz`` (n, 3) and levels ``s`` (n,)."""
        fr = self.index.fractional(xyz, s)
        return _tangent(
            sum(w * self.index.trilinear(f, *fr).astype(np.float64) for w, f in self._field_at(hours, len(xyz))), xyz
        )

    def vertex_velocity(self, hours, index, xyz):
        """:meth:`velocity` at the grid vertices ``index`` (flat), unit vectors ``xyz``: read, not interpolated."""
        rows = self.index.rows(index)
        parts = self._field_at(hours, len(rows))
        return _tangent(
            sum(w * f.reshape(-1, f.shape[-1]).take(rows, axis=0).astype(np.float64) for w, f in parts), xyz
        )

    def max_speed(self, t0, t1):
        """Largest (unit-sphere speed per hour, level rate per hour) over the steps spanning ``t0..t1``."""
        lo, hi = min(t0, t1), max(t0, t1)
        i_lo = self.dataset.locate_time(lo)[0]
        i_hi = self.dataset.locate_time(hi)[1]
        sp, vr = 0.0, 0.0
        for t in range(i_lo, i_hi + 1):
            if t not in self._speed:
                self._step(t)
            a, b = self._speed[t]
            sp, vr = max(sp, a), max(vr, b)
        return sp, vr

    def start_height(self, xyz, s):
        """Height in metres of the points (the grid's level heights interpolated)."""
        return self.index.trilinear(self.height_field, *self.index.fractional(xyz, s, clamp=True))[:, 0]


def _curvilinear_slopes(grid, h, radius):
    """East and north slopes ``(dh/dx, dh/dy)`` (nk, nj, ni) of level heights ``h`` on a curvilinear grid.

    The chain rule through the columns' positions: with ``J`` the east/north
    metres per column index (central differences of the unit vectors, one
    sided at the edges), ``(dh/di, dh/dj) = Jᵀ (dh/dx, dh/dy)``.
    """
    p = lonlat_to_xyz(grid.lon2d, grid.lat2d)
    lam, phi = np.deg2rad(grid.lon2d), np.deg2rad(grid.lat2d)
    east = np.stack([-np.sin(lam), np.cos(lam), np.zeros_like(lam)], axis=-1)
    north = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], axis=-1)
    pi, pj = np.gradient(p, axis=1) * radius, np.gradient(p, axis=0) * radius
    a, b = np.sum(east * pi, axis=-1), np.sum(east * pj, axis=-1)  # J = [[a, b], [c, d]]
    c, d = np.sum(north * pi, axis=-1), np.sum(north * pj, axis=-1)
    det = a * d - b * c
    hi, hj = np.gradient(h, axis=2), np.gradient(h, axis=1)
    # Solve [[a, c], [b, d]] (dh/dx, dh/dy) = (dh/di, dh/dj).
    return (d * hi - c * hj) / det, (a * hj - b * hi) / det


def _tangent(out, xyz):
    """Split (n, 4) interpolated winds into the velocity tangent to the sphere at ``xyz`` and the level rate."""
    v = out[:, :3]
    v -= _dot(v, xyz)[:, None] * xyz
    return v, out[:, 3]


def steps_to_keep(grid, period_hours, budget_mb=512):
    """Wind steps a :class:`WindField` should keep for a restart period of ``period_hours``.

    The period's steps plus two (the next frame's), capped so they fit in
    ``budget_mb`` megabytes; at least 6.  The bound depends on the grid and
    the period, not on the film's length.
    """
    nk, nj, ni = grid.shape
    step_mb = nk * (nj + 4) * (ni + 3) * 4 * 4 / 2**20
    return int(max(6, min(np.ceil(period_hours) + 2, budget_mb // step_mb)))


class AnalyticWind:
    """A flow from :mod:`nephele.core.flow.flows` as a velocity field (no vertical motion).

    Parameters
    ----------
    flow : object with ``wind(lon, lat, hours) -> (u, v)`` and ``period_hours``
    nk : int
        Number of levels of the level coordinate (stays constant).
    hours : (float, float), optional
        Time range (default ``0..period_hours``).
    min_spacing : float
        Grid spacing in radians used by the CFL bound.
    radius : float, optional
        Planet radius (m) turning the winds into angular speed; default the
        flow's own ``radius`` (the one its winds were made with), else
        :data:`~nephele.core.climate.grid.EARTH_RADIUS`.
    """

    def __init__(self, flow, nk=2, hours=None, min_spacing=np.deg2rad(1.125), radius=None):
        self.flow = flow
        self.radius = float(radius if radius is not None else getattr(flow, "radius", EARTH_RADIUS))
        self.nk = nk
        self.time_range = tuple(float(h) for h in (hours or (0.0, flow.period_hours)))
        self.min_spacing = float(min_spacing)
        lon, lat = np.meshgrid(np.arange(0, 360, 5.0), np.arange(-87.5, 90, 5.0))
        self._lon, self._lat = lon.ravel(), lat.ravel()

    def check_time(self, hours):
        lo, hi = self.time_range
        if not (np.isfinite(hours) and lo - 1e-9 <= hours <= hi + 1e-9):
            raise DataError(
                f"time {hours:g} h is outside the data range {lo:g}..{hi:g} h",
                path=type(self.flow).__name__,
                field="time",
            )

    def velocity(self, hours, xyz, s):
        lon, lat = _lonlat(xyz)
        u, v = self.flow.wind(lon, lat, hours)
        return tangent_velocity(lon, lat, u, v) * (HOUR / self.radius), np.zeros(len(xyz))

    def max_speed(self, t0, t1):
        sp = 0.0
        for t in np.linspace(t0, t1, 5):
            u, v = self.flow.wind(self._lon, self._lat, t)
            sp = max(sp, float(np.sqrt(np.max(u * u + v * v))) * HOUR / self.radius)
        return 1.05 * sp, 0.0


__all__ = ["HOUR", "AnalyticWind", "WindField", "steps_to_keep"]
