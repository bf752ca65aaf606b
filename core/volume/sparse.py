"""Curvilinear globe fields resampled into sparse Cartesian block volumes (VDB-style).

Blender renders volumes on regular grids; climate fields live on a
longitude × latitude × terrain-following-level grid.  :func:`resample`
bridges the two:

* the field is defined everywhere by trilinear interpolation in the
  curvilinear cell (:class:`CurvilinearField`): a Cartesian point is mapped
  back analytically to longitude, latitude and height, the longitude and
  latitude give the fractional column index (periodic longitude, the poles
  closed by a ring of the last row's mean), and the level is found by
  searching the column's bilinearly interpolated terrain-following heights;
* only blocks of ``block``³ voxels (8³, OpenVDB's leaf nodes) that may have a
  non-zero opacity are ever evaluated: grid cells whose value range meets the
  transfer function's non-zero range give Cartesian bounding boxes, and those
  give the block set — transparent space costs nothing, memory follows the
  cloudy volume;
* a voxel's density is the transfer function's opacity of the interpolated
  value (NaN, outside the grid and below the terrain are empty); a second
  grid carries a colour variable (or the altitude) for the colour map.

Voxel index ``(a, b, c)`` sits at world position ``voxel_size * (a, b, c)``
(OpenVDB's linear transform), block ``(A, B, C)`` holds indices
``block*A .. block*A+block-1`` along each axis, arrays ordered ``[x, y, z]``.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
.. [2] K. Museth, "VDB: High-resolution sparse volumes with dynamic
   topology", ACM Trans. Graph. 32(3), 2013 (8³ leaf nodes).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..memory import check_memory
from ..climate.columns import ColumnLocator
from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, globe_radius, height_from_radius, xyz_to_lonlat
from ..threads import default_threads
from .transfer import TransferFunction

DEFAULT_VOXEL_SIZE = 0.0027
"""Scene units (the sea-level globe has radius 1): ~570 m of height at the
default exaggeration, 17 km across.  On the demo climate, rays of the Fig. 2
view have an opacity error of 1.5 % of full scale at the 99th percentile
(0.6 % rms); rays grazing the cloud layers (the limb) do much worse, up to
~60 % for a ray running along a layer at the threshold; one step resamples
in ~1.5 s on two threads (``benchmarks/bench_volume.py``)."""

DEFAULT_EXTINCTION = 300.0
"""Extinction per scene unit at opacity 1: a full cloud 0.0033 units thick
(~700 m at exaggeration 30) has optical depth 1."""

ALTITUDE = "altitude"
"""Colour-variable name meaning "the height above sea level in metres"."""

EXACT = "exact"
"""Volume mode: the renderer shades the curvilinear field itself
(:mod:`nephele.core.volume.volume_atlas`); opacity exact along every ray."""

VOXELS = "voxels"
"""Volume mode: opacity resampled into cubic voxels (:func:`resample`)."""


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
            return cls(0.0, np.arange(ni, dtype=np.float64), np.arange(nj, dtype=np.float64), height, vals, float(radius),
                       float(exaggeration), None, ColumnLocator(grid.lon2d, grid.lat2d))
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
            return w[0] * hf[base + corners[0]] + w[1] * hf[base + corners[1]] + w[2] * hf[base + corners[2]] + w[3] * hf[base + corners[3]]

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
            hm = ww[0] * hf[base + cc[0]] + ww[1] * hf[base + cc[1]] + ww[2] * hf[base + cc[2]] + ww[3] * hf[base + cc[3]]
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
        ground = ((1 - fj) * ((1 - fi) * hf[col] + fi * hf[col + 1]) + fj * ((1 - fi) * hf[col + ni] + fi * hf[col + ni + 1]))
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
        hmin = np.minimum(np.minimum(H[:, :-1, :-1], H[:, :-1, 1:]), np.minimum(H[:, 1:, :-1], H[:, 1:, 1:])).reshape(nk, -1)
        hmax = np.maximum(np.maximum(H[:, :-1, :-1], H[:, :-1, 1:]), np.maximum(H[:, 1:, :-1], H[:, 1:, 1:])).reshape(nk, -1)
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


@dataclass(eq=False)
class SparseVolume:
    """Blocks of voxels: the output of :func:`resample`.

    Attributes
    ----------
    voxel_size : float
        Scene units between voxel centres.
    block : int
        Voxels per block edge (8).
    blocks : (n, 3) int32
        Block coordinates; voxel index = ``block * blocks[b] + local``.
    density : (n, block, block, block) float32
        Opacity from the transfer function, axes ``[x, y, z]``.
    color : (n, block, block, block) float32 or None
        The colour variable, NaN replaced by 0.
    color_name : str or None
    stats : dict
        ``candidate_cells``, ``boxed_blocks`` (sub-blocks meeting the
        candidate cells' boxes), ``candidate_blocks`` (those evaluated),
        ``blocks``, ``active_voxels``,
        ``bytes`` of the kept arrays.
    """

    voxel_size: float
    block: int
    blocks: np.ndarray
    density: np.ndarray
    color: np.ndarray = None
    color_name: str = None
    stats: dict = None

    @property
    def empty(self):
        return self.blocks.shape[0] == 0

    def arrays(self):
        """Plain arrays for ``np.savez`` / the cache (no pickle)."""
        out = {
            "voxel_size": np.float64(self.voxel_size),
            "block": np.int64(self.block),
            "blocks": self.blocks,
            "density": self.density,
        }
        if self.color is not None:
            out["color"] = self.color
        return out

    @classmethod
    def from_arrays(cls, d, color_name=None):
        return cls(
            float(d["voxel_size"]), int(d["block"]), np.asarray(d["blocks"]), np.asarray(d["density"]),
            np.asarray(d["color"]) if "color" in d else None, color_name, {},
        )

    def bounds(self):
        """World-space ``(min, max)`` corners of the voxel centres, or None if empty."""
        if self.empty:
            return None
        lo = self.blocks.min(axis=0) * self.block
        hi = (self.blocks.max(axis=0) + 1) * self.block - 1
        return lo * self.voxel_size, hi * self.voxel_size

    def sample(self, xyz, grid="density"):
        """Trilinear interpolation between voxel centres (zero outside blocks)."""
        data = self.density if grid == "density" else self.color
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(xyz.shape[0])
        if self.empty:
            return out
        B = self.block
        u = xyz / self.voxel_size
        base = np.floor(u).astype(np.int64)
        f = u - base
        keys = _block_keys(self.blocks)
        order = np.argsort(keys)
        skeys = keys[order]
        flat = data.reshape(data.shape[0], -1)
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    idx = base + (dx, dy, dz)
                    blk = np.floor_divide(idx, B)
                    loc = idx - blk * B
                    k = _block_keys(blk)
                    pos = np.clip(np.searchsorted(skeys, k), 0, skeys.size - 1)
                    hit = skeys[pos] == k
                    v = np.where(hit, flat[order[pos], (loc[:, 0] * B + loc[:, 1]) * B + loc[:, 2]], 0.0)
                    w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                    out += w * v
        return out


_KEY_OFFSET = 1 << 20


def _block_keys(b):
    """One int64 per block coordinate triple (|coordinate| < 2**20)."""
    b = np.asarray(b, dtype=np.int64) + _KEY_OFFSET
    return (b[..., 0] << 42) | (b[..., 1] << 21) | b[..., 2]


def _keys_to_blocks(k):
    m = (1 << 21) - 1
    return (np.stack([(k >> 42) & m, (k >> 21) & m, k & m], axis=-1) - _KEY_OFFSET).astype(np.int32)


def candidate_blocks(field, name, tf, voxel_size, block=8, *, pad=0.0, below=None):
    """Blocks that may hold a non-zero opacity, and the candidate cells.

    Returns ``(blocks (n, 3) int32, cells (nk-1, nj-1, ni-1) bool)``.

    A cell can be non-zero only when its corner values' range meets the
    transfer function's open non-zero range (trilinear values stay within the
    corners' range); its Cartesian bounding box, padded by how far the
    curved faces bulge past the corners, bounds its voxels.  ``pad`` (scene
    units) widens every box; ``below`` (scene units, default 1.75 voxels)
    how far boxes of the lowest cells reach into the ground.
    """
    support = tf.support()
    v = field.values[name]
    if support is None:
        return np.zeros((0, 3), np.int32), np.zeros(tuple(n - 1 for n in v.shape), bool)
    lo, hi = support
    cmax = v[:-1, :-1, :-1]
    cmin = cmax
    for dk in (0, 1):
        for dj in (0, 1):
            for di in (0, 1):
                if dk or dj or di:
                    s = v[dk : v.shape[0] - 1 + dk, dj : v.shape[1] - 1 + dj, di : v.shape[2] - 1 + di]
                    cmax = np.maximum(cmax, s)  # NaN propagates: cells touching NaN drop out
                    cmin = np.minimum(cmin, s)
    with np.errstate(invalid="ignore"):
        cand = (cmax > lo) & (cmin < hi)
    kk, jj, ii = np.nonzero(cand)
    if kk.size == 0:
        return np.zeros((0, 3), np.int32), cand
    pts = field.cell_corner_points()
    bmin = np.full((kk.size, 3), np.inf)
    bmax = np.full((kk.size, 3), -np.inf)
    for dk in (0, 1):
        for dj in (0, 1):
            for di in (0, 1):
                p = pts[kk + dk, jj + dj, ii + di]
                np.minimum(bmin, p, out=bmin)
                np.maximum(bmax, p, out=bmax)
    # Faces between corners are arcs: pad by the sagitta of the widest arc.
    widest = field.columns.cell_degrees() if field.columns is not None else max(np.diff(field.lon).max(), np.diff(field.lat).max())
    dang = np.deg2rad(widest)
    rmax = field.radius_range()[1]
    pad = rmax * (1 - np.cos(dang / 2)) + 1e-9 + pad
    # Cells on the lowest level also reach one voxel diagonal into the ground
    # (the resampler extends the field there, see CurvilinearField.locate).
    below = 1.75 * voxel_size if below is None else below
    pad = pad + np.where(kk == 0, below, 0.0)[:, None]
    first = np.ceil((bmin - pad) / voxel_size).astype(np.int64)
    last = np.floor((bmax + pad) / voxel_size).astype(np.int64)
    b0 = np.floor_divide(first, block)
    b1 = np.floor_divide(last, block)
    span = b1 - b0
    lo = b0.min(axis=0)
    shape = tuple(int(n) for n in b1.max(axis=0) - lo + 1)
    # Mark blocks in a dense boolean grid of blocks when it is small (sorted
    # and duplicate-free for free), else collect keys and sort them.
    mark = np.zeros(shape, bool) if np.prod(shape, dtype=np.float64) <= 64e6 else None
    keys = []
    # Offsets nested axis by axis, each level keeping only the cells that
    # reach that far (most boxes span one or two blocks).
    for ox in range(int(span[:, 0].max()) + 1):
        sx = np.flatnonzero(span[:, 0] >= ox)
        for oy in range(int(span[sx, 1].max()) + 1):
            sy = sx[span[sx, 1] >= oy]
            if not sy.size:
                continue
            for oz in range(int(span[sy, 2].max()) + 1):
                sel = sy[span[sy, 2] >= oz]
                if not sel.size:
                    continue
                off = np.array([ox, oy, oz])
                if mark is not None:
                    b = b0[sel] + (off - lo)
                    mark[b[:, 0], b[:, 1], b[:, 2]] = True
                else:
                    keys.append(_block_keys(b0[sel] + off))
    if mark is not None:
        return (np.argwhere(mark) + lo).astype(np.int32), cand
    return _keys_to_blocks(np.unique(np.concatenate(keys))), cand


def _near_candidates(field, table, blocks, sub, voxel_size):
    """Which blocks of ``sub``³ voxels can hold a located point: their
    bounding ball, seen from the globe's centre, is tested against the
    candidate height range of every grid column it may overlap (blocks near
    a pole or with a wide window are kept)."""
    n = blocks.shape[0]
    keep = np.ones(n, bool)
    if n == 0 or field.columns is not None:  # a curvilinear grid: no lon/lat axes to test against
        return keep
    c = (blocks.astype(np.float64) * sub + 0.5 * (sub - 1)) * voxel_size
    R = 0.5 * (sub - 1) * np.sqrt(3.0) * voxel_size * 1.001 + 1e-12
    lon, lat, r = xyz_to_lonlat(c if field.rotation is None else c @ field.rotation)
    h = height_from_radius(r, field.radius, field.exaggeration)
    dh = R / height_scale(field.exaggeration, field.radius)
    theta = np.rad2deg(np.arcsin(np.minimum(R / np.maximum(r, R), 1.0)))
    a = np.deg2rad(np.minimum(np.abs(lat) + theta, 90.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        tl = np.rad2deg(np.arcsin(np.minimum(np.sin(np.deg2rad(theta)) / np.cos(a), 1.0)))
    testable = (np.abs(lat) + theta < 90.0) & (tl < 45.0) & (r > R)
    ti, tj = field._index_tables
    nci = field.lon.size - 1
    periodic = field.lon[-1] == 360.0
    x = np.mod(lon - field.lon0, 360.0)
    x0, x1 = x - tl, x + tl
    if periodic:
        x0, x1 = np.mod(x0, 360.0), np.mod(x1, 360.0)
    i0, i1 = ti(x0), ti(x1)
    j0, j1 = tj(lat - theta), tj(lat + theta)
    wi = np.mod(i1 - i0, nci) if periodic else i1 - i0
    wj = j1 - j0
    widest = 2
    testable &= (wi <= widest) & (wj <= widest)
    hit = np.zeros(n, bool)
    for dj in range(widest + 1):
        for di in range(widest + 1):
            m = testable & (dj <= wj) & (di <= wi)
            cell = np.minimum(j0 + dj, field.lat.size - 2) * nci + (np.mod(i0 + di, nci) if periodic else np.minimum(i0 + di, nci - 1))
            hit |= m & (table.hlo[cell] <= h + dh) & (table.hhi[cell] >= h - dh)
    keep[testable] = hit[testable]
    return keep


def scalar_field(grid, values, color_values=None, color_name=None, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
    """The :class:`CurvilinearField` of ``values`` (as ``"value"``) and, for a
    colour variable other than :data:`ALTITUDE`, ``color_values`` (as ``"color"``)."""
    arrays = {"value": values}
    if color_name is not None and color_name != ALTITUDE:
        if color_values is None:
            raise DataError("color_values are needed for a colour variable other than altitude", field=color_name)
        arrays["color"] = color_values
    return CurvilinearField.from_grid(grid, arrays, radius, exaggeration)


def resample(
    grid,
    values,
    tf,
    *,
    voxel_size=DEFAULT_VOXEL_SIZE,
    color_values=None,
    color_name=None,
    radius=1.0,
    exaggeration=DEFAULT_EXAGGERATION,
    block=8,
    chunk_blocks=1024,
    workers=None,
):
    """Resample one time step into a sparse block volume of opacity (and colour).

    Parameters
    ----------
    grid : GlobeGrid
    values : (nk, nj, ni) array
        The scalar behind the opacity (cloudiness); NaN = missing.
    tf : TransferFunction
        Opacity of the scalar; zero below its threshold.
    voxel_size : float
        Scene units between voxel centres.
    color_values : (nk, nj, ni) array, optional
        Second variable carried in the ``color`` grid.
    color_name : str, optional
        Its name; :data:`ALTITUDE` (``"altitude"``) stores each voxel's
        height in metres instead (``color_values`` then unused).
    radius, exaggeration : float
        The globe mapping, as in :meth:`GlobeGrid.points`.
    block : int
        Voxels per block edge.
    chunk_blocks : int
        Blocks evaluated per batch (bounds the temporary memory).
    workers : int, optional
        Threads evaluating batches (numpy releases the GIL in most of it);
        default :func:`nephele.core.threads.default_threads`.

    Returns
    -------
    SparseVolume
        Only blocks with some non-zero opacity.

    References
    ----------
    .. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
    """
    if not isinstance(tf, TransferFunction):
        raise DataError(f"needs a TransferFunction, got {type(tf).__name__}", field="transfer function")
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise DataError(f"must be a positive number of scene units, got {voxel_size}", field="voxel_size")
    if int(block) < 1:
        raise DataError(f"must be >= 1, got {block}", field="block")
    block = int(block)
    field = scalar_field(grid, values, color_values, color_name, radius, exaggeration)
    # Blocks further out than the whole globe would overflow the block keys.
    if field.radius_range()[1] / (voxel_size * block) > (_KEY_OFFSET - 2):
        raise DataError(f"voxel size {voxel_size} is too small for a globe of radius {radius}", field="voxel_size")
    # Evaluate in sub-blocks half a block wide (a thin cloud layer fills few
    # of them), then gather the non-empty ones into whole blocks.
    sub = block // 2 if block % 2 == 0 and block >= 4 else block
    blocks, cells = candidate_blocks(field, "value", tf, voxel_size, sub)
    ncells = int(np.count_nonzero(cells))
    # Per column, the range of candidate levels: points elsewhere are transparent.
    nkc = cells.shape[0]
    has = cells.any(axis=0)
    levels = (
        np.where(has, np.argmax(cells, axis=0), 1),
        np.where(has, nkc - 1 - np.argmax(cells[::-1], axis=0), 0),
    )
    depth = 1.75 * voxel_size / height_scale(exaggeration, radius)
    table = field.level_table(levels, depth)
    boxed = blocks.shape[0]
    blocks = blocks[_near_candidates(field, table, blocks, sub, voxel_size)]
    n = blocks.shape[0]
    # ~20 bytes per voxel of the candidate blocks at the peak (tracemalloc on demo:small, voxel 0.0027:
    # 14.4 M block voxels, 284 MB; the add-on's BYTES_PER_VOXEL).
    check_memory(20.0 * n * sub**3, f"resampling {n:,} blocks of {sub}^3 voxels (voxel size {voxel_size:g})",
                 hint="raise the voxel size or lower the exaggeration", field="voxel_size")
    with_color = color_name is not None

    def run(start):
        b = blocks[start : start + chunk_blocks].astype(np.int64)
        # Voxel centres per axis, broadcast to (block, x, y, z): longitude and
        # its cell depend on x and y only, so they are found once per column.
        X, Y, Z = ((b[:, a, None] * sub + np.arange(sub)) * voxel_size for a in range(3))
        X, Y, Z = X[:, :, None, None], Y[:, None, :, None], Z[:, None, None, :]
        full = (b.shape[0], sub, sub, sub)
        if field.columns is not None:  # a curvilinear grid: fractional column indices per voxel
            lon, i, fi, lat, h = field._column_coords(np.stack(np.broadcast_arrays(X, Y, Z), axis=-1).reshape(-1, 3))
        elif field.rotation is None:
            lon, i, fi = (np.broadcast_to(a, full).reshape(-1) for a in field._lon_index(X, Y))
            lat, h = (np.broadcast_to(a, full).reshape(-1) for a in field._lat_height(X * X + Y * Y, Z))
        else:  # a rotated-pole grid: locate in its own frame, where lon/lat no longer split by axis
            P = np.stack(np.broadcast_arrays(X, Y, Z), axis=-1).reshape(-1, 3) @ field.rotation
            lon, i, fi = field._lon_index(P[:, 0], P[:, 1])
            lat, h = field._lat_height(P[:, 0] ** 2 + P[:, 1] ** 2, P[:, 2])
        sel, flat, fk, fj, fi, h = field._locate_columns(lon, i, fi, lat, h, table)
        nvox = lat.size
        dens = np.zeros(nvox, dtype=np.float32)
        col = np.zeros(nvox, dtype=np.float32) if with_color else None
        if sel.size:
            dens[sel] = np.nan_to_num(tf(field._trilinear("value", flat, fk, fj, fi)), nan=0.0)
            if color_name == ALTITUDE:
                col[sel] = h[sel]
            elif with_color:
                col[sel] = np.nan_to_num(field._trilinear("color", flat, fk, fj, fi), nan=0.0)
        dens = dens.reshape(-1, sub, sub, sub)
        keep = dens.reshape(dens.shape[0], -1).max(axis=1) > 0
        return b[keep], dens[keep], None if col is None else col.reshape(-1, sub, sub, sub)[keep]

    starts = list(range(0, n, chunk_blocks))
    if workers is None:
        workers = default_threads()
    if workers > 1 and len(starts) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=int(workers)) as ex:
            parts = list(ex.map(run, starts))
    else:
        parts = [run(s) for s in starts]
    sb = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3), np.int64)
    keys, inverse = np.unique(_block_keys(np.floor_divide(sb, block // sub)), return_inverse=True)
    kb = _keys_to_blocks(keys)
    kd = np.zeros((keys.size, block, block, block), np.float32)
    kc = np.zeros_like(kd) if with_color else None
    if sb.shape[0]:
        inverse = inverse.reshape(-1)
        ratio = block // sub
        off = sb - np.floor_divide(sb, ratio) * ratio
        sd = np.concatenate([p[1] for p in parts])
        # Scatter every sub-block into its block: axes (block, ox, x, oy, y, oz, z),
        # contiguous runs of ``sub`` voxels per copy.
        view = (keys.size, ratio, sub, ratio, sub, ratio, sub)
        kd.reshape(view)[inverse, off[:, 0], :, off[:, 1], :, off[:, 2], :] = sd
        if with_color:
            kc.reshape(view)[inverse, off[:, 0], :, off[:, 1], :, off[:, 2], :] = np.concatenate([p[2] for p in parts])
    stats = {
        "candidate_cells": ncells,
        "boxed_blocks": int(boxed),
        "candidate_blocks": int(n),
        "blocks": int(kb.shape[0]),
        "active_voxels": int(np.count_nonzero(kd)),
        "voxels": int(kb.shape[0]) * block**3,
        "bytes": int(kd.nbytes + (kc.nbytes if kc is not None else 0) + kb.nbytes),
    }
    return SparseVolume(float(voxel_size), block, kb, kd, kc, color_name, stats)


def height_scale(exaggeration=DEFAULT_EXAGGERATION, radius=1.0):
    """Scene units per metre of height."""
    return radius * exaggeration / EARTH_RADIUS


__all__ = [
    "ALTITUDE",
    "DEFAULT_EXTINCTION",
    "DEFAULT_VOXEL_SIZE",
    "EXACT",
    "VOXELS",
    "CurvilinearField",
    "SparseVolume",
    "candidate_blocks",
    "height_scale",
    "resample",
]
