"""Splat layouts whose weights sum to one on a globe: shells, widened kernels, factors.

A per-sample ellipsoid (:mod:`.samples`) is the affine approximation of the
grid map at the sample, so the weights of a lattice sum to one only where the
map is close to affine over a kernel's reach (2.5 cells).  On the
terrain-following levels of climate grids it is not: over steep terrain the
level surfaces of neighbouring columns lie several level spacings apart, and
no choice of per-sample ellipsoids and weight factors fits there (the best
least-squares factors still leave 20–30 % on a Himalaya or Andes block of the
demo).  So, by choice, the splats sample the field on **shells**: levels at
fixed heights above sea level, the same in every column (by default the lowest
height each level reaches anywhere, i.e. the grid's own level heights over the
sea), the field interpolated linearly in height within each column (NaN below
the ground, where no splat is drawn).  Such a grid is invariant under
rotation about the axis, its spacings change smoothly, and two more steps make
the sum one within about 1e-3:

* **Widening.**  Where the spacing changes fast — the longitude spacing
  ``∝ cos(lat)`` near the poles, the level spacing of stretched levels — a
  kernel fitted to its own cell is too thin for points a few cells away whose
  cells are larger, and the sum ripples.  Each sample's longitude axis is
  widened by ``λ_lon = max cos(lat') / cos(lat)`` over the latitudes ``lat'``
  within the kernel's reach, and its level axis by ``λ_lev = max spacing'
  / spacing`` over the levels within reach (both at least 1; 1 away from the
  poles and on even levels).
* **Factors.**  Each sample's weight is multiplied by a factor ``c(k, j)``
  (one per shell and latitude row: the layout is the same in every column)
  solved by least squares so that the sum is one at the grid nodes, cell,
  face and edge centres and random points of every cell whose support is
  complete (3 cells from the top, bottom and poles), regularised towards
  ``1 / (λ_lon λ_lev)`` (the widened kernel's share).

On a **curvilinear** grid (2-D latitude/longitude: WRF, Lambert conformal,
polar stereographic) the shells sample each column the same way, and each
sample's kernel comes from its own cell Jacobian, but there is no symmetry
along the rows, so the two steps are taken per sample
(:func:`curvilinear_shells`):

* **Widening.**  Each horizontal axis by ``λ = max spacing' / spacing`` over
  the columns within ``⌈R⌉`` of the sample along both axes (about 1.003 on
  50 km Lambert conformal and polar stereographic grids, whose map scale
  changes slowly), the level axis as above.
* **Factors.**  One per sample (:func:`sample_factors`), least squares at the
  half-step lattice of the closed block of cells 3 from every edge, the top
  and the ground, and 2 random points per cell, regularised towards
  ``1 / (λ_i λ_j λ_lev)``.  Closing the block matters: with the lattice of
  cell-corner offsets only (as for rows), the samples next to the block's
  far faces were fitted on too few points and the sum there was 2e-3 off.
  Solved in tiles of 48 × 48 columns with 8 more around each (the tiles'
  seams leave the sum as it was); about 0.3 ms per sample on 2 busy cores
  and about 1 GB at the peak, one tile's system (80 × 60 columns, 16 shells:
  22 s), cached per grid, shells, stride, exaggeration and kernel — a
  stride divides the time by its cube.

The renderers draw exactly these weights: :func:`.samples.splat_samples`
puts the widened axes in :attr:`.Splats.axes` and folds the factor into
:attr:`.Splats.opacity`.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (splats normalised so the weights sum to nearly one).
.. [2] R. Crawfis and N. Max, "Texture Splats for 3D Scalar and Vector Field
   Visualization", IEEE Visualization '93.
"""

from functools import lru_cache

import numpy as np

from ..climate.grid import GlobeGrid
from ..errors import DataError
from .cells import cell_jacobians, principal_axes
from .kernel import SplatKernel

_FACES = np.array(
    [[0, 0, 0], [0.5, 0.5, 0.5], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.5], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]]
)
_RANDOM_PER_CELL = 8
_REGULARISE = 1e-3
_MARGIN = 3  # cells from the top, bottom and poles whose kernel support is incomplete
_RANDOM_PER_SAMPLE_CELL = 2  # per-sample factors: random points per cell besides the half-step lattice
_CHUNK = 50_000  # points per stencil_weights call in the per-sample solve
_CG_RTOL, _CG_ITERATIONS = 1e-6, 300
_TILE, _HALO = 48, 8  # per-sample factors: columns per tile side, and more around it


def shell_heights(grid):
    """Default shell heights: the lowest height each level of ``grid`` reaches (m), ascending."""
    if not isinstance(grid, GlobeGrid):
        raise DataError(f"needs a GlobeGrid, got {type(grid).__name__}", field="grid")
    return grid.height.reshape(grid.shape[0], -1).min(axis=1)


def check_shells(heights, path=None):
    """``heights`` as float64, checked: finite, strictly ascending, at least 2."""
    h = np.asarray(heights, dtype=np.float64).reshape(-1)
    if h.size < 2 or not np.all(np.isfinite(h)) or not np.all(np.diff(h) > 0):
        raise DataError(f"shell heights must be >= 2 finite, strictly ascending values, got {h.size}", path=path,
                        field="shells")
    return h


@lru_cache(maxsize=4)
def _column_weights(height_bytes, shape, shell_bytes):
    """Per shell and column: the level below (``lo``), the fraction to the one above, and
    whether the shell lies within the column (between its ground and its top)."""
    flat = np.frombuffer(height_bytes).reshape(shape[0], -1)
    shells = np.frombuffer(shell_bytes)
    below = np.sum(flat[None, :, :] <= shells[:, None, None], axis=1)
    lo = np.clip(below - 1, 0, shape[0] - 2)
    cols = np.arange(flat.shape[1])[None, :]
    h0, h1 = flat[lo, cols], flat[lo + 1, cols]
    frac = (shells[:, None] - h0) / (h1 - h0)
    inside = (shells[:, None] >= flat[0][None, :]) & (shells[:, None] <= flat[-1][None, :])
    return lo, frac, inside


class ShellSampler:
    """Linear interpolation in height, column by column, from a grid's levels onto shells.

    ``sampler(values)`` maps ``(nk, nj, ni)`` grid values to ``(n_shells, nj, ni)``
    (NaN where a shell lies below the ground or above the top of its column);
    ``sampler.at(values, sel)`` gives only the shell samples ``sel = (k, j, i)``.
    """

    def __init__(self, grid, heights):
        self.shape = (len(heights),) + grid.shape[1:]
        self._lo, self._frac, self._inside = _column_weights(
            np.ascontiguousarray(grid.height).tobytes(), grid.shape,
            np.ascontiguousarray(heights, dtype=np.float64).tobytes()
        )

    def at(self, values, sel):
        v = np.asarray(values, dtype=np.float64)
        flat = v.reshape(v.shape[0], -1)
        k = np.asarray(sel[0])
        col = np.ravel_multi_index((np.asarray(sel[1]), np.asarray(sel[2])), self.shape[1:])
        lo, f = self._lo[k, col], self._frac[k, col]
        out = (1.0 - f) * flat[lo, col] + f * flat[lo + 1, col]
        return np.where(self._inside[k, col], out, np.nan)

    def __call__(self, values):
        k, j, i = np.indices(self.shape).reshape(3, -1)
        return self.at(values, (k, j, i)).reshape(self.shape)


def _reach_max(values, radius):
    """For each index ``n``: the largest of ``values`` over indices within ``radius`` of ``n``
    (``values`` linearly interpolated at ``n ± radius``)."""
    n = values.size
    idx = np.arange(n, dtype=np.float64)
    out = np.empty(n)
    for m in range(n):
        lo, hi = max(m - radius, 0.0), min(m + radius, n - 1.0)
        inner = values[int(np.ceil(lo)) : int(np.floor(hi)) + 1]
        out[m] = max(np.interp([lo, hi], idx, values).max(), inner.max() if inner.size else -np.inf)
    return out


def _level_widening(heights, radius):
    spacing = np.gradient(np.asarray(heights, dtype=np.float64))
    return np.maximum(1.0, _reach_max(spacing, radius) / spacing)


def widening(lat, heights, radius):
    """``(λ_lon (nj,), λ_lev (nk,))``: how much each row's longitude axis and each shell's
    level axis are widened (see the module docstring); both at least 1."""
    coslat = np.cos(np.deg2rad(np.asarray(lat, dtype=np.float64)))
    lam_lon = np.maximum(1.0, _reach_max(coslat, radius) / np.maximum(coslat, 1e-12))
    return lam_lon, _level_widening(heights, radius)


def column_widening(jac, radius):
    """``(λ_i, λ_j)`` ``(nj, ni)`` each: how much the two horizontal axes of a curvilinear
    layout's samples are widened (module docstring); at least 1.  ``jac``: the layout's
    Jacobians ``(nk, nj, ni, 3, 3)`` (the lowest shell's spacing is used)."""
    from scipy import ndimage

    size = 2 * int(np.ceil(radius)) + 1
    out = []
    for axis in (0, 1):
        s = np.maximum(np.linalg.norm(jac[0, ..., axis], axis=-1), 1e-300)
        out.append(np.maximum(1.0, ndimage.maximum_filter(s, size=size, mode="nearest") / s))
    return tuple(out)


def widen(jac, lam_lon, lam_lev, lam_lat=1.0):
    """Jacobians ``(..., 3, 3)`` with the longitude (``i``) column scaled by ``lam_lon``, the
    latitude (``j``) column by ``lam_lat`` and the level column by ``lam_lev`` (arrays
    broadcasting against ``jac.shape[:-2]``)."""
    out = np.array(jac, dtype=np.float64, copy=True)
    for col, lam in ((0, lam_lon), (1, lam_lat), (2, lam_lev)):
        out[..., :, col] *= np.asarray(lam, dtype=np.float64)[..., None]
    return out


def cell_points(points, frac_index):
    """Scene points at fractional grid indices ``(k, j, i)`` ``(m, 3)``: trilinear in the
    cell's corners (longitude periodic)."""
    nk, nj, ni, _ = points.shape
    f = np.asarray(frac_index, dtype=np.float64)
    b = np.floor(f).astype(np.int64)
    b[:, 0] = np.clip(b[:, 0], 0, nk - 2)
    b[:, 1] = np.clip(b[:, 1], 0, nj - 2)
    fr = f - b
    x = np.zeros((len(f), 3))
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([fr[:, a] if c else 1.0 - fr[:, a] for a, c in enumerate(corner)], axis=0)
        x += w[:, None] * points[b[:, 0] + corner[0], b[:, 1] + corner[1], (b[:, 2] + corner[2]) % ni]
    return x, b


def _stretch(to_cell):
    """The most each sample's map stretches a length (its spectral norm), for :func:`stencil_weights`."""
    return np.linalg.norm(to_cell, ord=2, axis=(-2, -1))


def stencil_weights(points, to_cell, frac_index, kernel, reach, stretch=None):
    """Kernel weights of every grid sample near points at fractional indices.

    ``to_cell[k, j, i]`` maps a scene offset from sample ``(k, j, i)`` to its cell
    offset (``R M⁻¹`` of the splat's axes); ``reach = (rk, rj, ri)`` bounds the
    index distance from a point's cell to the samples whose kernels reach it.
    ``stretch``: :func:`_stretch` ``to_cell``, passed by callers that call again with
    the same maps (a singular value decomposition per sample: 0.2 s on the demo's slab).
    Returns ``(point, k, j, i, weight)`` arrays over the pairs with a positive
    weight (longitude periodic).
    """
    nk, nj, ni, _ = points.shape
    x, b = cell_points(points, frac_index)
    # Cull whole cells first: a point of a cell lies within the cell's largest corner
    # distance of its centre, which a sample's map stretches by at most its norm.
    cells, owner = np.unique(b, axis=0, return_inverse=True)
    owner = owner.reshape(-1)
    centre, _ = cell_points(points, cells + 0.5)
    size = np.zeros(len(cells))
    for corner in np.ndindex(2, 2, 2):
        c, _ = cell_points(points, cells + np.array(corner, dtype=np.float64))
        size = np.maximum(size, np.linalg.norm(c - centre, axis=1))
    stretch = _stretch(to_cell) if stretch is None else stretch
    rk, rj, ri = reach
    out = [[], [], [], [], []]
    for off in np.ndindex(2 * rk + 2, 2 * rj + 2, 2 * ri + 2):
        shift = np.array(off) - np.array(reach)
        t = cells + shift
        ok = (t[:, 0] >= 0) & (t[:, 0] < nk) & (t[:, 1] >= 0) & (t[:, 1] < nj)
        k, j, i = t[:, 0].clip(0, nk - 1), t[:, 1].clip(0, nj - 1), t[:, 2] % ni
        dc = np.einsum("nij,nj->ni", to_cell[k, j, i], centre - points[k, j, i])
        near = ok & (np.sqrt(np.einsum("ij,ij->i", dc, dc)) < kernel.radius + stretch[k, j, i] * size)
        if not near.any():
            continue
        pts = np.flatnonzero(near[owner])
        t = b[pts] + shift
        k, j, i = t[:, 0], t[:, 1], t[:, 2] % ni
        d = np.einsum("nij,nj->ni", to_cell[k, j, i], x[pts] - points[k, j, i])
        w = kernel.weight(d)
        hit = w > 0
        for lst, a in zip(out, (pts, k, j, i, w)):
            lst.append(a[hit])
    if not out[0]:
        return tuple(np.zeros(0, dtype=dt) for dt in (np.int64, np.int64, np.int64, np.int64, np.float64))
    return tuple(np.concatenate(a) for a in out)


def _levels_within(coord, half):
    """For each level ``m``: the largest index distance to a level whose kernel (half-width
    ``half``, in the units of ``coord``) reaches it."""
    reaches = np.abs(coord[None, :] - coord[:, None]) < half[None, :]  # [m, k]: k's kernel reaches m
    dist = np.abs(np.arange(coord.size)[:, None] - np.arange(coord.size)[None, :])
    return np.max(np.where(reaches, dist, 0), axis=1)


def shell_reach(lat, heights, radius, lam_lon, lam_lev):
    """Index reach of the widened kernels of a shell grid, for :func:`stencil_weights`.

    Returns ``(rk (nk,), rj, ri (nj,))``: the largest level distance from a point on
    level ``k`` to a sample whose kernel reaches it (plus one for the point's
    position in its cell), the same for rows, and the column distance on row ``j``.
    """
    lat = np.asarray(lat, dtype=np.float64)
    heights = np.asarray(heights, dtype=np.float64)
    rk = _levels_within(heights, radius * lam_lev * np.gradient(heights)) + 1
    rj = int(_levels_within(lat, radius * np.abs(np.gradient(lat))).max()) + 1
    coslat = np.maximum(np.cos(np.deg2rad(lat)), 1e-12)
    ri = np.empty(lat.size, dtype=np.int64)
    for jp in range(lat.size):
        near = slice(max(jp - rj, 0), min(jp + rj + 1, lat.size))
        ri[jp] = int(np.ceil(radius * max(1.0, float(np.max(lam_lon[near] * coslat[near])) / coslat[jp]))) + 1
    return rk, rj, ri


@lru_cache(maxsize=8)
def _factors(lat_bytes, shell_bytes, lon_step, exaggeration, kernel_params):
    from scipy import sparse
    from scipy.sparse.linalg import spsolve


    kernel = SplatKernel(*kernel_params)
    lat = np.frombuffer(lat_bytes)
    shells = np.frombuffer(shell_bytes)
    nk, nj = shells.size, lat.size
    lam_lon, lam_lev = widening(lat, shells, kernel.radius)
    prior = (1.0 / (lam_lev[:, None] * lam_lon[None, :])).ravel()
    kk, jj = np.meshgrid(np.arange(_MARGIN, nk - _MARGIN - 1), np.arange(_MARGIN, nj - _MARGIN - 1), indexing="ij")
    if kk.size == 0:
        return prior.reshape(nk, nj)
    rk, rj, ri = shell_reach(lat, shells, kernel.radius, lam_lon, lam_lev)
    rk, ri = rk[kk.ravel()], ri[jj.ravel()]
    ni = 2 * int(ri.max()) + 4  # a slab of identical columns stands for the whole circle
    slab = GlobeGrid(lon_step * np.arange(ni), lat, np.broadcast_to(shells[:, None, None], (nk, nj, ni)).copy())
    points, jac = cell_jacobians(slab, exaggeration)
    jac = widen(jac, lam_lon[None, :, None], lam_lev[:, None, None])
    to_cell = kernel.radius * np.linalg.inv(principal_axes(jac.reshape(-1, 3, 3), kernel.radius)).reshape(jac.shape)
    base = np.column_stack([kk.ravel(), jj.ravel(), np.full(kk.size, ni // 2)]).astype(np.float64)
    rng = np.random.default_rng(0)
    cells = np.arange(kk.size)
    mat = None
    stretch = _stretch(to_cell)
    for rows in np.unique(np.column_stack([rk, ri]), axis=0):  # cells grouped by their reach
        sel = cells[(rk == rows[0]) & (ri == rows[1])]
        pts = np.vstack([base[sel] + o for o in _FACES]
                        + [base[sel] + rng.random((sel.size, 3)) for _ in range(_RANDOM_PER_CELL)])
        row, k, j, _, w = stencil_weights(points, to_cell, pts, kernel, (int(rows[0]), rj, int(rows[1])), stretch)
        part = sparse.csr_matrix((w, (row, k * nj + j)), shape=(len(pts), nk * nj))
        mat = part if mat is None else sparse.vstack([mat, part])
    mat = mat.tocsr()
    reg = _REGULARISE**2
    lhs = (mat.T @ mat + reg * sparse.identity(nk * nj)).tocsc()
    rhs = mat.T @ np.ones(mat.shape[0]) + reg * prior
    return spsolve(lhs, rhs).reshape(nk, nj)


def _sample_reach(jac, lam_i, lam_j, heights, lam_lev, radius):
    """``(rk, rj, ri)`` for :func:`stencil_weights` on a curvilinear shell layout: the level
    reach as :func:`shell_reach`, the column reach from the widest kernel over the narrowest
    spacing near it (the horizontal spacing grows with the radius alike in every column)."""
    from scipy import ndimage

    rk = int(_levels_within(heights, radius * lam_lev * np.gradient(heights)).max()) + 1
    out = [rk]
    for axis, lam in ((1, lam_j), (0, lam_i)):
        s = np.linalg.norm(jac[0, ..., axis], axis=-1)
        size = 2 * int(np.ceil(radius * lam.max())) + 3
        widest = ndimage.maximum_filter(lam * s, size=size, mode="nearest")
        out.append(int(np.ceil(radius * np.max(widest / ndimage.minimum_filter(s, size=size, mode="nearest")))) + 1)
    return tuple(out)


def _block_factors(points, to_cell, prior, reach, kernel):
    """:func:`sample_factors` of one block of columns (fitted 3 cells from its edges)."""
    from scipy import sparse
    from scipy.sparse.linalg import LinearOperator, cg

    shape = prior.shape
    hi = np.array(shape) - _MARGIN - 1
    if np.any(hi <= _MARGIN):
        return prior.copy()
    half = [np.arange(2 * _MARGIN, 2 * h + 1) / 2.0 for h in hi]
    cells = np.stack(np.meshgrid(*[np.arange(_MARGIN, h) for h in hi], indexing="ij"), axis=-1).reshape(-1, 3)
    rng = np.random.default_rng(0)
    pts = np.vstack(
        [np.stack(np.meshgrid(*half, indexing="ij"), axis=-1).reshape(-1, 3)]
        + [cells + rng.random(cells.shape) for _ in range(_RANDOM_PER_SAMPLE_CELL)]
    )
    base = np.minimum(np.floor(pts), hi - 1)
    pts = pts[np.lexsort(base.T[::-1])]  # a cell's points in one chunk: stencil_weights culls per cell
    parts = []
    stretch = _stretch(to_cell)
    for start in range(0, len(pts), _CHUNK):
        row, k, j, i, w = stencil_weights(points, to_cell, pts[start : start + _CHUNK], kernel, reach, stretch)
        cols = np.ravel_multi_index((k, j, i), shape)
        parts.append(sparse.csr_matrix((w, (row, cols)), shape=(min(_CHUNK, len(pts) - start), prior.size)))
    mat = sparse.vstack(parts).tocsr()
    reg = _REGULARISE**2
    n = prior.size
    normal = LinearOperator((n, n), matvec=lambda c: mat.T @ (mat @ c) + reg * c, dtype=np.float64)
    diag = np.bincount(mat.indices, mat.data**2, minlength=n) + reg
    jacobi = LinearOperator((n, n), matvec=lambda c: c / diag, dtype=np.float64)
    rhs = mat.T @ np.ones(mat.shape[0]) + reg * prior.ravel()
    c, _ = cg(normal, rhs, x0=prior.ravel(), rtol=_CG_RTOL, maxiter=_CG_ITERATIONS, M=jacobi)
    return c.reshape(shape)


def sample_factors(points, jac, prior, reach, kernel):
    """Weight factors ``c (nk, nj, ni)``, one per sample, of a curvilinear shell layout.

    Least squares: the weights sum to one at the half-step lattice (nodes, cell, face and
    edge centres) of the closed block of cells whose support is complete (3 cells from every
    edge) and at random points of its cells, regularised towards ``prior`` (the widened
    kernels' share); conjugate gradients on the normal equations, Jacobi-preconditioned,
    from ``prior``.  Samples no such point sees keep ``prior``.  Solved in tiles of
    ``_TILE²`` columns, each with ``_HALO`` more columns around it (fitted to 3 from the
    halo's edge, i.e. 5 columns past the tile), so that memory stays bounded.

    Parameters
    ----------
    points : (nk, nj, ni, 3) scene positions of the samples.
    jac : (nk, nj, ni, 3, 3) their widened Jacobians (the splats' ellipsoids).
    prior : (nk, nj, ni) the factors without the solve, ``1 / (λ_i λ_j λ_lev)``.
    reach : (rk, rj, ri) index reach of the kernels, for :func:`stencil_weights`.
    kernel : SplatKernel
    """
    radius = kernel.radius
    to_cell = radius * np.linalg.inv(principal_axes(jac.reshape(-1, 3, 3), radius)).reshape(jac.shape)
    out = np.empty_like(prior)
    nj, ni = prior.shape[1:]
    for j0 in range(0, nj, _TILE):
        for i0 in range(0, ni, _TILE):
            ja, ia = max(j0 - _HALO, 0), max(i0 - _HALO, 0)
            block = np.s_[:, ja : min(j0 + _TILE + _HALO, nj), ia : min(i0 + _TILE + _HALO, ni)]
            c = _block_factors(points[block], to_cell[block], prior[block], reach, kernel)
            out[:, j0 : j0 + _TILE, i0 : i0 + _TILE] = c[:, j0 - ja : j0 - ja + _TILE, i0 - ia : i0 - ia + _TILE]
    return out


@lru_cache(maxsize=2)
def _curvilinear(lon_bytes, lat_bytes, columns, shell_bytes, stride, exaggeration, kernel_params):
    kernel = SplatKernel(*kernel_params)
    shells = np.frombuffer(shell_bytes)
    shape = (shells.size,) + columns
    lon2d, lat2d = (np.frombuffer(b).reshape(columns) for b in (lon_bytes, lat_bytes))
    layout = GlobeGrid(np.arange(columns[1], dtype=np.float64), np.arange(columns[0], dtype=np.float64),
                       np.broadcast_to(shells[:, None, None], shape).copy(), lon2d=lon2d, lat2d=lat2d)
    points, jac = cell_jacobians(layout, exaggeration, stride)
    lam_i, lam_j = column_widening(jac, kernel.radius)
    lam_lev = _level_widening(shells[::stride], kernel.radius)
    jac = widen(jac, lam_i, lam_lev[:, None, None], lam_j)
    prior = 1.0 / (lam_i[None] * lam_j[None] * lam_lev[:, None, None])
    reach = _sample_reach(jac, lam_i, lam_j, shells[::stride], lam_lev, kernel.radius)
    return points, jac, sample_factors(points, jac, prior, reach, kernel)


def curvilinear_shells(grid, heights, stride, exaggeration, kernel):
    """The shell layout of a curvilinear grid, every ``stride``-th sample (module docstring).

    Returns
    -------
    points : (nk', nj', ni', 3) scene positions of the samples.
    jac : (nk', nj', ni', 3, 3) their Jacobians, widened (the splats' ellipsoids).
    factors : (nk', nj', ni') the per-sample weight factors (:func:`sample_factors`).
        All three cached per arguments; do not modify them.
    """
    params = (kernel.kind, kernel.radius, kernel.sigma, kernel.window)
    key = [np.ascontiguousarray(a, dtype=np.float64).tobytes() for a in (grid.lon2d, grid.lat2d, heights)]
    return _curvilinear(key[0], key[1], grid.lat2d.shape, key[2], int(stride), float(exaggeration), params)


def shell_factors(lat, heights, lon_step, exaggeration, kernel):
    """Weight factors ``c (n_shells, nj)`` of the samples of a shell grid (module docstring).

    Parameters
    ----------
    lat : (nj,) latitudes in degrees.
    heights : (n_shells,) shell heights in metres, ascending.
    lon_step : float
        Longitude spacing in degrees (regular).
    exaggeration : float
    kernel : SplatKernel

    Returns
    -------
    (n_shells, nj) float64 (cached per arguments).
    """
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    h = np.ascontiguousarray(heights, dtype=np.float64)
    params = (kernel.kind, kernel.radius, kernel.sigma, kernel.window)
    return _factors(lat.tobytes(), h.tobytes(), float(lon_step), float(exaggeration), params).copy()


__all__ = [
    "ShellSampler", "cell_points", "check_shells", "column_widening", "curvilinear_shells", "sample_factors",
    "shell_factors", "shell_heights", "shell_reach", "stencil_weights", "widen", "widening",
]
