"""Backward trajectories through time-varying winds, for textures that move with the wind.

The texture of a frame at time ``t`` is evaluated not at the rendered point A
but at the point B that, starting at time 0, reaches A at ``t`` [1]_.  Every
grid vertex the scene needs is traced backwards through the hourly winds.

Positions are unit vectors on the sphere plus a fractional level index ``s``
(0 = lowest level).  Winds are turned into a Cartesian velocity on the unit
sphere (per hour) and a level-index rate, interpolated trilinearly in
(level, latitude, longitude) index and linearly in time.  Integrating in 3-D
Cartesian coordinates and renormalising every stage keeps the poles regular;
rows mirrored across each pole and periodic longitudes let points cross both.
Vertical motion is clamped at the bottom and top levels.  The step is the
smaller of ``dt_max`` and a CFL bound from the fastest wind of the interval.

On a curvilinear grid (2-D latitude/longitude: WRF, Lambert conformal, polar
stereographic) points are located in the grid's columns each stage
(:class:`~nephele.core.climate.columns.ColumnLocator`) and the winds, east/north
at each column turned Cartesian with that column's own east and north, are
interpolated in the same index space; positions stay unit vectors, so the date
line and a pole inside the grid need nothing special.  A regional grid
(curvilinear, or 1-D longitudes that do not close the circle) has calm air
outside: a trajectory that leaves it stops at its first step end outside,
within two steps of where it crossed the edge.

Three strategies give the start coordinates of frame ``n`` (:class:`FullTrace`,
:class:`ComposedTrace`, :class:`RestartTrace`); each returns a list of
:class:`Copy` (start positions and a blending weight).

Missing winds (NaN) raise :class:`~nephele.core.errors.DataError` by default;
``nan="zero"`` treats them as calm air instead.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 4).
.. [2] N. Max and R. Crawfis, "Visualizing wind velocities by advecting cloud
   textures", Proc. Visualization '92, 179-184.
.. [3] F. Neyret, "Advected textures", Proc. SCA 2003 (two phase-shifted layers
   restarted periodically and cross-faded).
"""

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import DataError
from .flows import tangent_velocity
from ..climate.columns import ColumnLocator
from ..climate.grid import EARTH_RADIUS, lonlat_to_xyz, xyz_to_lonlat
from ..threads import default_threads

HOUR = 3600.0
METHODS = ("euler", "rk2", "rk4")


def _lonlat(xyz):
    lon = np.rad2deg(np.arctan2(xyz[:, 1], xyz[:, 0]))
    lat = np.rad2deg(np.arcsin(np.clip(xyz[:, 2], -1.0, 1.0)))
    return lon, lat


def _normalise(x):
    return x / np.sqrt(_dot(x, x))[:, None]


def _dot(a, b):
    """Row-wise dot products of (n, 3) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


class _GridIndex:
    """Fractional (level, row, column) indices of points on a GlobeGrid, and fast gathers.

    Fields are stored padded (:meth:`pad`): ``pad`` extra rows at each end, the
    rows nearest the pole rolled half way round in longitude, so a point
    between the last row and the pole (or beyond it) interpolates across the
    pole; and one column before and two after (wrapped round a periodic grid,
    repeated otherwise), so every stencil is a fixed set of flat offsets from
    its first tap.
    """

    def __init__(self, grid, pad):
        nk, nj, ni = grid.shape
        self.shape = grid.shape
        self.periodic = grid.periodic_lon
        lon, lat = grid.lon, grid.lat
        self.lon0 = lon[0]
        self.pad = pad if (self.periodic and ni % 2 == 0) else 0
        if self.periodic:
            self.lon_axis = np.append(lon - lon[0], 360.0)
        else:
            self.lon_axis = lon - lon[0]
            self.lon_centre = 0.5 * (lon[0] + lon[-1])
        p = self.pad
        south = [j + (lat[0] == -90.0) for j in range(p)]
        north = [nj - 1 - j - (lat[-1] == 90.0) for j in range(p)]
        self.south_rows, self.north_rows = south, north
        self.lat_axis = np.concatenate([-180.0 - lat[south][::-1], lat, 180.0 - lat[north]])
        self.njp = nj + 2 * p
        self.nip = ni + 3
        self.poles = p > 0
        self.bounded = not self.periodic  # a regional grid: points beyond its edges are outside
        self._lon_step = _uniform_step(self.lon_axis)
        self._lat_step = _uniform_step(self.lat_axis)
        self._offsets = {}

    def padded(self, f, out=None):
        """``f`` (nk, nj, ni, ...) with mirrored rows added at both poles and wrapped (or repeated) columns.

        Written into ``out`` (a padded array, or a view of one) when given.
        """
        nk, nj, ni = self.shape
        p = self.pad
        if out is None:
            out = np.empty((nk, nj + 2 * p, ni + 3) + f.shape[3:], dtype=f.dtype)
        out[:, p : p + nj, 1 : ni + 1] = f
        half = ni // 2
        for r, j in enumerate(self.south_rows[::-1]):
            out[:, r, 1 : ni + 1] = np.roll(f[:, j], half, axis=1)
        for r, j in enumerate(self.north_rows):
            out[:, p + nj + r, 1 : ni + 1] = np.roll(f[:, j], half, axis=1)
        if self.periodic:
            out[:, :, 0], out[:, :, ni + 1], out[:, :, ni + 2] = out[:, :, ni], out[:, :, 1], out[:, :, 2]
        else:
            out[:, :, 0], out[:, :, ni + 1], out[:, :, ni + 2] = out[:, :, 1], out[:, :, ni], out[:, :, ni]
        return out

    def rows(self, index):
        """Flat (level, padded row, padded column) positions in a padded field of the grid vertices ``index``."""
        k, j, i = np.unravel_index(np.asarray(index), self.shape)
        return (k * self.njp + j + self.pad) * self.nip + i + 1

    def fractional(self, xyz, s, clamp=False):
        """Fractional indices ``(fk, fj, fi)`` of unit vectors ``xyz`` at level coordinate ``s``.

        On a regional (non-periodic) grid ``fi`` is NaN for points beyond its
        edges (more than 1e-9 degrees), or with ``clamp`` the nearest edge's index.
        """
        lon, lat = _lonlat(xyz)
        if self.periodic:
            d = np.mod(lon - self.lon0, 360.0)
        else:
            d = np.mod(lon - self.lon_centre + 180.0, 360.0) - 180.0 + self.lon_centre - self.lon0
        fi = _axis_index(d, self.lon_axis, self._lon_step)
        fj = _axis_index(lat, self.lat_axis, self._lat_step)
        fk = np.clip(s, 0.0, self.shape[0] - 1)
        if self.bounded and not clamp:
            eps = 1e-9
            outside = (d < -eps) | (d > self.lon_axis[-1] + eps) | (lat < self.lat_axis[0] - eps) | (lat > self.lat_axis[-1] + eps)
            if outside.any():
                fi[outside] = np.nan
        return fk, fj, fi

    def trilinear(self, f, fk, fj, fi):
        """Trilinear interpolation of padded field ``f`` (nk, njp, nip, c) at fractional indices (float32)."""
        return self._gather(f, fk, fj, fi, cubic=False)

    def cubic(self, f, fk, fj, fi):
        """Catmull-Rom bicubic in (row, column), linear in level (float32); NaN where a tap is NaN."""
        return self._gather(f, fk, fj, fi, cubic=True)

    def _offsets_of(self, cubic, dk):
        """Flat offsets of a stencil's taps from its first tap (level-major, then row, then column)."""
        key = (cubic, dk)
        if key not in self._offsets:
            nt = 4 if cubic else 2
            plane = self.njp * self.nip
            self._offsets[key] = (np.array([0, dk])[:, None, None] * plane + np.arange(nt)[None, :, None] * self.nip
                                  + np.arange(nt)[None, None, :]).ravel()
        return self._offsets[key]

    def _gather(self, f, fk, fj, fi, cubic, chunk=2048):
        """Interpolated ``f`` at the fractional indices; on a bounded grid 0 where ``fi`` is NaN (outside)."""
        if self.bounded:
            outside = np.isnan(fi)
            if outside.any():
                out = self._taps(f, fk, np.where(outside, float(self.pad), fj), np.where(outside, 0.0, fi), cubic, chunk)
                out[outside] = 0.0
                return out
        return self._taps(f, fk, fj, fi, cubic, chunk)

    def _taps(self, f, fk, fj, fi, cubic, chunk):
        nk, njp, nip, c = f.shape
        flat = f.reshape(-1, c)
        n = fk.size
        out = np.empty((n, c), dtype=np.result_type(f.dtype, np.float32))
        ni = self.shape[2]
        lo = 1 if cubic else 0
        hi = 2 if cubic else 1
        # Level taps k0 and k0 + dk with weights (1 - tk, tk).
        if nk == 1:
            k0, tk, dk = np.zeros(n, np.intp), np.zeros(n), 0  # both level taps on level 0, the second weighted 0
        else:
            k0 = np.minimum(fk.astype(np.intp), nk - 2)
            tk, dk = fk - k0, 1
        j0 = np.clip(fj.astype(np.intp), lo, njp - 1 - hi)
        tj = fj - j0
        i0 = np.floor(fi).astype(np.intp)
        if self.periodic:
            ti = fi - i0
            i0 %= ni
        else:
            i0 = np.minimum(i0, ni - 2)
            ti = fi - i0
        base = (k0 * njp + j0 - lo) * nip + i0 + 1 - lo  # first tap: row j0 - lo, padded column i0 + 1 - lo
        offs = self._offsets_of(cubic, dk)
        # Tap weights (taps, n), level-major like the offsets: products of the per-axis weights.
        f32 = np.float32
        wk = [(1.0 - tk).astype(f32), np.asarray(tk, dtype=f32)]
        wj = [a.astype(f32) for a in (_catmull_rom(tj) if cubic else (1.0 - tj, tj))]
        wi = [a.astype(f32) for a in (_catmull_rom(ti) if cubic else (1.0 - ti, ti))]
        block = 16 * chunk  # weights made a block at a time: one (taps, n) array would be tens of MB, page-faulted anew each call
        w = np.empty((offs.size, min(block, n)), dtype=f32)
        for b0 in range(0, n, block):
            nb = min(block, n - b0)
            t = 0
            for a in wk:
                for b in wj:
                    ab = a[b0 : b0 + nb] * b[b0 : b0 + nb]
                    for c_ in wi:
                        np.multiply(ab, c_[b0 : b0 + nb], out=w[t, :nb])
                        t += 1
            wt = w[:, :nb].T
            for a in range(0, nb, chunk):
                sl = slice(b0 + a, b0 + min(a + chunk, nb))
                g = flat.take(base[sl, None] + offs, axis=0)
                out[sl] = np.matmul(wt[a : a + chunk, None, :], g)[:, 0]
        return out


class _ColumnIndex(_GridIndex):
    """:class:`_GridIndex` of a curvilinear (2-D longitude/latitude, regional) grid.

    Points are located with :class:`~nephele.core.climate.columns.ColumnLocator`
    (bilinear cells in the gnomonic chart, Newton inversion), so every stencil
    is the same fixed set of index-space taps as on a longitude/latitude grid.
    Padded fields repeat the edge rows (two each side) and columns.  A point
    outside the region has NaN indices, and the gathers give 0 there: the air
    outside a regional grid is calm, so a trajectory that leaves the region
    stops within one step of its edge.
    """

    def __init__(self, grid, path=None):
        self.shape = grid.shape
        nk, nj, ni = grid.shape
        self.periodic = False
        self.poles = False
        self.bounded = True
        self.pad = 2
        self.njp, self.nip = nj + 2 * self.pad, ni + 3
        self._offsets = {}
        self.locator = ColumnLocator(grid.lon2d, grid.lat2d, path)

    def padded(self, f, out=None):
        nk, nj, ni = self.shape
        p = self.pad
        if out is None:
            out = np.empty((nk, nj + 2 * p, ni + 3) + f.shape[3:], dtype=f.dtype)
        out[:, p : p + nj, 1 : ni + 1] = f
        out[:, :p, 1 : ni + 1] = f[:, :1]
        out[:, p + nj :, 1 : ni + 1] = f[:, -1:]
        out[:, :, 0], out[:, :, ni + 1], out[:, :, ni + 2] = out[:, :, 1], out[:, :, ni], out[:, :, ni]
        return out

    def fractional(self, xyz, s, clamp=False):
        """Fractional ``(fk, fj, fi)`` (``fj`` in padded rows); NaN outside the region, or with
        ``clamp`` the nearest column's indices there."""
        fi, fj = self.locator(xyz)
        outside = fi < 0
        if outside.any():
            if clamp:
                ci, cj = self.locator.nearest(np.asarray(xyz)[outside])
                fi[outside], fj[outside] = ci, cj
            else:
                fi[outside] = fj[outside] = np.nan
        return np.clip(s, 0.0, self.shape[0] - 1), fj + self.pad, fi


def grid_index(grid, pad=2, path=None):
    """The :class:`_GridIndex` of ``grid``: longitude/latitude axes, or located columns on a curvilinear grid."""
    return _ColumnIndex(grid, path) if grid.curvilinear else _GridIndex(grid, pad)


def _column_spacing(grid):
    """Smallest angle (radians) between neighbouring columns of a curvilinear grid."""
    p = lonlat_to_xyz(grid.lon2d, grid.lat2d)
    angles = []
    for a, b in ((p[1:], p[:-1]), (p[:, 1:], p[:, :-1])):
        angles.append(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)).min())
    return float(min(angles))


def _uniform_step(axis):
    """The spacing of an evenly spaced axis, or None."""
    d = np.diff(axis)
    return float(d[0]) if d.size and np.all(np.abs(d - d[0]) <= 1e-9 * abs(d[0])) else None


def _axis_index(x, axis, step):
    """Fractional index of ``x`` on a monotonic ``axis`` (clamped to its ends), as np.interp gives it."""
    if step is None:
        return np.interp(x, axis, np.arange(axis.size, dtype=np.float64))
    return np.clip((x - axis[0]) * (1.0 / step), 0.0, axis.size - 1.0)


def _catmull_rom(t):
    """Weights of taps -1, 0, 1, 2 of the Catmull-Rom cubic at fraction ``t``."""
    t2 = t * t
    t3 = t2 * t
    return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


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
                raise DataError("is needed to advect textures but the dataset has no such field", path=dataset.source, field=name)
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
            raise DataError(f"time {hours:g} h is outside the data range {lo:g}..{hi:g} h", path=self.dataset.source, field="time")

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
        return _tangent(sum(w * self.index.trilinear(f, *fr).astype(np.float64) for w, f in self._field_at(hours, len(xyz))), xyz)

    def vertex_velocity(self, hours, index, xyz):
        """:meth:`velocity` at the grid vertices ``index`` (flat), unit vectors ``xyz``: read, not interpolated."""
        rows = self.index.rows(index)
        parts = self._field_at(hours, len(rows))
        return _tangent(sum(w * f.reshape(-1, f.shape[-1]).take(rows, axis=0).astype(np.float64) for w, f in parts), xyz)

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
            raise DataError(f"time {hours:g} h is outside the data range {lo:g}..{hi:g} h", path=type(self.flow).__name__, field="time")

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


def trace(wind, xyz, s, t_from, t_to, *, method="rk4", dt_max=1.0, cfl=1.0, vertices=None):
    """Integrate points from time ``t_from`` to ``t_to`` (hours; backwards when ``t_to < t_from``).

    Parameters
    ----------
    wind : WindField or AnalyticWind
    xyz : (n, 3) array
        Unit vectors (normalised here).
    s : (n,) array
        Level coordinates, clamped to ``0..nk-1``.
    method : {"euler", "rk2", "rk4"}
    dt_max : float
        Largest step in hours.
    cfl : float
        Largest displacement per step, in grid spacings (horizontal) or levels.
    vertices : (n,) int array, optional
        Flat grid indices of the points when they are the grid's vertices (and
        ``wind`` a :class:`WindField`): the first stage reads the wind at the
        vertices instead of interpolating it there.

    Returns
    -------
    xyz, s : arrays like the inputs, at ``t_to``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not dt_max > 0 or not cfl > 0:
        raise ValueError("dt_max and cfl must be positive")
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(s, dtype=np.float64).reshape(-1)
    if len(s) != len(xyz):
        raise ValueError(f"xyz has {len(xyz)} points but s has {len(s)}")
    wind.check_time(t_from)
    wind.check_time(t_to)
    xyz = _normalise(xyz)
    top = wind.nk - 1
    s = np.clip(s, 0.0, top)
    span = t_to - t_from
    if span == 0 or len(xyz) == 0:
        return xyz, s
    sp, vr = wind.max_speed(t_from, t_to)
    dt = dt_max
    if sp > 0:
        dt = min(dt, cfl * wind.min_spacing / sp)
    if vr > 0:
        dt = min(dt, cfl / vr)
    n = int(np.ceil(abs(span) / dt - 1e-9))
    h = span / n
    t = t_from
    first = wind.vertex_velocity(t, vertices, xyz) if vertices is not None and hasattr(wind, "vertex_velocity") else None
    for _ in range(n):
        xyz, s = _step(wind, method, t, h, xyz, s, top, first)
        t += h
        first = None
    return xyz, s


def _step(wind, method, t, h, x, s, top, first=None):
    def stage(xb, sb, k, dk, a):
        return _normalise(xb + a * k), np.clip(sb + a * dk, 0.0, top)

    k1, d1 = wind.velocity(t, x, s) if first is None else first
    if method == "euler":
        return stage(x, s, k1, d1, h)
    if method == "rk2":
        x2, s2 = stage(x, s, k1, d1, h / 2)
        k2, d2 = wind.velocity(t + h / 2, x2, s2)
        return stage(x, s, k2, d2, h)
    x2, s2 = stage(x, s, k1, d1, h / 2)
    k2, d2 = wind.velocity(t + h / 2, x2, s2)
    x3, s3 = stage(x, s, k2, d2, h / 2)
    k3, d3 = wind.velocity(t + h / 2, x3, s3)
    x4, s4 = stage(x, s, k3, d3, h)
    k4, d4 = wind.velocity(t + h, x4, s4)
    return stage(x, s, k1 + 2 * k2 + 2 * k3 + k4, d1 + 2 * d2 + 2 * d3 + d4, h / 6)


@dataclass
class Copy:
    """One texture copy of a frame: where each point started, and the copy's weight.

    ``xyz`` (n, 3) unit vectors and ``s`` (n,) level coordinates at the copy's
    start time ``start_hours``; the texture is ``Σ weight · T(start)``.
    """

    xyz: np.ndarray
    s: np.ndarray
    weight: float
    start_hours: float


def _frame_hours(frame_hours):
    fh = np.asarray(frame_hours, dtype=np.float64).reshape(-1)
    if fh.size < 1 or not np.all(np.isfinite(fh)) or np.any(np.diff(fh) <= 0):
        raise ValueError("frame_hours must be a non-empty, finite, strictly increasing sequence")
    return fh


class _Strategy:
    """Common parts: the wind, frame times, the grid whose vertices are traced, step options."""

    def __init__(self, wind, frame_hours, grid, *, method="rk4", dt_max=1.0, cfl=1.0):
        self.wind, self.frame_hours, self.grid = wind, _frame_hours(frame_hours), grid
        self.opts = dict(method=method, dt_max=dt_max, cfl=cfl)
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self._columns = grid_vertices(grid, np.arange(grid.shape[1] * grid.shape[2]))  # one level's unit vectors

    def _frame(self, n):
        n = int(n)
        if not 0 <= n < self.frame_hours.size:
            raise ValueError(f"frame {n} is outside 0..{self.frame_hours.size - 1}")
        return n

    def _points(self, index):
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        k, col = np.divmod(index, self._columns.shape[0])
        return self._columns[col], k.astype(np.float64)

    def _one_frame(self, n, need):
        """Vertices ``need`` and where they were one frame earlier."""
        xyz, s = self._points(need)
        y, z = trace(self.wind, xyz, s, self.frame_hours[n], self.frame_hours[n - 1], vertices=need, **self.opts)
        return xyz, s, y, z


class FullTrace(_Strategy):
    """Strategy (a), the paper's: trace every vertex from frame ``n`` back to frame 0 (RK4).

    Exact up to the integrator and the data, but the cost of frame ``n`` grows with ``n``.
    """

    name = "full"

    def copies(self, n, index):
        """Start positions at frame 0 of the grid vertices ``index`` (flat indices) at frame ``n``."""
        n = self._frame(n)
        xyz, s = self._points(index)
        t0 = self.frame_hours[0]
        x, z = trace(self.wind, xyz, s, self.frame_hours[n], t0, vertices=index, **self.opts)
        return [Copy(x, z, 1.0, t0)]


class _StreamedMap:
    """The start positions of grid vertices, advanced one frame at a time by composition.

    ``S_n(x) = S_{n-1}(Φ(x))`` with ``Φ`` the one-frame backward trajectory and
    ``S_{n-1}`` interpolated from the vertices where it is stored (trilinear,
    or Catmull-Rom bicubic in latitude/longitude and linear in level).  The map
    is kept as the displacement ``D = S - x`` (smooth where ``S`` is not, e.g.
    in longitude) on a band of vertices around those asked for (one grid-sized
    array per copy: memory does not grow with the film).  After each step
    ``D`` is extended ``band + 2`` cells beyond the band from the nearest stored
    vertex, so the band's edge always has a stencil; a requested vertex whose
    stencil still finds no data (a cloud appearing far from any stored one) is
    traced directly back to its copy's start frame instead.

    ``copies`` maps with their own start frames are kept side by side (channels
    ``4c .. 4c + 3`` of one array): copies at the same frame share the band, the
    one-frame trace, one gather of all their channels and the extension.
    """

    def __init__(self, strategy, order, band, copies=1):
        self.st = strategy
        self.order = order
        self.band = band
        self.index = grid_index(strategy.grid, pad=2)
        self.map = self.index.padded(np.zeros(strategy.grid.shape + (4 * copies,), dtype=np.float32))
        # Regional grids: 1 near vertices whose start is not the composition's to give (their air came from
        # outside and stopped at the edge); a foot point there is traced directly instead.
        self.left = self.index.padded(np.zeros(strategy.grid.shape + (copies,), dtype=np.float32)) if self.index.bounded else None
        self.frames = [None] * copies
        self.starts = [None] * copies
        self.fallbacks = 0
        self._scratch = {}

    def reset(self, c, n):
        """Copy ``c`` is the identity at frame ``n``: every vertex starts where it is (zero displacement)."""
        self.map[..., 4 * c : 4 * c + 4] = 0.0
        if self.left is not None:
            self.left[..., c] = 0.0
        self.frames[c] = self.starts[c] = n

    def _band(self, index):
        if self.band is None:
            return np.arange(int(np.prod(self.st.grid.shape)))
        mask = np.zeros(self.st.grid.shape, dtype=bool)
        mask.reshape(-1)[index] = True
        return np.flatnonzero(dilate(mask, self.band, periodic_lon=self.st.grid.periodic_lon, poles=self.index.poles))

    def advance(self, copies, n, index):
        """Move copies ``copies`` (all at frame ``n - 1``) to frame ``n`` for the vertices around ``index``."""
        st = self.st
        need = self._band(index)
        xyz, s, y, z = st._one_frame(n, need)
        fr = self.index.fractional(y, z)
        d = self.index.cubic(self.map, *fr) if self.order == 3 else self.index.trilinear(self.map, *fr)
        asked = np.zeros(int(np.prod(st.grid.shape)), dtype=bool)
        asked[index] = True
        asked = asked[need]
        top = st.grid.shape[0] - 1
        values = np.empty((need.size, 4 * len(copies)), dtype=np.float32)
        left = self.index.trilinear(self.left, *fr) if self.left is not None else None
        flags = np.zeros((need.size, len(copies)), dtype=bool)
        for a, c in enumerate(copies):
            dc = d[:, 4 * c : 4 * c + 4]
            sx, sz = _normalise(y + dc[:, :3]), np.clip(z + dc[:, 3], 0.0, top)
            unsure = ~np.all(np.isfinite(dc), axis=1)
            if left is not None:
                unsure |= left[:, c] > 0
            redo = asked & unsure
            if redo.any():
                self.fallbacks += int(redo.sum())
                sx[redo], sz[redo] = trace(st.wind, xyz[redo], s[redo], st.frame_hours[n], st.frame_hours[self.starts[c]],
                                           vertices=need[redo], **st.opts)
            if left is not None:  # started outside (stopped at the edge), or composed from such starts
                flags[:, a] = np.isnan(self.index.fractional(sx, sz)[2]) | (unsure & ~redo)
            values[:, 4 * a : 4 * a + 3] = sx - xyz
            values[:, 4 * a + 3] = sz - s
        self._store(copies, need, values)
        if left is not None:
            for a, c in enumerate(copies):
                mark = np.zeros(st.grid.shape, dtype=bool)
                mark.reshape(-1)[need] = flags[:, a]
                # Grown by a cell: the bicubic stencil reaches one vertex beyond the trilinear one.
                self.index.padded(dilate(mark, 1).astype(np.float32)[..., None], out=self.left[..., c : c + 1])
        for c in copies:
            self.frames[c] = n

    def _store(self, copies, need, values):
        nc = values.shape[1]
        if nc not in self._scratch:  # reused: a fresh grid-sized array each frame costs its page faults again
            self._scratch[nc] = np.empty(self.st.grid.shape + (nc,), dtype=np.float32)
        m = self._scratch[nc]
        m.fill(np.nan)
        m.reshape(-1, nc)[need] = values
        if self.band is not None:
            m = _extend(m, self.band + 2)
        if list(copies) == list(range(copies[0], copies[-1] + 1)):
            self.index.padded(m, out=self.map[..., 4 * copies[0] : 4 * copies[-1] + 4])
        else:
            for a, c in enumerate(copies):
                self.index.padded(m[..., 4 * a : 4 * a + 4], out=self.map[..., 4 * c : 4 * c + 4])

    def lookup(self, index):
        """Start positions ``[(xyz, s), ...]`` of every copy at the vertices ``index`` (flat indices)."""
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        d = self.map.reshape(-1, self.map.shape[-1]).take(self.index.rows(index), axis=0).astype(np.float64)
        xyz, s = self.st._points(index)
        top = self.st.grid.shape[0] - 1
        return [(_normalise(xyz + d[:, 4 * c : 4 * c + 3]), np.clip(s + d[:, 4 * c + 3], 0.0, top)) for c in range(len(self.frames))]

    def at(self, n, index, starts):
        """The maps at frame ``n`` of the copies started at frames ``starts`` (streaming), for vertices ``index``."""
        for c, start in enumerate(starts):
            if self.frames[c] is None or self.starts[c] != start or n < self.frames[c]:
                self.reset(c, start)
        while min(self.frames) < n:
            m = min(self.frames) + 1
            self.advance([c for c, f in enumerate(self.frames) if f == m - 1], m, index)
        return self.lookup(index)


LEVEL_CELLS = 4
"""How many cells apart adjacent levels count when the band's edge is extended (same-level values first)."""


def _extend(m, cells):
    """Fill NaN vertices of ``m`` (nk, nj, ni, 4 c) within ``cells`` of stored ones with the nearest stored value.

    Distances are Euclidean in (row, column) with adjacent levels
    :data:`LEVEL_CELLS` apart, so within reach the nearest value comes from the
    vertex's own level or the level just below or above.  That is one 2-D
    distance transform of all levels stacked with ``cells + 1`` empty rows
    between them (faster than a 3-D one), then a choice among the three levels
    per vertex.  Each group of four channels is one copy's map; vertices stored
    for every copy are the sources, so one distance transform serves them all.
    """
    nk, nj, ni, nc = m.shape
    missing_c = np.isnan(m[..., ::4])
    missing = missing_c[..., 0].copy()
    for c in range(1, nc // 4):
        missing |= missing_c[..., c]
    if not missing.any() or missing.all():
        return m
    reach = int(np.floor(cells))
    rows = nj + reach + 1  # a level and the gap after it: no other level's vertex is within reach
    stack = np.ones((nk, rows, ni), dtype=bool)
    stack[:, :nj] = missing
    near = ndimage.distance_transform_edt(stack.reshape(nk * rows, ni), return_distances=False, return_indices=True)
    r_near = near[0].reshape(nk, rows, ni)[:, :nj]
    c_near = near[1].reshape(nk, rows, ni)[:, :nj]
    r_self = (np.arange(nk, dtype=np.int32)[:, None] * rows + np.arange(nj, dtype=np.int32))[:, :, None]
    dr = (r_near - r_self).astype(np.int64)  # squares of far rows of other levels overflow int32 on big grids
    dc = c_near - np.arange(ni, dtype=np.int32)
    cost = (dr * dr + dc * dc).reshape(nk, -1)
    src = ((r_near // rows * nj + r_near % rows) * ni + c_near).reshape(nk, -1)
    for lo, hi in ((slice(1, None), slice(None, -1)), (slice(None, -1), slice(1, None))):  # from below, from above
        via = cost[hi] + LEVEL_CELLS**2
        better = via < cost[lo]
        cost[lo][better] = via[better]
        src[lo][better] = src[hi][better]
    have = (cost <= cells * cells).reshape(missing.shape)
    flat = m.reshape(-1, nc)
    src = src.reshape(-1)
    for c in range(nc // 4):
        fill = np.flatnonzero(missing_c[..., c] & have)
        flat[fill, 4 * c : 4 * c + 4] = flat[src[fill], 4 * c : 4 * c + 4]
    return m


def dilate(mask, cells, periodic_lon=False, poles=False):
    """Grow a boolean (nk, nj, ni) mask by ``cells`` in latitude/longitude and one level.

    With ``poles`` the first and last rows neighbour themselves half way round
    in longitude, so the mask grows across the poles (a periodic longitude
    with an even number of columns).
    """
    m = mask.copy()
    half = m.shape[2] // 2
    for _ in range(int(cells)):
        g = m.copy()
        g[:, 1:] |= m[:, :-1]
        g[:, :-1] |= m[:, 1:]
        if poles:
            g[:, 0] |= np.roll(m[:, 0], half, axis=1)
            g[:, -1] |= np.roll(m[:, -1], half, axis=1)
        if periodic_lon:
            g |= np.roll(m, 1, axis=2) | np.roll(m, -1, axis=2)
        else:
            g[:, :, 1:] |= m[:, :, :-1]
            g[:, :, :-1] |= m[:, :, 1:]
        m = g
    g = m.copy()
    g[1:] |= m[:-1]
    g[:-1] |= m[1:]
    return g


DEFAULT_BAND = 5
"""Cells kept around the requested vertices by the streamed maps.  Beyond the
band a map holds only nearest-value extensions, which a vertex whose foot
point's stencil reaches them inherits: on the demo, restart copies at frames
100-123 are 72 km off at worst with a band of 4 cells, 10.4 km with 5, 6 or 8
(a direct trace of the same vertices: 17 km; benchmarks/bench_advect.py);
frames 1-24 need only 4."""


def _band_cells(band):
    """The streamed map's band: :data:`DEFAULT_BAND` for None, None (whole grid) for ``"all"``."""
    if band is None:
        return DEFAULT_BAND
    return None if band == "all" else band


class ComposedTrace(_Strategy):
    """Strategy (b): compose one-frame backward maps, interpolated on the grid.

    Cost per frame: one frame of tracing for the vertices around those asked
    for, plus one interpolation; the interpolation error accumulates over the
    film (``order=1``, trilinear, smears the map; ``order=3``, Catmull-Rom
    bicubic, keeps it sharp).  ``band`` cells around the requested vertices
    are kept (default :data:`DEFAULT_BAND`; ``"all"``: the whole grid).
    Frames should be requested in increasing order; an earlier frame restarts
    from frame 0.
    """

    name = "compose"

    def __init__(self, wind, frame_hours, grid, *, order=3, band=None, **opts):
        super().__init__(wind, frame_hours, grid, **opts)
        if order not in (1, 3):
            raise ValueError(f"order must be 1 or 3, got {order!r}")
        self.stream = _StreamedMap(self, order, _band_cells(band))

    def copies(self, n, index):
        n = self._frame(n)
        (x, z), = self.stream.at(n, index, [0])
        return [Copy(x, z, 1.0, self.frame_hours[0])]


class RestartTrace(_Strategy):
    """Strategy (c): two texture copies restarted every ``period`` frames, half a period apart.

    Copy A restarts (start = current position) at frames ``0, P, 2P, ...``, copy
    B at ``P/2, 3P/2, ...``; their weights are triangle ramps
    ``w_A = 1 - |2 ((n mod P) / P) - 1|``, ``w_B = 1 - w_A``, so each copy is
    invisible when it restarts and the texture never stretches without bound.
    With ``incremental=True`` each copy is streamed by composition (cost of
    one frame per frame, frames in increasing order); otherwise every frame is
    traced directly back to the restarts (independent frames, cost up to ``P``).
    """

    name = "restart"

    def __init__(self, wind, frame_hours, grid, *, period=24, incremental=True, order=3, band=None, **opts):
        super().__init__(wind, frame_hours, grid, **opts)
        if int(period) != period or int(period) < 2 or int(period) % 2:
            raise ValueError(f"period must be an even number of frames >= 2, got {period!r}")
        self.period = int(period)
        self.incremental = bool(incremental)
        self.stream = _StreamedMap(self, order, _band_cells(band), copies=2)

    def weights(self, n):
        """``(w_A, w_B)`` at frame ``n``."""
        p = self.period
        wa = 1.0 - abs(2.0 * ((n % p) / p) - 1.0)
        return wa, 1.0 - wa

    def restarts(self, n):
        """Frames at which copies A and B last restarted (clamped at frame 0)."""
        p = self.period
        return n - n % p, max(0, n - (n - p // 2) % p)

    def copies(self, n, index):
        n = self._frame(n)
        starts = self.restarts(n)
        if self.incremental:
            found = self.stream.at(n, index, starts)
        else:
            xyz, s = self._points(index)
            found = [trace(self.wind, xyz, s, self.frame_hours[n], self.frame_hours[start], vertices=index, **self.opts)
                     for start in starts]
        return [Copy(x, z, w, self.frame_hours[start]) for (x, z), start, w in zip(found, starts, self.weights(n))]


STRATEGIES = {"full": FullTrace, "compose": ComposedTrace, "restart": RestartTrace}

START = "nephele_start_{}"
"""Vector attribute: start position (unit vector) of copy ``a`` or ``b`` at each mesh vertex."""
START_ALT = "nephele_start_alt_{}"
"""Float attribute: start height (m) of copy ``a`` or ``b``."""
WEIGHT = "nephele_weight_{}"
"""Float attribute: blending weight of copy ``a`` or ``b`` (the same at every vertex)."""
COPIES = ("a", "b")


def grid_vertices(grid, index=None):
    """Unit vectors of grid vertices (all, or the flat indices ``index``), ``(n, 3)``."""
    nk, nj, ni = grid.shape
    if grid.curvilinear:
        cols = lonlat_to_xyz(grid.lon2d, grid.lat2d).reshape(-1, 3)
        if index is None:
            return np.tile(cols, (nk, 1))
        return cols[np.asarray(index) % (nj * ni)]
    lam = np.deg2rad(grid.lon)
    phi = np.deg2rad(grid.lat)
    if index is None:
        j, i = np.divmod(np.arange(nj * ni), ni)
        j = np.tile(j, nk)
        i = np.tile(i, nk)
    else:
        _, j, i = np.unravel_index(np.asarray(index), grid.shape)
    cp = np.cos(phi[j])
    return np.stack([cp * np.cos(lam[i]), cp * np.sin(lam[i]), np.sin(phi[j])], axis=1)


def vertex_levels(grid, index):
    """Level index of the flat vertex indices ``index`` (float)."""
    return np.unravel_index(np.asarray(index), grid.shape)[0].astype(np.float64)


def active_vertices(values, level, periodic_lon=False):
    """Flat indices of the vertices of cells that hold the ``level`` contour.

    A cell is active when its 8 vertex values straddle ``level``
    (``min <= level <= max``); cells with a NaN vertex are skipped, as the
    contour skips them.  With ``periodic_lon`` the cells between the last and
    the first column count too.

    Parameters
    ----------
    values : (nk, nj, ni) array
    level : float
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 3:
        raise ValueError(f"values must be (nk, nj, ni), got shape {v.shape}")
    if periodic_lon:
        v = np.concatenate([v, v[:, :, :1]], axis=2)
    lo = np.minimum(v[:-1], v[1:])
    hi = np.maximum(v[:-1], v[1:])
    lo = np.minimum(lo[:, :-1], lo[:, 1:])
    hi = np.maximum(hi[:, :-1], hi[:, 1:])
    lo = np.minimum(lo[:, :, :-1], lo[:, :, 1:])
    hi = np.maximum(hi[:, :, :-1], hi[:, :, 1:])
    cell = (lo <= level) & (hi >= level)
    mark = np.zeros(v.shape, dtype=bool)
    for a in (0, 1):
        for b in (0, 1):
            for c in (0, 1):
                mark[a : a + cell.shape[0], b : b + cell.shape[1], c : c + cell.shape[2]] |= cell
    if periodic_lon:
        mark[:, :, 0] |= mark[:, :, -1]
        mark = mark[:, :, :-1]
    return np.flatnonzero(mark)


def start_coordinates(wind, copy):
    """Start longitude, latitude (degrees) and height (m) of a :class:`Copy`.

    True longitude and latitude on the globe: a rotated-pole grid's winds are
    traced in the grid's own frame, so its start points are turned back with
    the grid's rotation.
    """
    rotation = getattr(getattr(wind, "grid", None), "rotation", None)
    lon, lat, _ = xyz_to_lonlat(copy.xyz if rotation is None else copy.xyz @ rotation.T)
    if isinstance(wind, WindField):
        alt = wind.start_height(copy.xyz, copy.s)
    else:
        alt = copy.s.copy()
    return lon, lat, alt


def great_circle_km(a, b, radius=EARTH_RADIUS):
    """Great-circle distance in km between unit vectors ``a`` and ``b`` (n, 3) on a planet of ``radius`` metres."""
    a, b = _normalise(np.asarray(a, float)), _normalise(np.asarray(b, float))
    c = np.linalg.norm(np.cross(a, b), axis=1)
    d = np.sum(a * b, axis=1)
    return np.arctan2(c, d) * float(radius) / 1000.0


__all__ = [
    "COPIES",
    "START",
    "START_ALT",
    "WEIGHT",
    "AnalyticWind",
    "ComposedTrace",
    "Copy",
    "FullTrace",
    "RestartTrace",
    "STRATEGIES",
    "WindField",
    "active_vertices",
    "dilate",
    "grid_vertices",
    "great_circle_km",
    "start_coordinates",
    "steps_to_keep",
    "trace",
    "vertex_levels",
]
