"""Points on the globe back to fractional column indices of a curvilinear (2-D lon/lat) grid.

A regional grid (WRF, Lambert conformal, polar stereographic) places column
``(j, i)`` at ``lon2d[j, i]``, ``lat2d[j, i]``.  Between columns the grid is
taken bilinear in the gnomonic projection about the grid's centre (great
circles are straight lines there, and the whole region is one chart, poles
included).  :class:`ColumnLocator` inverts that map: the nearest column
(k-d tree) names four candidate cells, and Newton's method on each cell's
bilinear map gives the fractions; a point lies in the first cell whose
fractions fall in [0, 1].

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (resampling curvilinear grids).
.. [2] J. P. Snyder, "Map Projections: A Working Manual", USGS Prof. Paper
   1395 (1987), gnomonic projection.
"""

import numpy as np

from ..errors import DataError
from .grid import lonlat_to_xyz

_EDGE = 1e-9
"""Fractions this far outside [0, 1] still count as inside (rounding on shared cell edges)."""


class ColumnLocator:
    """Fractional ``(i, j)`` column indices of Cartesian points over a curvilinear grid.

    Parameters
    ----------
    lon2d, lat2d : (nj, ni) arrays
        True longitude and latitude (degrees) of every column.
    path : str, optional
        Named in errors.

    Raises
    ------
    DataError
        Fewer than 2 x 2 columns, non-finite positions, or a grid reaching
        more than ~78 degrees from its centre (no single gnomonic chart).
    """

    def __init__(self, lon2d, lat2d, path=None):
        lon2d, lat2d = np.asarray(lon2d, dtype=np.float64), np.asarray(lat2d, dtype=np.float64)
        if lon2d.ndim != 2 or lon2d.shape != lat2d.shape or min(lon2d.shape) < 2:
            raise DataError(f"needs matching 2-D longitudes/latitudes of at least 2 x 2 columns, got {lon2d.shape} "
                            f"and {lat2d.shape}",
                            path=path, field="lon2d")
        if not (np.all(np.isfinite(lon2d)) and np.all(np.isfinite(lat2d))):
            raise DataError("has NaN or infinite coordinates", path=path, field="lon2d")
        p = lonlat_to_xyz(lon2d, lat2d)
        c = p.reshape(-1, 3).mean(axis=0)
        norm = np.linalg.norm(c)
        if norm < 1e-6:
            raise DataError("the columns surround the globe: no centre for a regional chart", path=path, field="lon2d")
        c /= norm
        if float((p @ c).min()) < 0.2:
            raise DataError("the grid reaches more than 78 degrees from its centre; volumes need a regional grid",
                            path=path, field="lon2d")
        a = np.array([0.0, 0.0, 1.0]) if abs(c[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(a, c)
        e1 /= np.linalg.norm(e1)
        self.basis = np.stack([e1, np.cross(c, e1), c])  # rows: chart x, chart y, centre
        self.xy = self.chart(p.reshape(-1, 3)).reshape(lon2d.shape + (2,))
        self._x, self._y = self.xy[..., 0].copy(), self.xy[..., 1].copy()
        self.shape = lon2d.shape
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.xy.reshape(-1, 2))
        # A point inside a cell is at most the cell's diameter from its nearest column: farther points are outside.
        x = self.xy
        corners = (x[:-1, :-1], x[:-1, 1:], x[1:, :-1], x[1:, 1:])
        self._reach = max(float(np.linalg.norm(a - b, axis=-1).max()) for n, a in enumerate(corners)
                          for b in corners[n + 1 :])
        self._raster()
        self._points = p.reshape(-1, 3)
        self._tree3 = None

    def _raster(self, per_cell=2):
        """A uniform raster over the chart's box naming, per pixel, the cell that holds its centre (or the
        nearest column's cell), and whether the whole pixel lies outside every cell: a first guess for
        :meth:`__call__` that one Newton inversion (or a short walk) confirms."""
        nj, ni = self.shape
        lo, hi = self.xy.reshape(-1, 2).min(axis=0), self.xy.reshape(-1, 2).max(axis=0)
        m = np.maximum(np.ceil(np.array([ni, nj]) * per_cell), 1).astype(int)
        step = (hi - lo) / m
        centres = lo + (np.stack(np.meshgrid(np.arange(m[0]), np.arange(m[1]), indexing="xy"), axis=-1).reshape(-1, 2)
                        + 0.5) * step
        dist, near = self._tree.query(centres, k=1)
        jn, in_ = np.divmod(np.asarray(near), ni)
        cj, ci = np.clip(jn, 0, nj - 2), np.clip(in_, 0, ni - 2)
        fi, fj = self._search(centres, np.arange(len(centres)))
        inside = fi >= 0
        ci[inside], cj[inside] = np.minimum(fi[inside].astype(int), ni - 2), np.minimum(fj[inside].astype(int), nj - 2)
        self._lo, self._step, self._m = lo, step, m
        self._cell = np.stack([cj, ci], axis=-1)
        self._empty = np.asarray(dist) > self._reach * (1 + 1e-9) + 0.5 * float(np.hypot(*step))

    def chart(self, xyz):
        """Gnomonic chart coordinates ``(n, 2)`` of points ``(n, 3)`` (any distance from the centre);
        NaN for points on the far side."""
        q = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) @ self.basis.T
        with np.errstate(divide="ignore", invalid="ignore"):
            out = q[:, :2] / q[:, 2:3]
        out[q[:, 2] <= 0.0] = np.nan
        return out

    def cell_degrees(self):
        """The widest angle (degrees) between two neighbouring columns."""
        u = self.xy
        p = np.concatenate([u, np.ones(u.shape[:2] + (1,))], axis=-1)
        p /= np.linalg.norm(p, axis=-1, keepdims=True)
        cosines = [np.sum(p[1:] * p[:-1], axis=-1), np.sum(p[:, 1:] * p[:, :-1], axis=-1),
                   np.sum(p[1:, 1:] * p[:-1, :-1], axis=-1), np.sum(p[1:, :-1] * p[:-1, 1:], axis=-1)]
        return float(np.rad2deg(np.arccos(np.clip(min(x.min() for x in cosines), -1.0, 1.0))))

    def nearest(self, xyz):
        """``(i, j)`` integer indices of the column nearest each point ``(n, 3)`` (by the angle from the centre)."""
        if self._tree3 is None:
            from scipy.spatial import cKDTree

            self._tree3 = cKDTree(self._points)
        q = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            q = q / np.linalg.norm(q, axis=1, keepdims=True)
        _, near = self._tree3.query(np.nan_to_num(q), k=1)
        j, i = np.divmod(np.asarray(near, dtype=np.int64), self.shape[1])
        return i, j

    def _invert(self, x, y, j0, i0, iters=4):
        """Fractions ``(s, t)`` along i and j of chart points ``(x, y)`` in cells with lowest corner ``(j0, i0)``.

        Newton's method on the bilinear map ``p00 + s a + t b + s t c``, started at the
        parallelogram's solution (exact for a parallelogram cell)."""
        X, Y = self._x, self._y
        x00, y00 = X[j0, i0], Y[j0, i0]
        ax, ay = X[j0, i0 + 1] - x00, Y[j0, i0 + 1] - y00
        bx, by = X[j0 + 1, i0] - x00, Y[j0 + 1, i0] - y00
        cx, cy = X[j0 + 1, i0 + 1] - x00 - ax - bx, Y[j0 + 1, i0 + 1] - y00 - ay - by
        rx, ry = x - x00, y - y00
        with np.errstate(divide="ignore", invalid="ignore"):
            det = ax * by - ay * bx
            s = (rx * by - ry * bx) / det
            t = (ax * ry - ay * rx) / det
            for _ in range(iters):
                np.clip(s, -2.0, 3.0, out=s)  # keep far misses finite
                np.clip(t, -2.0, 3.0, out=t)
                dsx, dsy = ax + t * cx, ay + t * cy
                dtx, dty = bx + s * cx, by + s * cy
                st = s * t
                fx = s * ax + t * bx + st * cx - rx
                fy = s * ay + t * by + st * cy - ry
                det = dsx * dty - dsy * dtx
                s -= (fx * dty - fy * dtx) / det
                t -= (dsx * fy - dsy * fx) / det
        return s, t

    def __call__(self, xyz):
        """``(i, j)`` fractional column indices of points ``(n, 3)``; ``-1`` for points outside the grid."""
        xy = self.chart(xyz)
        n = xy.shape[0]
        out_i, out_j = np.full(n, -1.0), np.full(n, -1.0)
        ok = np.all(np.isfinite(xy), axis=1)
        q = np.floor((np.where(ok[:, None], xy, 0.0) - self._lo) / self._step)
        ok &= np.all((q >= -1) & (q <= self._m), axis=1)  # well off the chart's box: in no cell
        q = np.clip(q, 0, self._m - 1).astype(np.int64)  # a pixel's width off the box: the edge pixel decides
        todo = np.flatnonzero(ok)
        pix = q[todo, 1] * self._m[0] + q[todo, 0]
        todo, pix = todo[~self._empty[pix]], pix[~self._empty[pix]]
        nj, ni = self.shape
        j0, i0 = self._cell[pix, 0], self._cell[pix, 1]
        for _ in range(3):  # the raster's cell, then up to two steps toward the point
            if not todo.size:
                break
            s, t = self._invert(xy[todo, 0], xy[todo, 1], j0, i0)
            hit = (s >= -_EDGE) & (s <= 1 + _EDGE) & (t >= -_EDGE) & (t <= 1 + _EDGE)
            out_i[todo[hit]] = i0[hit] + np.clip(s[hit], 0.0, 1.0)
            out_j[todo[hit]] = j0[hit] + np.clip(t[hit], 0.0, 1.0)
            todo, s, t, j0, i0 = todo[~hit], s[~hit], t[~hit], j0[~hit], i0[~hit]
            di = np.clip(np.floor(np.nan_to_num(s)), -1, 1).astype(np.int64)
            dj = np.clip(np.floor(np.nan_to_num(t)), -1, 1).astype(np.int64)
            # Beyond a boundary cell's outer edge (and next to the cell): outside the region.
            off_i = ((di < 0) & (i0 == 0)) | ((di > 0) & (i0 == ni - 2))
            off_j = ((dj < 0) & (j0 == 0)) | ((dj > 0) & (j0 == nj - 2))
            near = (s > -1) & (s < 2) & (t > -1) & (t < 2)
            gone = near & (off_i | off_j) & (off_i | (di == 0)) & (off_j | (dj == 0))
            todo, j0, i0 = todo[~gone], np.clip(j0 + dj, 0, nj - 2)[~gone], np.clip(i0 + di, 0, ni - 2)[~gone]
        if todo.size:  # the few left (edges, skewed cells): the search from the nearest columns
            fi, fj = self._search(xy[todo], np.arange(todo.size))
            out_i[todo], out_j[todo] = fi, fj
        return out_i, out_j

    def continued(self, xyz):
        """``(i, j)`` as :meth:`__call__` inside the grid; outside, the bilinear map of the
        nearest column's cell continued past the edge (no ``-1``: for lookups that must
        interpolate across the edge, e.g. the exact volume mode's index map)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        fi, fj = self(xyz)
        out = fi < 0
        if out.any():
            i, j = self.nearest(xyz[out])
            nj, ni = self.shape
            i0, j0 = np.clip(i, 0, ni - 2), np.clip(j, 0, nj - 2)
            xy = self.chart(xyz[out])
            s, t = self._invert(xy[:, 0], xy[:, 1], j0, i0)
            fi[out], fj[out] = i0 + s, j0 + t
        return fi, fj

    def _search(self, xy, todo):
        """Fractional ``(i, j)`` of chart points ``xy`` by trying the cells around their nearest columns; -1 outside."""
        n = xy.shape[0]
        out_i, out_j = np.full(n, -1.0), np.full(n, -1.0)
        nj, ni = self.shape
        for k in (1, 4):  # nearest column first; the few left (skewed cells, edges) try the 4 nearest
            if not todo.size:
                break
            dist, near = self._tree.query(xy[todo], k=k)
            near = np.asarray(near).reshape(todo.size, k)
            if k == 1:
                close = np.asarray(dist).reshape(-1) <= self._reach * (1 + 1e-9)
                todo, near = todo[close], near[close]
                if not todo.size:
                    break
            found = np.zeros(todo.size, bool)
            for col in near.T:
                jn, in_ = np.divmod(col, ni)
                X, Y = self._x, self._y
                # The cell on the point's side of the column along i and along j first (almost always it).
                rx, ry = xy[todo, 0] - X[jn, in_], xy[todo, 1] - Y[jn, in_]
                ip, im = np.minimum(in_ + 1, ni - 1), np.maximum(in_ - 1, 0)
                jp, jm = np.minimum(jn + 1, nj - 1), np.maximum(jn - 1, 0)
                di = np.where(rx * (X[jn, ip] - X[jn, im]) + ry * (Y[jn, ip] - Y[jn, im]) >= 0, 0, -1)
                dj = np.where(rx * (X[jp, in_] - X[jm, in_]) + ry * (Y[jp, in_] - Y[jm, in_]) >= 0, 0, -1)
                for flip_j, flip_i in ((0, 0), (0, 1), (1, 0), (1, 1)):
                    left = np.flatnonzero(~found)
                    if not left.size:
                        break
                    j0 = np.clip(jn[left] + (dj[left] if not flip_j else -1 - dj[left]), 0, nj - 2)
                    i0 = np.clip(in_[left] + (di[left] if not flip_i else -1 - di[left]), 0, ni - 2)
                    s, t = self._invert(xy[todo[left], 0], xy[todo[left], 1], j0, i0)
                    hit = (s >= -_EDGE) & (s <= 1 + _EDGE) & (t >= -_EDGE) & (t <= 1 + _EDGE)
                    rows = todo[left[hit]]
                    out_i[rows] = i0[hit] + np.clip(s[hit], 0.0, 1.0)
                    out_j[rows] = j0[hit] + np.clip(t[hit], 0.0, 1.0)
                    found[left[hit]] = True
            todo = todo[~found]
        return out_i, out_j

__all__ = ["ColumnLocator"]
