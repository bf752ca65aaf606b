"""Fractional grid indices of points on the sphere, and the gathers that interpolate padded fields there.

:class:`_GridIndex` serves a longitude/latitude grid (rows mirrored across
each pole, periodic columns wrapped); :class:`_ColumnIndex` a curvilinear one,
its columns located with :class:`~nephele.core.climate.columns.ColumnLocator`.
Both give every stencil (trilinear, or Catmull-Rom bicubic in row and column)
as one fixed set of flat offsets from its first tap.  Used by the winds
(:mod:`.winds`) and the streamed maps of the strategies (:mod:`.advect`).

References
----------
.. [1] E. Catmull and R. Rom, "A class of local interpolating splines", in
   Computer Aided Geometric Design, Academic Press, 1974.
"""

import numpy as np

from ..climate.columns import ColumnLocator
from ..climate.grid import lonlat_to_xyz


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
            outside = (
                (d < -eps)
                | (d > self.lon_axis[-1] + eps)
                | (lat < self.lat_axis[0] - eps)
                | (lat > self.lat_axis[-1] + eps)
            )
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
                out = self._taps(
                    f, fk, np.where(outside, float(self.pad), fj), np.where(outside, 0.0, fi), cubic, chunk
                )
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
        block = (
            16 * chunk
        )  # weights made a block at a time: one (taps, n) array would be tens of MB, page-faulted anew each call
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
