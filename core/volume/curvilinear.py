"""A globe grid's fields defined everywhere: trilinear in the curvilinear cell, closed across the seam and the poles.

A Cartesian point is mapped back analytically to longitude, latitude and
height; the longitude and latitude give the fractional column index
(periodic longitude, the poles closed by a ring of the last row's mean; a
curvilinear grid's columns located by
:class:`~nephele.core.climate.columns.ColumnLocator`), and the level is found
by searching the column's bilinearly interpolated terrain-following heights
(:class:`LevelTable`).  Used by the resampling (:mod:`.sparse`), the exact
rays (:mod:`.exact_ray`) and the atlas program (:mod:`.volume_atlas`).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

from dataclasses import dataclass

import numpy as np

from ..climate.columns import ColumnLocator
from ..climate.grid import DEFAULT_EXAGGERATION, globe_radius, height_from_radius
from ..errors import DataError


@dataclass(frozen=True, eq=False)
class CurvilinearField:
    """Scalar fields on a globe grid, closed across the seam and the poles.

    Build with :meth:`from_grid`.  ``lon`` (relative to ``lon0``, ascending
    from 0), ``lat``, ``height`` ``(nk, nj, ni)`` and each array in ``values``
    are the grid's, with a copy of the first column appended at +360° when
    the longitudes are periodic, and a pole row (mean of the nearest row) at
    ±90° when a periodic grid stops short of a pole.  ``rotation`` is the
    grid's rotated-pole matrix (:attr:`GlobeGrid.rotation`): points are located
    in the grid's own frame, so the field sits at its true place on the globe.
    ``columns``: for a curvilinear grid (2-D longitude/latitude), the
    :class:`~nephele.core.climate.columns.ColumnLocator` turning points into
    fractional column indices; ``lon``/``lat`` are then the index axes
    ``0..ni-1``/``0..nj-1`` (no seam, no poles to close).
    """

    lon0: float
    lon: np.ndarray
    lat: np.ndarray
    height: np.ndarray
    values: dict
    radius: float
    exaggeration: float
    rotation: np.ndarray = None
    columns: ColumnLocator = None

    @classmethod
    def from_grid(cls, grid, values, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
        """``values``: dict name → ``(nk, nj, ni)`` array (NaN = missing).

        A grid with 2-D longitude/latitude is located by its columns
        (:class:`~nephele.core.climate.columns.ColumnLocator`).
        """
        grid.validate()
        if not (np.isfinite(radius) and radius > 0 and np.isfinite(exaggeration) and exaggeration > 0):
            raise DataError(f"radius {radius} and exaggeration {exaggeration} must be positive", field="exaggeration")
        lon = grid.lon - grid.lon[0]
        lat = grid.lat.copy()
        height = grid.height.copy()
        vals = {}
        for name, a in values.items():
            a = np.asarray(a, dtype=np.float32)
            if a.shape != grid.shape:
                raise DataError(f"shape {a.shape} does not match the grid {grid.shape}", field=name)
            vals[name] = a
        if grid.curvilinear:
            if np.any(np.diff(height, axis=0) <= 0):
                raise DataError("levels are not strictly increasing upward", field="height")
            nk, nj, ni = grid.shape
            return cls(
                0.0,
                np.arange(ni, dtype=np.float64),
                np.arange(nj, dtype=np.float64),
                height,
                vals,
                float(radius),
                float(exaggeration),
                None,
                ColumnLocator(grid.lon2d, grid.lat2d),
            )
        if grid.periodic_lon:
            lon = np.append(lon, 360.0)
            height = np.concatenate([height, height[:, :, :1]], axis=2)
            vals = {n: np.concatenate([a, a[:, :, :1]], axis=2) for n, a in vals.items()}
            # Close the poles: a ring at ±90° holding the nearest row's mean, so
            # the field is continuous over the pole instead of a hole.
            for side, pole in ((0, -90.0), (-1, 90.0)):
                if (lat[0] > -90.0) if side == 0 else (lat[-1] < 90.0):
                    ring_h = np.broadcast_to(height[:, side, :-1].mean(axis=1)[:, None], height[:, 0].shape)
                    rings = {}
                    for n, a in vals.items():
                        row = a[:, side, :-1]
                        with np.errstate(invalid="ignore"):
                            m = np.where(np.isnan(row).any(axis=1), np.nan, row.mean(axis=1, dtype=np.float64))
                        rings[n] = np.broadcast_to(m[:, None], a[:, 0].shape).astype(np.float32)
                    if side == 0:
                        lat = np.concatenate([[pole], lat])
                        height = np.concatenate([ring_h[:, None], height], axis=1)
                        vals = {n: np.concatenate([rings[n][:, None], a], axis=1) for n, a in vals.items()}
                    else:
                        lat = np.append(lat, pole)
                        height = np.concatenate([height, ring_h[:, None]], axis=1)
                        vals = {n: np.concatenate([a, rings[n][:, None]], axis=1) for n, a in vals.items()}
        if np.any(np.diff(height, axis=0) <= 0):
            raise DataError("levels are not strictly increasing upward", field="height")
        return cls(float(grid.lon[0]), lon, lat, height, vals, float(radius), float(exaggeration), grid.rotation)

    @property
    def shape(self):
        return self.height.shape

    def radius_range(self):
        """Smallest radius of the lowest level and largest of the top level."""
        return (
            float(globe_radius(self.height[0].min(), self.radius, self.exaggeration)),
            float(globe_radius(self.height[-1].max(), self.radius, self.exaggeration)),
        )

    def __post_init__(self):
        object.__setattr__(self, "_index_tables", (_IndexTable(self.lon), _IndexTable(self.lat)))
        object.__setattr__(self, "_all_levels", None)

    def level_table(self, levels=None, clamp_below=0.0):
        """A :class:`LevelTable` for :meth:`locate` (build once, locate many points)."""
        if levels is None and clamp_below == 0.0:
            if self._all_levels is None:
                object.__setattr__(self, "_all_levels", LevelTable(self, None, 0.0))
            return self._all_levels
        return LevelTable(self, levels, clamp_below)

    def locate(self, xyz, levels=None, clamp_below=0.0):
        """Cell and fractions of Cartesian points.

        Parameters
        ----------
        xyz : (n, 3) array
        levels : (kmin, kmax) pair of ``(nj-1, ni-1)`` int arrays, or LevelTable, optional
            Per column, the only cells worth locating (``kmin > kmax`` for
            none); points elsewhere come back with ``ok`` False.  Used by
            :func:`resample` to skip transparent cells.  A :class:`LevelTable`
            (from :meth:`level_table`, which then also holds ``clamp_below``)
            saves rebuilding it per call.
        clamp_below : float
            Points up to this many metres under the lowest level (below the
            terrain) take the lowest level's values instead of being outside.  The ground hides them;
            extending the field there keeps voxels straddling the ground from
            blending the cloud with empty space.

        Returns
        -------
        flat : (n,) int
            Flat index of each point's cell's lowest corner in ``(nk, nj, ni)``.
        f : (n, 3)
            Fractions along (level, lat, lon).
        h : (n,)
            Height in metres.
        ok : (n,) bool
            Inside the grid (and the ``levels``).  Other rows hold arbitrary
            in-range indices.
        """
        table = levels if isinstance(levels, LevelTable) else self.level_table(levels, clamp_below)
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        sel, flat_s, fk, fj, fi, h = self._locate_inside(xyz, table)
        flat = np.zeros(h.shape, dtype=np.intp)
        f = np.zeros((h.size, 3))
        ok = np.zeros(h.shape, bool)
        flat[sel] = flat_s
        f[sel, 0], f[sel, 1], f[sel, 2] = fk, fj, fi
        ok[sel] = True
        return flat, f, h, ok

    def _locate_inside(self, xyz, table):
        """:meth:`locate` for the points inside only: ``(sel, flat, fk, fj, fi, h)``,
        ``sel`` the indices of the inside points, ``h`` the heights of all."""
        if self.columns is not None:
            return self._locate_columns(*self._column_coords(xyz), table)
        if self.rotation is not None:
            xyz = xyz @ self.rotation
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        rxy2 = x * x + y * y
        lon, i, fi = self._lon_index(x, y)
        return self._locate_columns(lon, i, fi, *self._lat_height(rxy2, z), table)

    def _lon_index(self, x, y):
        """Longitude relative to ``lon0`` in [0, 360], its cell and fraction."""
        lon = np.arctan2(y, x)
        lon *= 180.0 / np.pi
        lon -= self.lon0
        # [0, 360) without np.mod, which costs more than the rest of this together.
        lon += 360.0 * (lon < 0.0)
        lon += 360.0 * (lon < 0.0)  # lon0 may be up to 360 east of the result
        lon -= 360.0 * (lon >= 360.0)
        i = self._index_tables[0](lon)
        ax = self.lon
        fi = (lon - ax[i]) / (ax[i + 1] - ax[i])
        np.clip(fi, 0.0, 1.0, out=fi)
        return lon, i, fi

    def _column_coords(self, xyz):
        """A curvilinear grid's ``(i, cell, fraction, j, height)`` of points ``(n, 3)``: the arguments
        of :meth:`_locate_columns` (``i``/``j`` fractional column indices, -1 outside the grid)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        x, j = self.columns(xyz)
        i = self._index_tables[0](x)
        fi = np.clip(x - self.lon[i], 0.0, 1.0)
        return x, i, fi, j, height_from_radius(np.sqrt(np.einsum("ij,ij->i", xyz, xyz)), self.radius, self.exaggeration)

    def _lat_height(self, rxy2, z):
        """Latitude (degrees) and height (metres) from ``x² + y²`` and ``z``."""
        r = np.sqrt(rxy2 + z * z)
        lat = np.arctan2(z, np.sqrt(rxy2))
        lat *= 180.0 / np.pi
        return lat, height_from_radius(r, self.radius, self.exaggeration)

    def _locate_columns(self, x, i, fi, lat, h, table):
        """The rest of :meth:`_locate_inside`, from relative longitude ``x`` with
        its cell ``i`` and fraction ``fi``, latitude and height (flat arrays)."""
        clamp_below = table.clamp_below
        nk, nj, ni = self.shape
        j = self._index_tables[1](lat)
        cell = j * (ni - 1) + i
        # Cheap rejections first: outside the grid's columns, or outside the
        # height range that the column's candidate cells can reach.
        lon_ax, lat_ax = self.lon, self.lat
        ok = (h >= table.hlo[cell]) & (h <= table.hhi[cell])
        if lon_ax[-1] - lon_ax[0] < 360.0:
            ok &= (x >= lon_ax[0]) & (x <= lon_ax[-1])
        if lat_ax[0] > -90.0 or lat_ax[-1] < 90.0:
            ok &= (lat >= lat_ax[0]) & (lat <= lat_ax[-1])
        sel = np.flatnonzero(ok)
        i, j, fi, lat, cell = i[sel], j[sel], fi[sel], lat[sel], cell[sel]
        fj = np.clip((lat - lat_ax[j]) / (lat_ax[j + 1] - lat_ax[j]), 0.0, 1.0)
        h_s = h[sel]
        col = j * ni + i
        hf = self.height.reshape(-1)
        w = ((1 - fj) * (1 - fi), (1 - fj) * fi, fj * (1 - fi), fj * fi)
        corners = (col, col + 1, col + ni, col + ni + 1)
        layer = nj * ni

        def column_height(level):
            base = level * layer
            return (
                w[0] * hf[base + corners[0]]
                + w[1] * hf[base + corners[1]]
                + w[2] * hf[base + corners[2]]
                + w[3] * hf[base + corners[3]]
            )

        # The level: bracketed by the column's height table, then a binary
        # search (heights increase upward in every column, so the bilinear
        # mix of four columns does too).  Invariant: the answer is in
        # [lo, hi), the largest level whose mixed height is <= h.
        lo, hi = table.bracket(cell, h_s)
        while True:
            open_ = np.flatnonzero(hi - lo > 1)
            if not open_.size:
                break
            mid = (lo[open_] + hi[open_]) // 2
            base = mid * layer
            ww = [a[open_] for a in w]
            cc = [a[open_] for a in corners]
            hm = (
                ww[0] * hf[base + cc[0]]
                + ww[1] * hf[base + cc[1]]
                + ww[2] * hf[base + cc[2]]
                + ww[3] * hf[base + cc[3]]
            )
            go = hm <= h_s[open_]
            lo[open_] = np.where(go, mid, lo[open_])
            hi[open_] = np.where(go, hi[open_], mid)
        h0, h1 = column_height(lo), column_height(lo + 1)
        inside = (h_s <= h1) & (h_s >= h0)
        if clamp_below > 0:
            inside |= (lo == 0) & (h_s < h0) & (h_s >= h0 - clamp_below)
        fk = np.clip((h_s - h0) / (h1 - h0), 0.0, 1.0)
        keep = np.flatnonzero(inside)
        return sel[keep], (lo * layer + col)[keep], fk[keep], fj[keep], fi[keep], h

    def interpolate(self, name, flat, f, ok):
        """Trilinear value of field ``name`` at located points; NaN outside or
        where a corner of the cell is missing."""
        out = self._trilinear(name, flat, f[:, 0], f[:, 1], f[:, 2])
        out[~ok] = np.nan
        return out

    def _trilinear(self, name, flat, fk, fj, fi):
        a = self.values[name].reshape(-1)
        nk, nj, ni = self.shape
        out = np.zeros(flat.shape, dtype=np.float64)
        for dk in (0, 1):
            wk = fk if dk else 1 - fk
            for dj in (0, 1):
                wjk = wk * (fj if dj else 1 - fj)
                for di in (0, 1):
                    out += (wjk * (fi if di else 1 - fi)) * a[flat + (dk * nj * ni + dj * ni + di)]
        return out

    def below_ground(self, xyz):
        """True for points within the grid's longitudes and latitudes but under its lowest level."""
        flat, f, h, ok = self.locate(xyz, clamp_below=np.inf)
        nk, nj, ni = self.shape
        col = flat % (nj * ni)
        hf = self.height.reshape(nk, -1)[0]
        fj, fi = f[:, 1], f[:, 2]
        ground = (1 - fj) * ((1 - fi) * hf[col] + fi * hf[col + 1]) + fj * (
            (1 - fi) * hf[col + ni] + fi * hf[col + ni + 1]
        )
        return ok & (h < ground)

    def sample(self, name, xyz):
        """Field ``name`` at Cartesian points (NaN outside the grid or missing)."""
        flat, f, _, ok = self.locate(xyz)
        return self.interpolate(name, flat, f, ok)

    def cell_corner_points(self):
        """Cartesian vertices ``(nk, nj, ni, 3)`` of the closed grid."""
        r = globe_radius(self.height, self.radius, self.exaggeration)
        if self.columns is not None:  # the columns' unit vectors, from their gnomonic chart positions
            u = np.concatenate([self.columns.xy, np.ones(self.columns.shape + (1,))], axis=-1) @ self.columns.basis
            return r[..., None] * (u / np.linalg.norm(u, axis=-1, keepdims=True))[None]
        lam = np.deg2rad(self.lon + self.lon0)[None, None, :]
        phi = np.deg2rad(self.lat)[None, :, None]
        cphi = np.cos(phi)
        pts = np.stack(np.broadcast_arrays(r * cphi * np.cos(lam), r * cphi * np.sin(lam), r * np.sin(phi)), axis=-1)
        return pts if self.rotation is None else pts @ self.rotation.T

class _IndexTable:
    """``searchsorted(axis, x, "right") - 1`` clipped to ``[0, n-2]`` by a
    lookup table finer than the smallest spacing and one correction step."""

    def __init__(self, axis):
        self.axis = np.asarray(axis, dtype=np.float64)
        n = self.axis.size
        span = self.axis[-1] - self.axis[0]
        cells = int(min(np.ceil(span / np.diff(self.axis).min()) + 1, 1 << 20))
        self.scale = cells / span
        edges = self.axis[0] + np.arange(cells) / self.scale
        self.table = np.clip(np.searchsorted(self.axis, edges, side="right") - 1, 0, n - 2).astype(np.intp)
        self.cells = cells
        # Cell bounds for the correction steps, open at the ends so that the
        # index never leaves [0, n-2].
        self.upper = self.axis[1:].copy()
        self.upper[-1] = np.inf
        self.lower = self.axis[:-1].copy()
        self.lower[0] = -np.inf

    def __call__(self, x):
        t = x - self.axis[0]
        t *= self.scale
        np.maximum(t, 0, out=t)
        np.minimum(t, self.cells - 1, out=t)
        i = self.table[t.astype(np.intp)]
        # A table cell holds at most one axis point: one step up at most, and
        # one step down where rounding put x just below its cell's edge.
        i += x >= self.upper[i]
        i -= x < self.lower[i]
        return i

class LevelTable:
    """Per grid column, what :meth:`CurvilinearField.locate` needs to find levels fast.

    For the candidate levels ``kmin..kmax`` of each column (all by default):
    the height range ``hlo..hhi`` the column's cells can reach (the corners'
    extremes: a bilinear mix stays between them; ``hlo`` lowered by
    ``clamp_below`` where the range starts at the ground), and a table over
    ``bins`` height bins giving, for any height in a bin, a level range
    certain to hold the point's level (from the corners' lowest and highest
    heights per level), so that the binary search takes one or two steps.
    """

    def __init__(self, field, levels=None, clamp_below=0.0, bins=32):
        nk, nj, ni = field.shape
        H = field.height
        hmin = np.minimum(np.minimum(H[:, :-1, :-1], H[:, :-1, 1:]), np.minimum(H[:, 1:, :-1], H[:, 1:, 1:])).reshape(
            nk, -1
        )
        hmax = np.maximum(np.maximum(H[:, :-1, :-1], H[:, :-1, 1:]), np.maximum(H[:, 1:, :-1], H[:, 1:, 1:])).reshape(
            nk, -1
        )
        ncol = hmin.shape[1]
        if levels is None:
            k0 = np.zeros(ncol, np.intp)
            k1 = np.full(ncol, nk - 2, np.intp)
        else:
            k0 = np.asarray(levels[0]).reshape(-1).astype(np.intp)
            k1 = np.asarray(levels[1]).reshape(-1).astype(np.intp)
        c = np.arange(ncol)
        none = k0 > k1
        k0c, k1c = np.clip(k0, 0, nk - 2), np.clip(k1, 0, nk - 2)
        hlo = hmin[k0c, c] - np.where(k0c == 0, clamp_below, 0.0)
        hhi = hmax[k1c + 1, c]
        self.hlo = np.where(none, np.inf, hlo)
        self.hhi = np.where(none, -np.inf, hhi)
        self.k0, self.k1 = k0c, k1c
        self.clamp_below = float(clamp_below)
        # Bin edges per column over [ground min, top max]; levels stacked
        # per column with an offset so one searchsorted serves all columns.
        self.bins = int(bins)
        self.base = hmin[0]
        top = hmax[-1]
        self.inv = self.bins / np.maximum(top - self.base, 1e-9)
        edges = self.base[:, None] + np.arange(self.bins + 1)[None, :] / self.inv[:, None]
        tol = 1e-6  # metres: bins rounded at their edges stay bracketed
        # g: last level whose highest corner is <= the bin's lower edge (its
        # mixed height is then <= any height in the bin); u: first level whose
        # lowest corner is above the bin's upper edge.
        # Only columns with candidate cells need a table (others are rejected first).
        use = np.flatnonzero(~none)
        g = np.zeros((ncol, self.bins), np.intp)
        u = np.ones((ncol, self.bins), np.intp)
        if use.size:
            off = (np.arange(use.size) * (hmax.max() - hmin.min() + 1.0))[:, None]
            g[use] = np.searchsorted((hmax.T[use] + off).ravel(), (edges[use, :-1] - tol + off).ravel(),
                                     side="right").reshape(use.size, -1) - (np.arange(use.size) * nk)[:, None] - 1
            u[use] = np.searchsorted((hmin.T[use] + off).ravel(), (edges[use, 1:] + tol + off).ravel(),
                                     side="right").reshape(use.size, -1) - (np.arange(use.size) * nk)[:, None]
        self.g = np.clip(g, 0, nk - 2).astype(np.int8 if nk < 128 else np.int32)
        self.u = np.clip(u, 1, nk - 1).astype(self.g.dtype)

    def bracket(self, cell, h):
        """``(lo, hi)``: the level of heights ``h`` in columns ``cell`` lies in ``[lo, hi)``,
        narrowed to the column's candidate levels."""
        b = np.clip((h - self.base[cell]) * self.inv[cell], 0, self.bins - 1).astype(np.intp)
        t = cell * self.bins + b
        lo = np.maximum(self.g.reshape(-1)[t], self.k0[cell])
        hi = np.minimum(self.u.reshape(-1)[t], self.k1[cell] + 1)
        return lo.astype(np.intp), np.maximum(hi, lo + 1).astype(np.intp)


__all__ = ["CurvilinearField", "LevelTable"]
