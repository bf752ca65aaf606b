"""Exact volume shading: the curvilinear field handed to the renderer as texture atlases.

:func:`~nephele.core.volume.sparse.resample` bakes opacity into cubic voxels.  With
the 30× vertical exaggeration a voxel is far taller, in metres, than the
levels near the ground are apart, and rays grazing a layer whose cloudiness
hovers at the transfer function's threshold come out tens of percent wrong
(``docs/benchmarks.md``).  Here the renderer evaluates the curvilinear field
itself at every volume sample, exactly as
:class:`~nephele.core.volume.curvilinear.CurvilinearField` defines it:

1. longitude, latitude and height from the sample's position (``atan2``);
2. the fractional column index from piecewise-linear maps of the closed
   longitude and latitude axes (one clamped linear ramp per run of equal
   spacing, so a regular grid with pole rows takes three, a Gaussian grid
   one per row — exact either way);
3. the fractional level: the column's level heights are bilinear lookups in
   a *heights atlas* (four levels per RGBA texel), and the index is
   ``Σₖ clamp((h − zₖ) / (zₖ₊₁ − zₖ), 0, 1)`` — what the reference finds by
   binary search;
4. value and colour variable: bilinear lookups in the two level tiles of the
   *values atlas* around that index, mixed linearly (trilinear in the cell);
5. opacity: the transfer function as a sum of clamped ramps (exact), zero
   where a corner is missing, outside the grid, or outside a sparse *support*
   volume (a VDB of the blocks that may hold cloud) that keeps the renderer
   out of empty space.

A rotated-pole grid is shaded in its own frame: the atlas, the support and
:meth:`ExactVolume.shade` work in grid coordinates, and the renderer's
object carries the grid's rotation (:attr:`ExactVolume.rotation`) to put the
field at its true place.

A curvilinear grid (2-D longitude/latitude) replaces steps 1–2 by an *index
map* (:class:`IndexMap`): the sample's gnomonic chart coordinates about the
grid's centre (three dot products and two divisions) look up the fractional
column indices in a texture of :data:`INDEX_TEXELS` texels per cell, filled by
:class:`~nephele.core.climate.columns.ColumnLocator` (continued past the edge
by the edge cells' own bilinear maps, so the edge is where the interpolated
index crosses it).  The map is bilinear in each cell of the texture, so it
carries a small error of its own (``docs/benchmarks.md``).

Atlas layout: a tile per level (values) or per four levels (heights),
stacked along the image's rows; a tile's rows are the closed latitude axis
(pole rows included, see :class:`~nephele.core.volume.curvilinear.CurvilinearField`)
with one padding row above and below copying the edge rows, so bilinear
lookups never bleed into the next tile; its columns are the longitudes, the
seam closed by the texture's periodic (REPEAT) extension.  Values channels:
R the value (0 where missing), G the colour variable (0 where missing), B 1
where the value is present, else 0.

:meth:`AtlasLayout.shade` evaluates the same program in float32 on NumPy,
texel for texel as Cycles' linear image interpolation does; the benchmark
measures its error against the float64 reference, and a Cycles render test
checks the node graph against it.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
.. [2] P. Williams and N. Max, "A Volume Density Optical Model", 1992.
"""

from dataclasses import dataclass, replace

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS
from ..errors import DataError
from .curvilinear import CurvilinearField
from .sparse import ALTITUDE, SparseVolume, candidate_blocks, height_scale, scalar_field
from .transfer import TransferFunction

PAD = 1
"""Padding rows above and below each tile."""

MAX_RUNS = 512
"""Most ramps an axis map may take (a node each in the shader)."""

VALID = 1.0 - 1e-6
"""A bilinear validity above this means all four texels hold a value (float32
rounding of a mix of ones stays within a few 1e-8).  A missing corner whose
weight is under 1e-6 escapes: a sliver a millionth of a cell wide."""


def axis_runs(knots):
    """Piecewise-linear map from coordinate to fractional index as runs of equal spacing.

    Returns a list of ``(x0, x1, i0, i1)``: between ``x0`` and ``x1`` the
    index goes linearly from ``i0`` to ``i1``.  The map is
    ``Σ clamp((x − x0) / (x1 − x0), 0, 1) · (i1 − i0)``, exact for every knot
    spacing.
    """
    x = np.asarray(knots, dtype=np.float64)
    d = np.diff(x)
    if x.ndim != 1 or d.size < 1 or not np.all(d > 0):
        raise DataError("needs strictly ascending coordinates", field="axis")
    runs = []
    start = 0
    for i in range(1, d.size + 1):
        if i == d.size or abs(d[i] - d[start]) > 1e-9 * abs(d).max():
            runs.append((float(x[start]), float(x[i]), float(start), float(i)))
            start = i
    if len(runs) > MAX_RUNS:
        raise DataError(f"has {len(runs)} runs of distinct spacing, more than {MAX_RUNS} shader ramps",
                        field="axis")
    return runs


def map_runs(x, runs):
    """:func:`axis_runs`' map in float32, as the shader's Map Range nodes compute it."""
    x = np.asarray(x, dtype=np.float32)
    out = np.zeros(x.shape, np.float32)
    for x0, x1, i0, i1 in runs:
        out += map_range(x, x0, x1, 0.0, i1 - i0)
    return out


def map_range(x, a, b, c, d):
    """Cycles' clamped linear Map Range in float32."""
    a, b, c, d = (np.float32(v) for v in (a, b, c, d))
    f = (np.asarray(x, np.float32) - a) / (b - a)
    r = c + f * (d - c)
    return np.clip(r, min(c, d), max(c, d)).astype(np.float32)


def tf_ramps(tf):
    """The transfer function as ``(offset, [(kind, a, b, rise), ...])``: opacity =
    offset + Σ rise · ramp, ``ramp`` a clamped linear ramp from ``a`` to ``b``
    (``kind`` "ramp") or a step at ``a`` (``kind`` "step", for two points at one value)."""
    v, o = tf.values, tf.opacities
    parts = []
    for i in range(v.size - 1):
        rise = float(o[i + 1] - o[i])
        if rise == 0.0:
            continue
        parts.append(("step", float(v[i]), float(v[i]), rise) if v[i + 1] == v[i]
                     else ("ramp", float(v[i]), float(v[i + 1]), rise))
    return float(o[0]), parts


def tf_eval32(tf, s):
    """The shader's transfer function in float32 (NaN gives the opacity below the first point)."""
    s = np.nan_to_num(np.asarray(s, np.float32), nan=-np.inf)
    offset, parts = tf_ramps(tf)
    out = np.full(s.shape, offset, np.float32)
    for kind, a, b, rise in parts:
        if kind == "step":
            out += np.float32(rise) * (s >= np.float32(a))
        else:
            out += map_range(s, a, b, 0.0, rise)
    return out


INDEX_TEXELS = 4
"""Texels of a curvilinear grid's index map per grid cell along each axis."""

MAX_INDEX = 2048
"""Largest side of the index map (texels)."""

INDEX_EDGE = 1e-4
"""Index units past the grid's edge still inside (float32 rounding; the map's own error is larger)."""


@dataclass(eq=False)
class IndexMap:
    """A curvilinear grid's fractional column indices over its gnomonic chart (build with :func:`index_map`).

    Attributes
    ----------
    basis : (3, 3) array
        Rows: chart x, chart y and the chart's centre (:attr:`ColumnLocator.basis`).
    lo, hi : (2,) arrays
        Chart coordinates of the texture's outer edges.
    image : (my, mx, 4) float32
        R the column index ``i``, G the row index ``j`` at each texel centre.
    """

    basis: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    image: np.ndarray

    def to_dict(self):
        return {"basis": self.basis.tolist(), "lo": self.lo.tolist(), "hi": self.hi.tolist(),
                "size": [int(self.image.shape[1]), int(self.image.shape[0])]}

    def lookup(self, p):
        """The shader's ``(i, j, front)`` of float32 points ``p`` (n, 3): ``front`` False on the far side of
        the globe."""
        q = p @ self.basis.T.astype(np.float32)
        front = q[:, 2] > np.float32(0.0)
        z = np.where(front, q[:, 2], np.float32(1.0))
        lo, size = self.lo.astype(np.float32), (self.hi - self.lo).astype(np.float32)
        u = (q[:, 0] / z - lo[0]) / size[0]
        v = (q[:, 1] / z - lo[1]) / size[1]
        texel = bilinear(self.image, u, v, False)
        return texel[:, 0], texel[:, 1], front


def index_map(columns, texels=INDEX_TEXELS, most=MAX_INDEX):
    """The :class:`IndexMap` of a :class:`~nephele.core.climate.columns.ColumnLocator`.

    Texel centres inside the grid take the locator's indices; those outside
    take the bilinear map of the edge cell nearest them, extended, so that
    the shader's bilinear lookup stays accurate up to the edge and puts the
    edge where the interpolated index crosses it.
    """
    nj, ni = columns.shape
    xy = columns.xy.reshape(-1, 2)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    m = np.minimum(np.array([ni, nj]) * texels, most).astype(int)
    step = (hi - lo) / (m - 2)  # one texel of margin each side: the edge lies inside the texture
    lo, hi = lo - step, hi + step
    gx = lo[0] + (np.arange(m[0]) + 0.5) * step[0]
    gy = lo[1] + (np.arange(m[1]) + 0.5) * step[1]
    X, Y = (a.ravel() for a in np.meshgrid(gx, gy))
    fi, fj = columns.continued(np.stack([X, Y, np.ones_like(X)], axis=1) @ columns.basis)
    img = np.zeros((m[1], m[0], 4), np.float32)
    img[..., 0] = fi.reshape(m[1], m[0])
    img[..., 1] = fj.reshape(m[1], m[0])
    img[..., 3] = 1.0
    return IndexMap(columns.basis.copy(), lo, hi, img)


@dataclass(eq=False)
class AtlasLayout:
    """Time-independent half of the exact shading: axes, tiles and the heights atlas.

    Build with :func:`atlas_layout`.

    Attributes
    ----------
    lon0 : float
        Longitude (degrees) of the first column.
    periodic : bool
        Longitudes close the circle (texture extension REPEAT, else EXTEND).
    lon_runs, lat_runs : list
        :func:`axis_runs` of the closed longitude axis (relative to ``lon0``)
        and latitude axis.
    lon_range, lat_range : (float, float)
        Covered range (relative longitude, latitude); outside is empty.
    width, rows, nk : int
        Texels per row, rows per tile without padding, levels.
    heights : (ceil(nk/4) * (rows + 2), width, 4) float32
        The heights atlas, metres.
    radius, exaggeration : float
    index : IndexMap or None
        A curvilinear grid's column lookup (the axis runs and ranges are then unused).
    """

    lon0: float
    periodic: bool
    lon_runs: list
    lat_runs: list
    lon_range: tuple
    lat_range: tuple
    width: int
    rows: int
    nk: int
    heights: np.ndarray
    radius: float
    exaggeration: float
    index: IndexMap = None

    @property
    def tile(self):
        """Rows per tile, padding included."""
        return self.rows + 2 * PAD

    @property
    def closed_lat(self):
        """The latitudes reach both poles: no latitude is outside."""
        return self.lat_range[0] <= -90.0 and self.lat_range[1] >= 90.0

    @property
    def value_rows(self):
        """Rows of a values atlas."""
        return self.nk * self.tile

    def to_dict(self):
        """JSON-ready description (no images) for the material builder."""
        return {
            "lon0": self.lon0, "periodic": self.periodic, "lon_runs": self.lon_runs, "lat_runs": self.lat_runs,
            "lon_range": list(self.lon_range), "lat_range": list(self.lat_range), "width": self.width,
            "rows": self.rows, "nk": self.nk, "radius": self.radius, "exaggeration": self.exaggeration,
            "index": None if self.index is None else self.index.to_dict(),
        }

    def values_atlas(self, field):
        """The values atlas of a :class:`CurvilinearField` built by :func:`atlas_layout`'s
        recipe: ``(nk * tile, width, 4)`` float32 (see the module docstring)."""
        v = field.values["value"]
        c = field.values.get("color")
        if v.shape[0] != self.nk or v.shape[1] != self.rows:
            raise DataError(f"shape {v.shape} does not match the atlas ({self.nk} levels, {self.rows} rows)",
                            field="value")
        if self.periodic:
            v = v[:, :, :-1]
            c = None if c is None else c[:, :, :-1]
        img = np.zeros((self.nk, self.tile, self.width, 4), np.float32)
        inner = img[:, PAD : PAD + self.rows]
        ok = np.isfinite(v)
        inner[..., 0] = np.where(ok, v, 0.0)
        if c is not None:
            inner[..., 1] = np.nan_to_num(c, nan=0.0)
        inner[..., 2] = ok
        _pad_rows(img)
        return img.reshape(-1, self.width, 4)

    def shade(self, values, xyz, *, below=0.0, color_altitude=False):
        """The shader program in float32: ``(value, colour, ok)`` at points ``xyz``.

        ``value`` is the field (trilinear in the curvilinear cell), ``colour``
        the colour variable (or the height in metres with ``color_altitude``),
        ``ok`` False where the shader's density is zero whatever the transfer
        function: outside the grid (strictly inside its longitude and latitude
        range for a regional grid), a missing corner, above the top level or
        more than ``below`` metres under the lowest level (the lowest level's
        values are used in between, as :func:`~nephele.core.volume.sparse.resample`
        does; the ground hides them).
        """
        p = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        f32 = np.float32
        deg = f32(180.0 / np.pi)
        lon = np.arctan2(y, x) * deg - f32(self.lon0)
        rxy = np.sqrt(x * x + y * y)
        lat = np.arctan2(z, rxy) * deg
        r = np.sqrt(x * x + y * y + z * z)
        ok = np.ones(p.shape[0], bool)
        if self.index is not None:
            col, row, front = self.index.lookup(p)
            e = f32(INDEX_EDGE)
            ok &= front & (col > -e) & (col < f32(self.width - 1) + e) & (row > -e) & (row < f32(self.rows - 1) + e)
            # Outside, the clamp keeps the lookups below inside their own tiles.
            col, row = np.clip(col, f32(0.0), f32(self.width - 1)), np.clip(row, f32(0.0), f32(self.rows - 1))
        else:
            # Relative longitude in [0, 360) for every grid: a regional grid may straddle ±180°.
            lon = lon - f32(360.0) * np.floor(lon / f32(360.0))
            if not self.periodic:
                ok &= (lon > f32(self.lon_range[0])) & (lon < f32(self.lon_range[1]))
            if not self.closed_lat:
                ok &= (lat > f32(self.lat_range[0])) & (lat < f32(self.lat_range[1]))
            col = map_runs(lon, self.lon_runs)
            row = map_runs(lat, self.lat_runs)
        a, b = self.height_coefficients()
        h = r * f32(a) + f32(b)
        u = col * f32(1.0 / self.width) + f32(0.5 / self.width)
        hrows = self.heights.shape[0]
        z_levels = []
        for m in range((self.nk + 3) // 4):
            v = row * f32(1.0 / hrows) + f32((m * self.tile + PAD + 0.5) / hrows)
            texel = bilinear(self.heights, u, v, self.periodic)
            z_levels.extend(texel[:, c] for c in range(4))
        z_levels = z_levels[: self.nk]
        index = np.zeros(h.shape, np.float32)
        for k in range(self.nk - 1):
            index += map_range(h, z_levels[k], z_levels[k + 1], 0.0, 1.0)
        ok &= (h > z_levels[0] - f32(below)) & (h < z_levels[-1])
        k0 = np.minimum(np.floor(index), f32(self.nk - 2))
        f = index - k0
        vrows = self.value_rows
        t = row * f32(1.0 / vrows) + f32((PAD + 0.5) / vrows)
        va = k0 * f32(self.tile / vrows) + t
        vb = va + f32(self.tile / vrows)
        A = bilinear(values, u, va, self.periodic)
        B = bilinear(values, u, vb, self.periodic)
        value = A[:, 0] + f * (B[:, 0] - A[:, 0])
        color = h if color_altitude else A[:, 1] + f * (B[:, 1] - A[:, 1])
        ok &= np.minimum(A[:, 2], B[:, 2]) > f32(VALID)
        return value, color, ok

    def height_coefficients(self):
        """``(a, b)`` with height = ``a · r + b`` metres for a distance ``r`` from the centre."""
        return EARTH_RADIUS / (self.radius * self.exaggeration), -EARTH_RADIUS / self.exaggeration


def _pad_rows(img):
    """Copy each tile's edge rows into its padding rows (img: (tiles, tile, width, 4))."""
    for p in range(PAD):
        img[:, p] = img[:, PAD]
        img[:, -1 - p] = img[:, -1 - PAD]


def bilinear(img, u, v, periodic):
    """Cycles' linear image lookup (texel centres at (i + ½) / size) in float32:
    columns wrap when ``periodic`` (REPEAT) else clamp (EXTEND); rows clamp."""
    H, W = img.shape[:2]
    x = np.asarray(u, np.float32) * np.float32(W) - np.float32(0.5)
    y = np.asarray(v, np.float32) * np.float32(H) - np.float32(0.5)
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = (x - ix)[:, None], (y - iy)[:, None]
    ix, iy = ix.astype(np.int64), iy.astype(np.int64)
    if periodic:
        x0, x1 = np.mod(ix, W), np.mod(ix + 1, W)
    else:
        x0, x1 = np.clip(ix, 0, W - 1), np.clip(ix + 1, 0, W - 1)
    y0, y1 = np.clip(iy, 0, H - 1), np.clip(iy + 1, 0, H - 1)
    one = np.float32(1.0)
    return ((one - fy) * ((one - fx) * img[y0, x0] + fx * img[y0, x1])
            + fy * ((one - fx) * img[y1, x0] + fx * img[y1, x1])).astype(np.float32)


def atlas_layout(grid, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
    """The :class:`AtlasLayout` of a :class:`~nephele.core.climate.grid.GlobeGrid`."""
    field = CurvilinearField.from_grid(grid, {}, radius, exaggeration)
    return _layout(field)


def _layout(field):
    curvilinear = field.columns is not None
    periodic = bool(field.lon[-1] == 360.0) and not curvilinear
    nk, rows, ncols = field.shape
    width = ncols - 1 if periodic else ncols
    ntiles = (nk + 3) // 4
    hgt = np.zeros((ntiles * 4, rows, width), np.float32)
    hgt[:nk] = field.height[:, :, :width]
    # Levels past the top (4 per texel) repeat the top: never read.
    hgt[nk:] = field.height[-1, :, :width]
    img = np.zeros((ntiles, rows + 2 * PAD, width, 4), np.float32)
    img[:, PAD : PAD + rows] = hgt.reshape(ntiles, 4, rows, width).transpose(0, 2, 3, 1)
    _pad_rows(img)
    return AtlasLayout(
        lon0=float(field.lon0), periodic=periodic, lon_runs=[] if curvilinear else axis_runs(field.lon),
        lat_runs=[] if curvilinear else axis_runs(field.lat),
        lon_range=(float(field.lon[0]), float(field.lon[-1])), lat_range=(float(field.lat[0]), float(field.lat[-1])),
        width=int(width), rows=int(rows), nk=int(nk), heights=img.reshape(-1, width, 4),
        radius=float(field.radius), exaggeration=float(field.exaggeration),
        index=index_map(field.columns) if curvilinear else None,
    )


DEFAULT_SUPPORT_SIZE = 0.01
"""Scene units between the support grid's voxels (~64 km across, ~2 km of
height): it bounds where the renderer looks, not what it sees."""

DEFAULT_BELOW = 1000.0
"""Metres under the lowest level that still take its values: the ground hides
them, and a relief finer than the model's never shows a gap under the cloud."""


@dataclass(eq=False)
class ExactVolume:
    """One frame of exact shading: the values atlas and the support voxels.

    Attributes
    ----------
    layout : AtlasLayout
    values : (nk * tile, width, 4) float32
    support : (n, 3) int32
        Voxel indices (voxel at ``support_size * index``) of the support
        grid: the shader's density is zero wherever the trilinear mix of
        these voxels (1 each, 0 elsewhere) is zero.
    support_size : float
    below : float
        Metres under the lowest level that take its values.
    color_name : str or None
    rotation : (3, 3) array or None
        A rotated-pole grid's rotation (:attr:`GlobeGrid.rotation`): the
        atlas and the support are in grid coordinates, and the object that
        shows them takes this rotation (``world = rotation @ local``).
    """

    layout: AtlasLayout
    values: np.ndarray
    support: np.ndarray
    support_size: float
    below: float
    color_name: str = None
    rotation: np.ndarray = None

    @property
    def empty(self):
        return self.support.shape[0] == 0

    def local(self, xyz):
        """Scene points ``(n, 3)`` in the object's (the grid's) frame."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return xyz if self.rotation is None else xyz @ self.rotation

    def shade(self, xyz):
        """:meth:`AtlasLayout.shade` masked by the support at scene points: ``(value, colour, ok)``."""
        p = self.local(xyz)
        value, color, ok = self.layout.shade(self.values, p, below=self.below,
                                             color_altitude=self.color_name == ALTITUDE)
        return value, color, ok & self._in_support(p)

    def sample(self, xyz):
        """The value the shader sees (NaN where its density is forced to zero)."""
        value, _, ok = self.shade(xyz)
        return np.where(ok, value, np.nan)

    def in_support(self, xyz):
        """Scene points where the support grid's trilinear mix is positive (the shader's test)."""
        return self._in_support(self.local(xyz))

    def _in_support(self, p):
        n = self.support.shape[0]
        grid = SparseVolume(self.support_size, 1, self.support, np.ones((n, 1, 1, 1), np.float32))
        return grid.sample(p) > 0

    def arrays(self):
        """Plain arrays for ``np.savez`` / the cache (no pickle); the layout is rebuilt from the grid."""
        return {"values": self.values, "support": self.support, "support_size": np.float64(self.support_size),
                "below": np.float64(self.below)}


def support_voxels(field, tf, size, below=DEFAULT_BELOW):
    """Voxels of a grid of spacing ``size`` whose trilinear footprint covers every
    point that may have a non-zero opacity.

    Every candidate cell's box (:func:`~nephele.core.volume.sparse.candidate_blocks`,
    reaching ``below`` metres into the ground at the lowest level) widened by
    one voxel, so a voxel centre lies less than a voxel from each of its points.
    """
    hs = height_scale(field.exaggeration, field.radius)
    vox, _ = candidate_blocks(field, "value", tf, size, 1, pad=size, below=below * hs)
    return vox


def exact_volume(grid, values, tf, *, support_size=DEFAULT_SUPPORT_SIZE, color_values=None, color_name=None,
                 radius=1.0, exaggeration=DEFAULT_EXAGGERATION, below=DEFAULT_BELOW, layout=None):
    """One time step for exact shading: the values atlas and the support voxels.

    Parameters
    ----------
    grid, values, tf, color_values, color_name, radius, exaggeration
        As for :func:`~nephele.core.volume.sparse.resample`.
    support_size : float
        Scene units between support voxels.
    below : float
        Metres under the lowest level that take its values.
    layout : AtlasLayout, optional
        An :func:`atlas_layout` of the same grid, to reuse.

    Returns
    -------
    ExactVolume

    References
    ----------
    .. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
    """
    if not isinstance(tf, TransferFunction):
        raise DataError(f"needs a TransferFunction, got {type(tf).__name__}", field="transfer function")
    if not (np.isfinite(support_size) and support_size > 0):
        raise DataError(f"must be a positive number of scene units, got {support_size}", field="support_size")
    if not (np.isfinite(below) and below >= 0):
        raise DataError(f"must be >= 0 metres, got {below}", field="below")
    field = scalar_field(grid, values, color_values, color_name, radius, exaggeration)
    rotation = field.rotation
    if rotation is not None:  # shaded in the grid's frame; the object turns it into place
        field = replace(field, rotation=None)
    layout = layout or _layout(field)
    if (layout.nk, layout.rows) != field.shape[:2]:
        raise DataError("layout belongs to another grid", field="layout")
    support = support_voxels(field, tf, float(support_size), float(below))
    return ExactVolume(layout, layout.values_atlas(field), support, float(support_size), float(below), color_name,
                       rotation)


__all__ = [
    "DEFAULT_BELOW",
    "DEFAULT_SUPPORT_SIZE",
    "AtlasLayout",
    "ExactVolume",
    "INDEX_EDGE",
    "INDEX_TEXELS",
    "IndexMap",
    "atlas_layout",
    "axis_runs",
    "bilinear",
    "exact_volume",
    "index_map",
    "support_voxels",
    "tf_eval32",
    "tf_ramps",
]
