"""Backward trajectories through time-varying winds, for textures that move with the wind.

The texture of a frame at time ``t`` is evaluated not at the rendered point A
but at the point B that, starting at time 0, reaches A at ``t`` [1]_.  Every
grid vertex the scene needs is traced backwards through the hourly winds.

Positions are unit vectors on the sphere plus a fractional level index ``s``
(0 = lowest level).  The parts: grid indices and their gathers
(:mod:`._grid_index`: rows mirrored across each pole and periodic longitudes
let points cross both), the winds (:mod:`.winds`), the integrators
(:mod:`.integrators`, :func:`trace`) and, here, the strategies.

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

from dataclasses import dataclass

import numpy as np

from ..climate.grid import EARTH_RADIUS, lonlat_to_xyz, xyz_to_lonlat
from ._grid_index import _normalise, grid_index
from .integrators import METHODS, trace
from .winds import HOUR, AnalyticWind, WindField, steps_to_keep


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
        self.left = (
            self.index.padded(np.zeros(strategy.grid.shape + (copies,), dtype=np.float32))
            if self.index.bounded
            else None
        )
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
                sx[redo], sz[redo] = trace(
                    st.wind,
                    xyz[redo],
                    s[redo],
                    st.frame_hours[n],
                    st.frame_hours[self.starts[c]],
                    vertices=need[redo],
                    **st.opts,
                )
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
        return [
            (_normalise(xyz + d[:, 4 * c : 4 * c + 3]), np.clip(s + d[:, 4 * c + 3], 0.0, top))
            for c in range(len(self.frames))
        ]

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
    from scipy import ndimage  # (here: importing it takes 1.8 s, and the add-on and every farm worker load this module)

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
    "HOUR",
    "METHODS",
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
