"""Blobby surfaces: the contour of a sum of Gaussian ellipsoids, meshed sparsely.

The field is

    f(x) = sum_i w_i exp(-1/2 |S_i^-1 R_i^T (x - c_i)|^2)

(Blinn's "blobby" model, the paper's molecules).  :func:`blobby_surface`
meshes ``f = level`` in four steps, each a compiled kernel (``native/src/blobby_*.c``,
through :mod:`..native`) where the ``nephele_native`` wheel is installed, else whole-array
NumPy (the kernels' twins, agreeing to the tolerances tests/core/muscle states):

1. The grid is cut into blocks of :data:`BLOCK`\\ :sup:`3` nodes.  For every
   (block, Gaussian) pair whose ``cutoff`` ellipsoid reaches the block, the
   Gaussian's Mahalanobis distance to the block centre bounds it over the
   block; summed, the bounds say which blocks lie wholly below or wholly above
   the level.  Only the others are evaluated.
2. Node values of those blocks: per pair the exponent splits into three 2-D
   tables (k-j, k-i, j-i), so a node costs two multiplies per Gaussian.
3. Marching cubes with the project's tables (:mod:`nephele.core.surface._mc_tables`,
   the classification ``value >= level`` and :data:`~nephele.core.surface.contour.EDGE_MARGIN`
   of :func:`~nephele.core.surface.contour.isosurface`).  Every node belongs to one
   block and every block reads it from there, so neighbouring blocks agree on
   every corner and every grid edge has one vertex: closed blobs are
   watertight.  Steps 2 and 3 run :data:`MARCH_BATCH` active blocks at a time
   (memory: 100,000 bench ellipsoids, 120M vertices, mesh in 11 GiB at the peak).
4. Each vertex slides along its grid edge onto the level set of the sum cut at
   ``cutoff + 1`` sigma (safeguarded Newton steps on the analytic derivative);
   marching cubes alone leaves about 0.02 sigma at spacing sigma/4.  Normals
   are the analytic gradient.

With ``box`` the field is periodic (every image counts) and the mesh is the
part in the box: vertices on the faces ``x = 0`` and ``x = L`` are the same
points shifted by exactly ``L``, so copies of the mesh shifted by the box
vectors join without cracks.

References
----------
.. [1] J. F. Blinn, "A generalization of algebraic surface drawing",
   ACM Transactions on Graphics 1(3), 235-256 (1982).
.. [2] W. E. Lorensen and H. E. Cline, "Marching cubes", SIGGRAPH 1987.
.. [3] N. Max and R. Crawfis, "Advances in Scientific Visualization" (muscle
   molecules as contour surfaces of sums of Gaussian ellipsoids).
"""

import ctypes
import functools
from dataclasses import dataclass

import numpy as np

from .. import native
from ..surface import _mc_tables as tables
from ..surface.contour import EDGE_MARGIN
from ..errors import DataError
from ..memory import check_memory
from ..surface.mesh import Mesh, vertex_normals
from ..threads import default_threads, thread_map

BLOCK = 8
"""Nodes per block edge: 8 nodes at spacing sigma/4 span 2 sigma."""

NEWTON_TOL = 2e-4
"""Newton stops when |f - level| / |grad f| < NEWTON_TOL * sigma_min."""

NEWTON_STEPS = 12
SETTLE_STEP = 10.0
"""A Newton step may end a vertex only if shorter than SETTLE_STEP * NEWTON_TOL * sigma_min (its
normal is the gradient where the step starts: off by about the step over the surface's radius).
Its position keeps NEWTON_TOL (the step's second-order error must be below it).  Bench scene of
1,000 ellipsoids: normals within 0.31 deg of the exact gradient (2: 0.10 deg), positions the same,
a tenth less time."""
REFINE_EXTRA = 1.0
"""Vertices are projected onto the sum cut at (cutoff + REFINE_EXTRA) sigma."""

EXACT_RANGE = 12.0
"""The "exact" field counts every image within this many sigma (the rest is below 1e-31 w)."""

_F32 = np.float32
_EXP_MAX = _F32(40.0)
"""Largest exponent of one of the three float32 factors (two of them multiply below exp(88.7), the overflow)."""


@dataclass
class _Blobs:
    """Gaussians (periodic images included) as float64 arrays; ``src`` is the input index."""

    src: np.ndarray  # (m,) int64
    c: np.ndarray  # (m, 3) centres
    a: np.ndarray  # (m, 6) inverse covariance xx yy zz xy xz yz
    lnw: np.ndarray  # (m,) log weight
    smax: np.ndarray  # (m,) largest sigma: 1 / sqrt of A's smallest eigenvalue
    half: np.ndarray  # (m, 3) bounding-box half-widths at Mahalanobis radius 1

    def take(self, idx):
        return _Blobs(*(x[idx] for x in (self.src, self.c, self.a, self.lnw, self.smax, self.half)))


def _check(centers, rotations, sigmas, weights):
    c = np.asarray(centers, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise DataError(f"needs shape (n, 3), got {c.shape}", field="centers")
    n = len(c)
    r = np.asarray(rotations, dtype=np.float64)
    if r.shape != (n, 3, 3):
        raise DataError(f"needs shape ({n}, 3, 3), got {r.shape}", field="rotations")
    s = np.asarray(sigmas, dtype=np.float64)
    if s.shape != (n, 3):
        raise DataError(f"needs shape ({n}, 3), got {s.shape}", field="sigmas")
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise DataError(f"needs shape ({n},), got {w.shape}", field="weights")
    for name, x in (("centers", c), ("rotations", r), ("sigmas", s), ("weights", w)):
        if not np.all(np.isfinite(x)):
            raise DataError("has NaN or infinite values", field=name)
    if n and not np.all(s > 0):
        raise DataError("must be positive", field="sigmas")
    if n and not np.all(w >= 0):
        raise DataError("must be >= 0 (negative blobs are not supported)", field="weights")
    if n:
        err = np.abs(np.einsum("nki,nkj->nij", r, r) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero(err > 1e-5)
        if len(bad):
            raise DataError(f"rotation {bad[0]} is not orthonormal (|R^T R - I| = {err[bad[0]]:.2g})", field="rotations")
    return c, r, s, w


def _blobs(c, r, s, w):
    keep = np.flatnonzero(w > 0)
    c, r, s, w = c[keep], r[keep], s[keep], w[keep]
    # A = R S^-2 R^T (inverse covariance); the covariance's diagonal gives the bounding box.
    a = np.einsum("nik,nk,njk->nij", r, 1.0 / s**2, r)
    cov = np.einsum("nik,nk->ni", r**2, s**2)
    a6 = np.stack([a[:, 0, 0], a[:, 1, 1], a[:, 2, 2], a[:, 0, 1], a[:, 0, 2], a[:, 1, 2]], axis=1)
    return _Blobs(keep.astype(np.int64), c, a6, np.log(w), s.max(axis=1), np.sqrt(cov))


def _images(b, box, radius):
    """Every periodic image whose ``radius``-sigma box meets [0, L]: centres wrapped into the box first."""
    box = np.asarray(box, dtype=np.float64)
    c = b.c - np.floor(b.c / box) * box
    c = np.where(c >= box, c - box, c)  # floor rounding at the top
    e = radius * b.half
    lo = np.ceil((-e - c) / box).astype(np.int64)
    hi = np.floor((box + e - c) / box).astype(np.int64)
    cnt = hi - lo + 1
    tot = cnt.prod(axis=1)
    idx = np.repeat(np.arange(len(c)), tot)
    k = np.arange(tot.sum()) - np.repeat(np.cumsum(tot) - tot, tot)
    shift = np.empty((len(idx), 3), np.int64)
    shift[:, 0] = lo[idx, 0] + k % cnt[idx, 0]
    shift[:, 1] = lo[idx, 1] + (k // cnt[idx, 0]) % cnt[idx, 1]
    shift[:, 2] = lo[idx, 2] + k // (cnt[idx, 0] * cnt[idx, 1])
    out = b.take(idx)
    out.c = c[idx] + shift * box
    return out


def _quad(a6, d):
    """d^T A d for rows of d (..., 3) and A in 6-component form."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return a6[..., 0] * x * x + a6[..., 1] * y * y + a6[..., 2] * z * z + 2 * (
        a6[..., 3] * x * y + a6[..., 4] * x * z + a6[..., 5] * y * z
    )


def _amul(a6, d):
    """A d (..., 3)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack(
        [
            a6[..., 0] * x + a6[..., 3] * y + a6[..., 4] * z,
            a6[..., 3] * x + a6[..., 1] * y + a6[..., 5] * z,
            a6[..., 4] * x + a6[..., 5] * y + a6[..., 2] * z,
        ],
        axis=-1,
    )


# --- exact field ------------------------------------------------------------


def blobby_field(points, centers, rotations, sigmas, weights, *, box=None, gradient=False):
    """The exact (uncut) sum of Gaussian ellipsoids at ``points``.

    Brute force over every Gaussian (and, with ``box``, every periodic image
    within :data:`EXACT_RANGE` sigma, beyond which an image adds less than
    1e-31 of its weight), in float64: the reference the meshes are checked
    against.  Cost grows as points x Gaussians.

    Parameters
    ----------
    points : (p, 3) array
    centers, rotations, sigmas, weights
        As for :func:`blobby_surface`.
    box : (3,) floats, optional
        Periodic box ``(Lx, Ly, Lz)``.
    gradient : bool
        Also return the gradient ``(p, 3)``.

    Returns
    -------
    f : (p,) float64, and grad : (p, 3) float64 if ``gradient``.

    References
    ----------
    .. [1] J. F. Blinn, "A generalization of algebraic surface drawing", ACM TOG 1(3), 1982.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    c, r, s, w = _check(centers, rotations, sigmas, weights)
    b = _blobs(c, r, s, w)
    if box is not None:
        b = _images(b, _check_box(box), EXACT_RANGE)
    f = np.zeros(len(pts))
    g = np.zeros((len(pts), 3))
    step = max(1, 4_000_000 // max(len(b.c), 1))
    for lo in range(0, len(pts), step):
        d = pts[lo : lo + step, None, :] - b.c[None]  # (p, m, 3)
        e = np.exp(b.lnw - 0.5 * _quad(b.a, d))
        f[lo : lo + step] = e.sum(axis=1)
        if gradient:
            g[lo : lo + step] = -np.einsum("pm,pmi->pi", e, _amul(b.a, d))
    return (f, g) if gradient else f


def level_distance(points, centers, rotations, sigmas, weights, level, *, box=None):
    """First-order distance ``|f - level| / |grad f|`` of ``points`` from the exact level set."""
    f, g = blobby_field(points, centers, rotations, sigmas, weights, box=box, gradient=True)
    return np.abs(f - level) / np.linalg.norm(g, axis=1)


# --- meshing ----------------------------------------------------------------


def _check_box(box):
    box = np.asarray(box, dtype=np.float64)
    if box.shape != (3,) or not np.all(np.isfinite(box)) or not np.all(box > 0):
        raise DataError(f"needs three positive lengths, got {box.tolist()}", field="box")
    return box


def _positive(x, name):
    x = float(x)
    if not np.isfinite(x) or x <= 0:
        raise DataError(f"must be a positive number, got {x}", field=name)
    return x


@dataclass
class _Grid:
    """Nodes at n * h; block q owns nodes q * BLOCK ... q * BLOCK + BLOCK - 1 per axis."""

    h: np.ndarray  # (3,) spacing
    box: np.ndarray | None  # (3,) or None
    nb: np.ndarray | None  # (3,) blocks per axis (periodic)

    @property
    def size(self):
        return BLOCK * self.h

    def coords(self, n):
        """Positions of integer nodes (m, 3); node N of a periodic axis is exactly L."""
        x = n * self.h
        if self.box is not None:
            x = np.where(n == BLOCK * self.nb, self.box, x)
        return x


def _grid(spacing, box):
    if box is None:
        return _Grid(np.full(3, spacing), None, None)
    nb = np.maximum(1, np.ceil(box / (BLOCK * spacing))).astype(np.int64)
    return _Grid(box / (BLOCK * nb), box, nb)


@dataclass
class _Blocks:
    """Active blocks (sorted by key) and the lists of Gaussians reaching each."""

    q: np.ndarray  # (na, 3) block coordinates
    nbr: np.ndarray  # (na, 8) active index of the block at offset code 4*dz+2*dy+dx; -1 below, -2 above
    grid_start: np.ndarray  # (na + 1,) into grid_g
    grid_g: np.ndarray  # Gaussians within cutoff, per block
    fine_start: np.ndarray  # (na + 1,) into fine_g
    fine_g: np.ndarray  # Gaussians within cutoff + REFINE_EXTRA, per block
    node_lo: np.ndarray  # (3,) lowest node of the block index's range
    node_dims: np.ndarray  # (3,) nodes in that range (edge keys)


_PAIR_CHUNK = 1 << 18  # (block, Gaussian) candidates per step: temporaries of a few MB


def _block_pairs(b, grid, cut, cut_fine, threads):
    """The block index (:class:`_Index`, over every candidate block) and, per run of Gaussians,
    (key (p,), g (p,), on_grid (p,), upper (p,), lower (p,)) for blocks whose closed box may meet a
    Gaussian's ``cut_fine`` ellipsoid: whether it meets the ``cut`` one too, and then bounds of the
    Gaussian over the block from above and below (from sphere bounds of the Mahalanobis distance;
    0 where not on the grid).  None if no block is a candidate."""
    size = grid.size
    e = cut_fine * b.half
    lo = np.ceil((b.c - e) / size).astype(np.int64) - 1
    hi = np.floor((b.c + e) / size).astype(np.int64)
    if grid.box is not None:
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, grid.nb - 1)
    cnt = np.maximum(hi - lo + 1, 0)
    tot = cnt.prod(axis=1)
    some = tot > 0
    if not some.any():
        return None, []
    index = _Index(grid, lo[some].min(axis=0), hi[some].max(axis=0))
    # The largest A-norm of a block's half-diagonals, per Gaussian: a point of the block is within
    # this Mahalanobis distance of its centre (the norm is convex, so a corner is farthest).
    diag = np.array([[1, 1, 1], [-1, 1, 1], [1, -1, 1], [1, 1, -1]]) * (size / 2)
    ra = np.sqrt(np.max([_quad(b.a, np.broadcast_to(dv, b.c.shape)) for dv in diag], axis=0))
    ends = np.cumsum(tot)
    spans, start = [], 0
    while start < len(tot):
        done = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, done + _PAIR_CHUNK, side="right")), start + 1)
        spans.append((start, stop))
        start = stop

    kernel = native.kernel("blobby_block_pairs", ctypes.c_int64, [ctypes.c_int64] * 2 + [ctypes.c_void_p] * 8
                           + [ctypes.c_double] * 2 + [ctypes.c_void_p] * 2 + [ctypes.c_int64] + [ctypes.c_void_p] * 5)
    if kernel is not None:
        arrays = _c_arrays(lo, cnt, b.c, b.a, b.lnw, b.smax, ra, size, index.lo, index.dims)

    def run(span):
        start, stop = span
        if kernel is not None:
            m = int(tot[start:stop].sum())
            out = (np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.bool_), np.empty(m), np.empty(m))
            ptrs = [x.ctypes.data for x in arrays + list(out)]
            n = kernel(start, stop, *ptrs[:8], cut, cut_fine, *ptrs[8:10], index.box, *ptrs[10:])
            return tuple(x[:n] for x in out)
        t = tot[start:stop]
        g = np.repeat(np.arange(start, stop), t)
        k = np.arange(t.sum()) - np.repeat(np.cumsum(t) - t, t)
        cg = cnt[g]
        q = np.empty((len(g), 3), np.int64)
        q[:, 0] = lo[g, 0] + k % cg[:, 0]
        q[:, 1] = lo[g, 1] + (k // cg[:, 0]) % cg[:, 1]
        q[:, 2] = lo[g, 2] + k // (cg[:, 0] * cg[:, 1])
        d = (q + 0.5) * size - np.take(b.c, g, axis=0)
        sq = np.sqrt(_quad(np.take(b.a, g, axis=0), d))
        gap = np.maximum(np.abs(d) - size / 2, 0.0)  # Euclidean offsets from the centre to the block
        near = np.maximum(np.maximum(sq - ra[g], 0.0), np.sqrt(np.einsum("ij,ij->i", gap, gap)) / b.smax[g])
        far = sq + ra[g]  # upper bound
        keep = np.flatnonzero(near <= cut_fine)
        g, near, far = g[keep], near[keep], far[keep]
        w = np.exp(b.lnw[g])
        on_grid = near <= cut
        upper = np.where(on_grid, w * np.exp(-0.5 * near**2), 0.0)
        lower = np.where(on_grid, w * np.exp(-0.5 * far**2), 0.0)
        return index.key(q[keep]), g, on_grid, upper, lower

    return index, thread_map(run, spans, threads)


class _Index:
    """Block coordinates -> a compact key; dense table where small, sorted keys otherwise."""

    def __init__(self, grid, qlo, qhi):
        if grid.box is not None:
            self.lo, self.dims = np.zeros(3, np.int64), grid.nb.copy()
        else:
            self.lo, self.dims = qlo - 1, qhi - qlo + 3  # room for the +1 neighbours
        self.box = grid.box is not None

    def key(self, q):
        q = q - self.lo
        if self.box:
            q = q % self.dims
        return (q[:, 2] * self.dims[1] + q[:, 1]) * self.dims[0] + q[:, 0]

    def block(self, key):
        """The block coordinates of keys (a periodic index's in [0, nb))."""
        i, k = np.divmod(key, self.dims[0])
        k2, j = np.divmod(i, self.dims[1])
        return np.stack([k, j, k2], axis=1) + self.lo

    @property
    def total(self):
        return int(np.prod(self.dims))


def _find_blocks(b, grid, level, cut, cut_fine, threads):
    """Classify blocks by bounds; return the active ones with their Gaussian lists, or None."""
    index, parts = _block_pairs(b, grid, cut, cut_fine, threads)
    key = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
    if len(key) == 0:
        return None
    g = np.concatenate([p[1] for p in parts])
    on_grid = np.concatenate([p[2] for p in parts])
    dense = index.total <= 1 << 25
    if dense:
        slot, nslot = key, index.total
    else:
        ukeys, slot = np.unique(key, return_inverse=True)
        slot = slot.reshape(-1)
        nslot = len(ukeys)
    upper = np.bincount(slot, np.concatenate([p[3] for p in parts]), nslot)
    lower = np.bincount(slot, np.concatenate([p[4] for p in parts]), nslot)
    cls = np.full(nslot, -1, np.int64)  # below
    cls[lower >= level] = -2  # above
    act = np.flatnonzero((upper >= level) & (lower < level))
    if len(act) == 0:
        return None
    cls[act] = np.arange(len(act))

    fine_start, fine_g, grid_start, grid_g, first = _group_pairs(slot, cls, g, on_grid, len(act))
    act_q = index.block(key[first])

    # Neighbours at offsets (dx, dy, dz) in {0, 1}^3.
    nbr = np.empty((len(act), 8), np.int64)
    for code in range(8):
        off = np.array([code & 1, (code >> 1) & 1, code >> 2])
        k = index.key(act_q + off)
        if dense:
            nbr[:, code] = cls[k]
        else:
            pos = np.minimum(np.searchsorted(ukeys, k), len(ukeys) - 1)
            nbr[:, code] = np.where(ukeys[pos] == k, cls[pos], -1)
    return _Blocks(act_q, nbr, grid_start, grid_g, fine_start, fine_g, index.lo * BLOCK, index.dims * BLOCK)


def _group_pairs(slot, cls, g, on_grid, na):
    """The pairs' Gaussians ``g`` listed by active block ``cls[slot]`` (the others dropped), in pair
    order: (fine_start, fine_g, grid_start, grid_g (on-grid pairs only), first pair of each block)."""
    count = native.kernel("blobby_group_count", None, [ctypes.c_int64] + [ctypes.c_void_p] * 3 + [ctypes.c_int64]
                          + [ctypes.c_void_p] * 2)
    if count is not None:
        return _group_pairs_c(count, slot, cls, g, on_grid, na)
    ai = cls[slot]
    sel = np.flatnonzero(ai >= 0)
    order = sel[_argsort_small(ai[sel], na)]  # by block, then Gaussian
    ai_sorted = ai[order]
    fine_start = np.searchsorted(ai_sorted, np.arange(na + 1))
    fine_g = g[order]
    grid_sel = on_grid[order]
    grid_g = fine_g[grid_sel]
    grid_start = np.searchsorted(ai_sorted[grid_sel], np.arange(na + 1))
    return fine_start, fine_g, grid_start, grid_g, order[fine_start[:-1]]


def _group_pairs_c(count, slot, cls, g, on_grid, na):
    """:func:`_group_pairs` by the compiled kernels (a counting sort, native/src/blobby_nodes.c)."""
    fill = native.kernel("blobby_group_fill", None, [ctypes.c_int64] + [ctypes.c_void_p] * 4 + [ctypes.c_int64]
                         + [ctypes.c_void_p] * 6)
    held = [*_c_arrays(slot, cls), np.ascontiguousarray(on_grid, np.bool_), *_c_arrays(g)]
    slot_p, cls_p, on_p, g_p = (x.ctypes.data for x in held)
    fine_start, grid_start = np.empty(na + 1, np.int64), np.empty(na + 1, np.int64)
    count(len(slot), slot_p, cls_p, on_p, na, fine_start.ctypes.data, grid_start.ctypes.data)
    fine_g, grid_g = np.empty(fine_start[-1], np.int64), np.empty(grid_start[-1], np.int64)
    first, cursor = np.empty(na, np.int64), np.empty(2 * na, np.int64)
    fill(len(slot), slot_p, cls_p, on_p, g_p, na, fine_start.ctypes.data, grid_start.ctypes.data, fine_g.ctypes.data,
         grid_g.ctypes.data, first.ctypes.data, cursor.ctypes.data)
    return fine_start, fine_g, grid_start, grid_g, first


def _argsort_small(x, top):
    """``np.argsort(x, kind="stable")`` for integers ``0 <= x < top``: below 2^32, two stable passes on
    16-bit digits, which NumPy sorts by radix (1.5M block indices, the bench's 5,000 ellipsoids:
    36 ms against 104 ms of timsort on int64, a serial step)."""
    if top > 1 << 32:
        return np.argsort(x, kind="stable")
    p = np.argsort((x & 0xFFFF).astype(np.uint16), kind="stable")
    if top <= 1 << 16:
        return p
    return p[np.argsort((x[p] >> 16).astype(np.uint16), kind="stable")]


def _chunks(n, size):
    return [(lo, min(lo + size, n)) for lo in range(0, n, size)]


def _node_values(b, grid, blocks, threads, act=None):
    """Values of the active blocks ``act`` (default: all) at their own BLOCK^3 nodes, float32
    (len(act), B, B, B) in (k, j, i) order.  A block's values are the same bits in any subset: every
    operation is elementwise per (block, Gaussian) pair, summed in the block's own Gaussian order."""
    B = BLOCK
    act = np.arange(len(blocks.q)) if act is None else act
    kernel = native.kernel("blobby_node_values", None, [ctypes.c_int64] + [ctypes.c_void_p] * 10)
    if kernel is not None:
        return _node_values_c(kernel, b, grid, blocks, threads, act)
    na = len(act)
    count = np.diff(blocks.grid_start)[act]
    perm = np.argsort(-count, kind="stable")  # most Gaussians first: rank r's blocks are a prefix
    values = np.empty((na, B, B, B), _F32)  # (every block is written once)
    u = [np.arange(B) * grid.h[a] for a in range(3)]
    uu = [x * x for x in u]
    uxy = (u[1][:, None] * u[0][None, :]).astype(_F32)[:, :, None]  # [j, i]
    uxz = (u[2][:, None] * u[0][None, :]).astype(_F32)[:, :, None]  # [k, i]
    uyz = (u[2][:, None] * u[1][None, :]).astype(_F32)[:, :, None]  # [k, j]

    def run(span):
        bl = perm[span[0] : span[1]]
        cnt = count[bl]
        gbl = act[bl]
        # The chunk's (block, Gaussian) pairs rank by rank: rank r's pairs are those of blocks bl[:n_r].
        rank, at = np.nonzero(np.arange(int(cnt[0]))[:, None] < cnt[None, :])
        ends = np.cumsum(np.bincount(rank))
        g = blocks.grid_g[blocks.grid_start[gbl[at]] + rank]
        rel = np.take(b.c, g, axis=0) - np.take(blocks.q, gbl[at], axis=0) * grid.size
        a6 = np.take(b.a, g, axis=0)
        ar = _amul(a6, rel)
        const = b.lnw[g] - 0.5 * np.einsum("ni,ni->n", rel, ar)
        # exponent(k, j, i) = const + u.Ar - 1/2 u^T A u, split into (j,i), (k,i), (k,j) tables.
        ai = (u[0][:, None] * ar[:, 0] - 0.5 * uu[0][:, None] * a6[:, 0]).astype(_F32)
        bj = (u[1][:, None] * ar[:, 1] - 0.5 * uu[1][:, None] * a6[:, 1] + const).astype(_F32)
        ck = (u[2][:, None] * ar[:, 2] - 0.5 * uu[2][:, None] * a6[:, 2]).astype(_F32)
        a32 = a6.astype(_F32)
        eji = bj[:, None, :] + ai[None, :, :] - uxy * a32[:, 3]
        eki = -uxz * a32[:, 4]
        ekj = ck[:, None, :] - uyz * a32[:, 5]
        # The three factors' exponents may exceed float32's exp range although their sum (<= ln w) does
        # not (strongly sheared Gaussians): such Gaussians take the exponent's sum and one exp.
        big = (eji.max(axis=(0, 1)) > _EXP_MAX) | (eki.max(axis=(0, 1)) > _EXP_MAX) | (ekj.max(axis=(0, 1)) > _EXP_MAX)
        clamp = (lambda e: np.minimum(e, _EXP_MAX)) if big.any() else (lambda e: e)
        tji, tki, tkj = np.exp(clamp(eji)), np.exp(clamp(eki)), np.exp(clamp(ekj))
        acc = np.empty((B, B, B, len(bl)), _F32)
        prod = np.empty_like(acc)
        lo = 0
        for hi in ends:
            n = hi - lo
            p = prod[..., :n] if lo else acc  # rank 0 (every block of the chunk) is the first term
            np.multiply(tkj[:, :, None, lo:hi], tki[:, None, :, lo:hi], out=p)
            np.multiply(p, tji[None, :, :, lo:hi], out=p)
            sel = np.flatnonzero(big[lo:hi])
            if len(sel):
                s = lo + sel
                p[..., sel] = np.exp(ekj[:, :, None, s] + eki[:, None, :, s] + eji[None, :, :, s])
            if lo:
                np.add(acc[..., :n], p, out=acc[..., :n])
            lo = hi
        values[bl] = np.moveaxis(acc, 3, 0)

    thread_map(run, _chunks(na, max(1, 4096 * 64 // B**3)), threads)
    return values


def _c_arrays(*arrays):
    """The arrays as C-contiguous int64 or float64 (copies where needed), for the compiled kernels."""
    return [np.ascontiguousarray(x, np.int64 if x.dtype.kind in "iub" else np.float64) for x in arrays]


def _node_values_c(kernel, b, grid, blocks, threads, act):
    """:func:`_node_values` by the compiled kernel (native/src/blobby_nodes.c), runs of blocks on threads."""
    values = np.empty((len(act), BLOCK, BLOCK, BLOCK), _F32)
    act, *arrays = _c_arrays(act, blocks.grid_start, blocks.grid_g, blocks.q, b.c, b.a, b.lnw, grid.h, grid.size)
    ptrs = [x.ctypes.data for x in arrays]
    step = 1024  # blocks per call: a few ms, shared out to the threads as they come free

    def run(lo):
        kernel(min(step, len(act) - lo), act[lo:].ctypes.data, *ptrs, values[lo:].ctypes.data)

    thread_map(run, range(0, len(act), step), threads)
    return values


def _crossed(values, blocks, level, sel=None, loc=None):
    """The active blocks ``sel`` (default: all; ascending) whose nodes, with the +1 layer read from their
    neighbours, are not all on one side of the level (the others cut no edge); from each block's and its
    neighbours' extremes.  ``values`` row ``loc[q]`` holds block q (default: row q)."""
    na = len(values)
    flat = values.reshape(na, -1)
    lvl = _F32(level)
    lo = np.append(flat.min(axis=1) >= lvl, [True, False])  # every node above; rows na, na + 1: inactive above, below
    hi = np.append(flat.max(axis=1) < lvl, [False, True])  # every node below
    sel = np.arange(len(blocks.q)) if sel is None else sel
    nb = blocks.nbr[sel]
    if loc is not None:
        nb = np.where(nb >= 0, loc[np.maximum(nb, 0)], nb)
    nb = np.where(nb >= 0, nb, na + 2 + nb)  # -2 -> na, -1 -> na + 1
    above = lo[nb[:, 0]] & lo[nb[:, 1:]].all(axis=1)
    below = hi[nb[:, 0]] & hi[nb[:, 1:]].all(axis=1)
    return sel[~(above | below)]


@dataclass
class _EdgeTables:
    """Marching-cubes tables on a block's (BLOCK + 1)^3 extended nodes.

    Edge slots are numbered ``((axis * E + k) * E + j) * E + i`` with
    ``E = BLOCK + 1``, (k, j, i) the edge's lower node; a block owns the edges
    whose lower node it owns (all coordinates below BLOCK).
    """

    table: np.ndarray  # (256, 5, 3) int32, per configuration: each triangle corner's edge slot offset from its cell's (axis 0) slot
    ntri: np.ndarray  # (256,)
    own: np.ndarray  # (3, E, E, E) the block owns this edge slot
    kind: np.ndarray  # (3 E^3,) int8: 0 no such edge (x at i = B, ...), 1 owned, 2 owned by a neighbour
    face_slots: np.ndarray  # (F,) owned slots on a lower face (other blocks refer to them)
    face_index: np.ndarray  # (3 E^3,) slot -> index into face_slots, or -1


def _edge_tables():
    B, E = BLOCK, BLOCK + 1
    table, ntri = tables.cube_table()
    pairs = np.array(tables.PAIRS)
    lower = tables.CORNERS[pairs[:, 0]]  # (di, dj, dk)
    axis = np.argmax(tables.CORNERS[pairs[:, 1]] - lower, axis=1)
    delta = axis * E**3 + lower[:, 2] * E * E + lower[:, 1] * E + lower[:, 0]
    ax, k, j, i = np.meshgrid(np.arange(3), np.arange(E), np.arange(E), np.arange(E), indexing="ij")
    own = (k < B) & (j < B) & (i < B)
    # An edge other blocks refer to lies on a lower face: a coordinate across it is 0.
    on_face = own & (((k == 0) & (ax != 2)) | ((j == 0) & (ax != 1)) | ((i == 0) & (ax != 0)))
    face_slots = np.flatnonzero(on_face.reshape(-1))
    face_index = np.full(3 * E**3, -1, np.int64)
    face_index[face_slots] = np.arange(len(face_slots))
    exists = np.stack([i[0] < B, j[1] < B, k[2] < B])
    kind = np.where(own, 1, np.where(exists, 2, 0)).astype(np.int8).reshape(-1)
    return _EdgeTables(delta[table].astype(np.int32), ntri, own, kind, face_slots, face_index)


_GHOSTS = []
for _code in range(1, 8):
    _o = ((_code >> 2) & 1, (_code >> 1) & 1, _code & 1)  # (dz, dy, dx)
    _dst = tuple(slice(BLOCK, BLOCK + 1) if d else slice(0, BLOCK) for d in _o)
    _src = tuple(slice(0, 1) if d else slice(0, BLOCK) for d in _o)
    _GHOSTS.append((_code, _dst, _src))


@dataclass
class _Chunk:
    """Marching-cubes output of a run of blocks, vertex ids local to the chunk."""

    blk: np.ndarray  # (v,) active block of each vertex (refinement uses its Gaussians)
    axis: np.ndarray  # (v,) edge axis 0..2 (x, y, z)
    node: np.ndarray  # (v, 3) uint8 lower node (x y z) within the block ``blk``: 0 .. BLOCK
    t: np.ndarray  # (v,) initial edge parameter
    curv: np.ndarray  # (v,) d^2 f / dt^2 along the edge (t: the edge parameter), estimated from node values, or NaN
    a_above: np.ndarray  # (v,) lower node above the level
    faces: np.ndarray  # (T, 3) >= 0: local vertex; < 0: -(1 + reference)
    ref_owner: np.ndarray  # (r,) int32 active block owning the edge, or -1 (duplicate vertex in this chunk)
    ref_slot: np.ndarray  # (r,) int32 the owner's face slot (index into face_slots), or the local duplicate vertex
    ref_shift: np.ndarray  # (r, 3) int8 periodic shift in box lengths (0 or 1)
    n_owned: int
    dup_key: np.ndarray  # (d,) wrapped global edge key of duplicate vertices (local ids n_owned..)
    dup_shift: np.ndarray  # (d, 3)
    face_key: np.ndarray  # (s,) ascending block * len(face_slots) + face slot of owned vertices other blocks may use
    face_vid: np.ndarray  # (s,) int32 their local vertex ids


def _march(values, blocks, grid, level, bl, et, loc=None):
    """Marching cubes over blocks ``bl`` (ascending): owned edges get vertices, edges owned by a
    neighbour become references to its face slot (resolved once every chunk is done).  ``values``
    row ``loc[q]`` holds block q (default: row q)."""
    count = native.kernel("blobby_march_count", None, [ctypes.c_int64, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p])
    if count is not None and len(bl):
        return _march_c(count, values, blocks, grid, level, bl, et, loc)
    B, E = BLOCK, BLOCK + 1
    n = len(bl)
    lvl = _F32(level)
    row = (lambda q: q) if loc is None else (lambda q: loc[q])
    ext = np.empty((n, E, E, E), _F32)
    ext[:, :B, :B, :B] = np.take(values, row(bl), axis=0)
    for code, dst, src in _GHOSTS:
        nb = blocks.nbr[bl, code]
        got = values[(row(np.maximum(nb, 0)),) + src]
        # A node of an inactive block: its sign is its block's class; the value is only a first guess.
        guess = np.where(nb == -2, _F32(2) * lvl, _F32(0))[:, None, None, None]
        ext[(slice(None),) + dst] = np.where((nb >= 0)[:, None, None, None], got, guess)
    # Node signs in one flat run (padded): a neighbour along x, y, z is 1, E, E^2 further on, so
    # the edge and cell tests are whole-run operations; where they pair nodes of different rows
    # (x at i = B, ...) the edge does not exist (et.kind 0) or the cell is not read.
    N = n * E**3
    run = np.zeros(N + 1 + E + E * E, bool)
    np.greater_equal(ext.reshape(-1), lvl, out=run[:N])
    cut = np.empty((n, 3, E**3), bool)
    for a, d in enumerate((1, E, E * E)):
        np.not_equal(run[:N].reshape(n, E**3), run[d : N + d].reshape(n, E**3), out=cut[:, a])
    at = np.flatnonzero(cut)
    kind = et.kind[at % (3 * E**3)]
    own = at[kind == 1]
    ghost = at[kind == 2]
    lut = np.empty(n * 3 * E**3, np.int32)
    lut[own] = np.arange(len(own))
    lut[ghost] = -1 - np.arange(len(ghost))
    # Owned vertices on a lower face, by (block, face slot): ascending, since own is.
    fi = et.face_index[own % (3 * E**3)]
    on_face = np.flatnonzero(fi >= 0)
    face_key = bl[own[on_face] // (3 * E**3)] * len(et.face_slots) + fi[on_face]

    # Own vertices: edge ends read from the extended block.
    vb, rest = np.divmod(own, 3 * E**3)
    vax, rest_own = np.divmod(rest, E**3)
    rest = rest_own
    flat = ext.reshape(-1)
    va = flat[vb * E**3 + rest]
    vz = flat[vb * E**3 + rest + np.array([1, E, E * E])[vax]]
    vk, rest = np.divmod(rest, E * E)
    vj, vi = np.divmod(rest, E)
    vijk = np.stack([vi, vj, vk], axis=1)
    vcoord = vijk[np.arange(len(vax)), vax]

    # Ghost edges: owned by a neighbour (refer to its face store) or, if it is inactive, by nobody.
    gb, rest = np.divmod(ghost, 3 * E**3)
    gax, rest = np.divmod(rest, E**3)
    gk, rest = np.divmod(rest, E * E)
    gj, gi = np.divmod(rest, E)
    code = 4 * (gk == B) + 2 * (gj == B) + (gi == B)
    owner = blocks.nbr[bl[gb], code]
    ref_slot = et.face_index[((gax * E + gk % B) * E + gj % B) * E + gi % B]
    shift = np.zeros((len(ghost), 3), np.int64)
    if grid.box is not None:
        off = np.stack([gi == B, gj == B, gk == B], axis=1)
        shift = (blocks.q[bl[gb]] + off >= grid.nb).astype(np.int64)
    dup = np.flatnonzero(owner < 0)
    n_owned = len(own)
    dup_key = np.zeros(0, np.int64)
    dup_shift = np.zeros((0, 3), np.int64)
    vblk, vaxis, vnode = bl[vb], vax, vijk
    if len(dup):
        # A vertex of our own, merged with its twins from other blocks by key at the end.
        dlocal = np.stack([gi[dup], gj[dup], gk[dup]], axis=1)
        dnode = blocks.q[bl[gb[dup]]] * B + dlocal
        wrapped = dnode if grid.box is None else dnode % (B * grid.nb)
        dup_key = _edge_key(wrapped, gax[dup], blocks)
        dup_shift = shift[dup]
        dflat = gb[dup] * E**3 + (gk[dup] * E + gj[dup]) * E + gi[dup]
        va = np.concatenate([va, flat[dflat]])
        vz = np.concatenate([vz, flat[dflat + np.array([1, E, E * E])[gax[dup]]]])
        vblk = np.concatenate([vblk, bl[gb[dup]]])
        vaxis = np.concatenate([vax, gax[dup]])
        vnode = np.concatenate([vijk, dlocal])
        ref_slot[dup] = n_owned + np.arange(len(dup))

    bits = run.view(np.uint8)
    bits = bits[:-1] | (bits[1:] << 1)
    bits = bits[:-E] | (bits[E:] << 2)
    bits = bits[: -E * E] | (bits[E * E :] << 4)
    cfg = bits[:N].reshape(n, E, E, E)[:, :B, :B, :B].reshape(-1)
    cells = np.flatnonzero(cfg + np.uint8(1) > 1).astype(np.int32)  # not 0 or 255 (n 8^3 < 2^31: int32 indices)
    c = cfg[cells].astype(np.int32)
    counts = et.ntri[c]
    cb, rest = np.divmod(cells, B**3)
    ck, rest = np.divmod(rest, B * B)
    cj, ci = np.divmod(rest, B)
    # Triangle j of a cell of configuration c is row 5 c + j of the table.
    row = np.arange(int(counts.sum())) + np.repeat(5 * c - (np.cumsum(counts) - counts), counts)
    idx = np.take(et.table.reshape(-1, 3), row, axis=0)  # (np.take: 3x faster on rows than indexing)
    idx += np.repeat(cb * 3 * E**3 + (ck * E + cj) * E + ci, counts)[:, None]
    faces = np.take(lut, idx)

    va64 = va.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (level - va64) / (vz.astype(np.float64) - va64)
    t = np.clip(np.where(np.isfinite(t), t, 0.5), EDGE_MARGIN, 1 - EDGE_MARGIN)
    t_own, curv = _edge_guess(flat, vb * E**3 + rest_own, vax, vcoord, blocks.nbr[bl[vb], 1 << vax] >= 0, level, t[:n_owned])
    t[:n_owned] = t_own
    curv = np.concatenate([curv, np.full(len(t) - n_owned, np.nan)]).astype(_F32)
    return _Chunk(
        vblk.astype(np.int32), vaxis.astype(np.int8), vnode.astype(np.uint8), t, curv, va >= lvl, faces,
        np.where(owner < 0, -1, owner).astype(np.int32), ref_slot.astype(np.int32), shift.astype(np.int8), n_owned, dup_key,
        dup_shift, face_key, on_face.astype(np.int32),
    )


_CHUNK_FIELDS = (  # the _Chunk arrays the march kernel writes (in struct march_out's order): dtype, row shape, size
    ("blk", np.int32, (), "v"), ("axis", np.int8, (), "v"), ("node", np.uint8, (3,), "v"), ("t", np.float64, (), "v"),
    ("curv", _F32, (), "v"), ("a_above", np.bool_, (), "v"), ("faces", np.int32, (3,), "tri"),
    ("ref_owner", np.int32, (), "ghost"), ("ref_slot", np.int32, (), "ghost"), ("ref_shift", np.int8, (3,), "ghost"),
    ("dup_key", np.int64, (), "dup"), ("dup_shift", np.int64, (3,), "dup"), ("face_key", np.int64, (), "face"),
    ("face_vid", np.int32, (), "face"),
)


def _march_c(count, values, blocks, grid, level, bl, et, loc):
    """:func:`_march` by the compiled kernel (native/src/blobby_march.c): one pass counts, the next writes."""
    emit = native.kernel("blobby_march_emit", None, [ctypes.c_int64, ctypes.c_double, ctypes.c_double, ctypes.c_int64]
                         + [ctypes.c_void_p] * 3)
    ext = np.empty((len(bl), (BLOCK + 1) ** 3), _F32)  # scratch: the blocks' extended nodes
    # struct march_in, in its order (int64 but values, table and kind)
    held = [x if x is None else np.ascontiguousarray(x) for x in (
        bl.astype(np.int64), values, None if loc is None else loc.astype(np.int64), blocks.nbr, blocks.q,
        None if grid.box is None else grid.nb.astype(np.int64), blocks.node_lo, blocks.node_dims, et.table, et.ntri,
        et.kind, et.face_index, ext)]
    march_in = (ctypes.c_void_p * len(held))(*(x if x is None else x.ctypes.data for x in held))
    n = np.zeros(5, np.int64)  # owned vertices, ghost edges, duplicates, triangles, face vertices
    count(len(bl), level, march_in, n.ctypes.data)
    size = {"v": n[0] + n[2], "ghost": n[1], "dup": n[2], "tri": n[3], "face": n[4]}
    out = {name: np.empty((int(size[k]),) + shape, dt) for name, dt, shape, k in _CHUNK_FIELDS}
    march_out = (ctypes.c_void_p * len(out))(*(x.ctypes.data for x in out.values()))
    emit(len(bl), level, EDGE_MARGIN, len(et.face_slots), march_in, n.ctypes.data, march_out)
    return _Chunk(n_owned=int(n[0]), **out)


def _edge_guess(flat, at, axis, coord, beyond_real, level, t):
    """A vertex's edge parameter from the cubic (or, at a block's edge, quadratic) through the node values
    along its edge, and that polynomial's second derivative d^2 f / dt^2 there (NaN where the
    nodes needed are not all computed).  ``at``: the lower node's index in ``flat``; ``coord`` its
    coordinate along the edge within the block; ``beyond_real``: the next block along the edge is active."""
    B, E = BLOCK, BLOCK + 1
    stride = np.array([1, E, E * E])[axis]
    up1 = (coord + 1 < B) | beyond_real
    has_m = coord >= 1
    has_p2 = (coord + 2 < B) | ((coord + 2 == B) & beyond_real)
    ok = up1 & (has_m | has_p2)
    fm = flat[np.where(has_m, at - stride, at)]
    f0 = flat[at]
    f1 = flat[at + stride]
    f2 = flat[np.where(has_p2, at + 2 * stride, at)]
    # p(t) = c0 + c1 t + c2 t^2 + c3 t^3 through nodes -1, 0, 1, 2 (or the three of them there are), float32.
    c0 = f0 - _F32(level)
    c2 = np.where(has_m, _F32(0.5) * (fm + f1) - f0, _F32(0.5) * (f0 + f2) - f1)
    c3 = np.where(has_m & has_p2, (f2 - fm) / _F32(6) + _F32(0.5) * (f0 - f1), _F32(0))
    c1 = f1 - f0 - c2 - c3
    # One Newton step on p from the linear guess: its error (~0.1 edge) drops to ~1e-3, below what
    # the projection's first Newton step needs to settle.
    t0 = t.astype(_F32)
    dp = c1 + t0 * (2 * c2 + 3 * t0 * c3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.clip(t0 - (c0 + t0 * (c1 + t0 * (c2 + t0 * c3))) / dp, _F32(EDGE_MARGIN), _F32(1 - EDGE_MARGIN))
    ok &= dp * (f1 - f0) > 0  # p rises where the field does (NaN: False)
    return np.where(ok, t1, t), np.where(ok, 2 * c2 + 6 * t1 * c3, np.nan)


def _edge_key(node, axis, blocks):
    """One integer per grid edge (axis, node), nodes numbered over the block index's range."""
    n = node - blocks.node_lo
    dims = blocks.node_dims
    return ((axis * dims[2] + n[:, 2]) * dims[1] + n[:, 1]) * dims[0] + n[:, 0]


class _Refiner:
    """Field, gradient and most-contributing Gaussian at points, from a block's Gaussian list.

    Per (block, Gaussian) pair the exponent is a quadratic in the point's offset
    ``u`` from the block's first node: 10 coefficients, so a batch of blocks
    with the same number of Gaussians is one batched matrix product; a second
    one sums ``e_g [A_g, A_g r_g, 1]``: the gradient and the field.  The
    coefficients are made per batch (:meth:`gather`).
    """

    BUDGET = 1 << 18  # (vertex, Gaussian) products per batch
    PAD = 1.2  # vertex counts of a batch's blocks within this factor: little padding
    SMALL = BUDGET // 16  # bands with fewer products merge (per number of Gaussians): a batch costs ~1 ms however small

    def __init__(self, b, grid, blocks):
        self.b, self.blocks = b, blocks
        self.count = np.diff(blocks.fine_start)
        self.x0 = blocks.q * grid.size

    def batches(self, blk, order):
        """Vertices ``order`` (sorted by their block in ``blk``) in padded batches ``(vid (nbt, vmax),
        nv (nbt,), ub (nbt,))`` of blocks with the same number of Gaussians and similar vertex counts."""
        if len(order) == 0:
            return []
        blk = blk[order]
        first = np.flatnonzero(np.r_[True, blk[1:] != blk[:-1]])
        nv = np.diff(np.r_[first, len(blk)])
        ub = blk[first]
        ng = self.count[ub]
        band = np.floor(np.log(nv) / np.log(self.PAD)).astype(np.int64)
        for merge in (True, False):
            by = np.lexsort((nv, band, ng))
            cuts = np.flatnonzero(np.diff(ng[by]) | np.diff(band[by])) + 1
            if merge:
                ends = np.r_[cuts, len(by)]
                size = np.diff(np.r_[0, ends]) * nv[by[ends - 1]] * ng[by[ends - 1]]
                small = np.repeat(size < self.SMALL, np.diff(np.r_[0, ends]))
                band[by[small]] = -1
        out = []
        for grp in np.split(by, cuts):
            lo = 0
            while lo < len(grp):  # (ascending vertex counts: a batch's last block has the most)
                padded = np.arange(1, len(grp) - lo + 1) * nv[grp[lo:]] * ng[grp[0]]
                sel = grp[lo : lo + max(1, int(np.searchsorted(padded, self.BUDGET, side="right")))]
                vid = first[sel, None] + np.minimum(np.arange(nv[sel[-1]]), nv[sel, None] - 1)
                out.append((order[vid], nv[sel], ub[sel]))
                lo += len(sel)
        return out

    def gather(self, ub):
        """The blocks' Gaussians (nbt, G) (input indices) and their coefficients, ready for :meth:`evaluate`."""
        g = self.blocks.fine_g[self.blocks.fine_start[ub][:, None] + np.arange(int(self.count[ub[0]]))]
        b = self.b
        rel = np.take(b.c, g, axis=0) - self.x0[ub][:, None, :]
        a6 = np.take(b.a, g, axis=0)
        ar = _amul(a6, rel)
        # (nbt, 10, G) contiguous: matmul is some 3x faster on it than on a transposed view.
        coef = np.empty((len(ub), 10, g.shape[1]), _F32)
        coef[:, 0:3] = -0.5 * a6[..., 0:3].transpose(0, 2, 1)
        coef[:, 3:6] = -a6[..., 3:6].transpose(0, 2, 1)
        coef[:, 6:9] = ar.transpose(0, 2, 1)
        coef[:, 9] = b.lnw[g] - 0.5 * np.einsum("...i,...i", rel, ar)
        kern = np.empty(g.shape + (10,), _F32)
        kern[..., 0:6] = a6
        kern[..., 6:9] = ar
        kern[..., 9] = 1
        return b.src[g], coef, kern

    @staticmethod
    def evaluate(u, coef, kern):
        """f (nbt, vmax), grad (nbt, vmax, 3) and the terms e (nbt, vmax, G) at offsets u, float32.

        The gradient ``sum_g e_g A_g (r_g - u)`` is ``m - M u`` from the sums ``sum_g e_g [A_g, A_g r_g]``,
        which the float32 product already rounds: finishing it in float64 would not undo that."""
        feat = np.empty(u.shape[:2] + (10,), _F32)
        np.multiply(u, u, out=feat[..., 0:3])
        x, y, z = u[..., 0], u[..., 1], u[..., 2]
        np.multiply(x, y, out=feat[..., 3])
        np.multiply(x, z, out=feat[..., 4])
        np.multiply(y, z, out=feat[..., 5])
        feat[..., 6:9] = u
        feat[..., 9] = 1
        e = np.exp(feat @ coef)
        m = e @ kern  # sum_g e_g [A_g, A_g r_g, 1]
        x, y, z = feat[..., 6], feat[..., 7], feat[..., 8]  # (u in float32)
        grad = np.empty(u.shape, _F32)
        grad[..., 0] = m[..., 6] - (m[..., 0] * x + m[..., 3] * y + m[..., 4] * z)
        grad[..., 1] = m[..., 7] - (m[..., 3] * x + m[..., 1] * y + m[..., 5] * z)
        grad[..., 2] = m[..., 8] - (m[..., 4] * x + m[..., 5] * y + m[..., 2] * z)
        return m[..., 9], grad, e


def _compact(live, per_vertex, per_row):
    """The live entries of a padded (rows, vmax) layout, packed to the front of their rows
    (padding repeats a row's first live entry); rows without any are dropped."""
    bi, vi = np.nonzero(live)
    first = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
    cnt = np.diff(np.r_[first, len(bi)])
    src = first[:, None] + np.minimum(np.arange(cnt.max()), cnt[:, None] - 1)
    sb, sv = bi[src], vi[src]
    valid = np.arange(src.shape[1]) < cnt[:, None]
    return valid, [a[sb, sv] for a in per_vertex], [a[bi[first]] for a in per_row]


def _rows(a):
    """A contiguous (n, k) array as (n,) opaque k-item records: NumPy scatters those by index with one
    copy per record, some 2x faster than rows of a 2-D array (6M rows of 3 float32: 29 ms against 62).
    (Gathers: ``np.take(a, idx, axis=0)`` is as fast: 1.5M rows of 3 float64, 9 ms against 32.)"""
    return a.view(np.dtype((np.void, a.shape[1] * a.itemsize))).reshape(len(a))


def _project(refiner, grid, blk, axis, node, t, curv, a_above, level, tol, threads):
    """Slide vertices along their edges onto f = level: Newton steps, bisection when one leaves the bracket.

    A vertex is done when its first-order distance is below ``tol``, or after a Newton step whose
    second-order error, ``|f''| dt^2 / 2`` with ``f''`` the node values' estimate ``curv``, is below
    a quarter of it: then its normal and Gaussian come from the point the step started from.

    Every vertex is evaluated once, in batches of blocks (:meth:`_Refiner.batches`), and written;
    the few still moving (with their edge parameters and brackets, in arrays of their own) are batched
    again and iterate together, packed whenever fewer than half still move, and written again when
    done.  Returns positions (float32), unit normals (float32, from the analytic gradient), where the
    gradient vanished, and the most-contributing Gaussian.  The compiled kernel, where installed, does
    the same per vertex in float64 (:func:`_project_c`).
    """
    kernel = _project_kernel()
    if kernel is not None:
        return _project_c(kernel, refiner, grid, blk, axis, node, t, curv, a_above, level, tol, threads)
    n = len(t)
    pos = np.empty((n + 1, 3), _F32)  # row n: where padding is written
    normal = np.empty((n + 1, 3), _F32)
    flat = np.empty(n + 1, bool)
    arg = np.empty(n + 1, np.int32)
    pos_rows, normal_rows = _rows(pos), _rows(normal)

    def setup(vid, ub):
        ax = axis[vid]
        # (a row of vid holds vertices of block ub only: its coordinates broadcast, not gathered per vertex)
        base = grid.coords(refiner.blocks.q[ub][:, None, :] * BLOCK + np.take(node, vid, axis=0))
        u0 = base - refiner.x0[ub][:, None, :]
        along = np.arange(0, u0.size, 3) + ax.reshape(-1)  # the edge's coordinate in (..., 3) rows
        # ab: f - level >= 0 at the lower node
        return ax, base, u0, along, grid.h[ax], a_above[vid], np.abs(curv[vid])

    def evaluate(u0, along, tt, st, coef, kern, keep=True):
        """The field at offsets ``u0`` moved ``tt`` along the edges (``keep=False``: in place)."""
        u = u0.copy() if keep else u0
        u.reshape(-1)[along] += (tt * st).reshape(-1)
        f, g, e = refiner.evaluate(u, coef, kern)
        return f, g, np.sqrt(np.einsum("...i,...i", g, g)), e

    def step(f, g, gn, valid, tt, lo, hi, ab, cv, along, st):
        """Newton (or bisection) along the edge: (the position to write, the next one, still moving, lo, hi)."""
        diff = f - level
        slack = tol * np.maximum(gn, 1e-300)
        go = valid & (np.abs(diff) >= slack)
        side = (diff > 0) == ab  # still on the lower node's side
        lo = np.where(go & side, tt, lo)
        hi = np.where(go & ~side, tt, hi)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            new = tt - diff / (g.reshape(-1)[along].reshape(tt.shape) * st)
        good = (new > lo) & (new < hi)  # False for NaN
        new = np.clip(np.where(good, new, 0.5 * (lo + hi)), EDGE_MARGIN, 1 - EDGE_MARGIN)
        # (and a short one: the normal comes from where the step starts)
        settled = good & (2 * cv * (new - tt) ** 2 < slack) & (np.abs(new - tt) * st < SETTLE_STEP * tol)  # False for NaN
        return np.where(go & settled, new, tt), new, go & (new != tt) & ~settled, lo, hi

    def write(ids, p, g, gn, best):
        """Outputs of vertices ``ids`` (rows of the other arguments)."""
        pos_rows[ids] = _rows(p.astype(_F32))
        np.divide(g, np.where(gn > 0, gn, 1)[:, None], out=g)  # (g: the caller's temporary, contiguous)
        normal_rows[ids] = _rows(np.negative(g, out=g))
        flat[ids] = gn <= 0
        arg[ids] = best

    def first(batch):
        """Evaluate and write every vertex of the batch (its padding to row n); return those still moving
        (their ids, next edge parameters and brackets)."""
        vid, nv, ub = batch
        src, coef, kern = refiner.gather(ub)
        valid = np.arange(vid.shape[1]) < nv[:, None]
        ax, base, u0, along, st, ab, cv = setup(vid, ub)
        tt = t[vid]
        f, g, gn, e = evaluate(u0, along, tt, st, coef, kern, keep=False)
        lo, hi = np.zeros(vid.shape), np.ones(vid.shape)
        final, new, live, lo, hi = step(f, g, gn, valid, tt, lo, hi, ab, cv, along, st)
        best = np.take_along_axis(src, e.argmax(axis=-1), axis=1)
        base.reshape(-1)[along] += (final * st).reshape(-1)
        write(np.where(valid, vid, n).reshape(-1), base.reshape(-1, 3), g.reshape(-1, 3), gn.reshape(-1), best.reshape(-1))
        at = np.flatnonzero(live)
        return vid.reshape(-1)[at], new.reshape(-1)[at], lo.reshape(-1)[at], hi.reshape(-1)[at]

    def rest(batch, left):
        """Iterate the vertices ``left`` (ids, t, lo, hi) at the batch's positions into them until done."""
        at, nv, ub = batch
        vid, tt, lo, hi = (x[at] for x in left)
        src, coef, kern = refiner.gather(ub)
        valid = np.arange(vid.shape[1]) < nv[:, None]
        ax, base, u0, along, st, ab, cv = setup(vid, ub)
        for it in range(1, NEWTON_STEPS + 1):
            f, g, gn, e = evaluate(u0, along, tt, st, coef, kern)
            live = np.zeros(vid.shape, bool)
            final = tt
            if it < NEWTON_STEPS:
                final, new, live, lo, hi = step(f, g, gn, valid, tt, lo, hi, ab, cv, along, st)
            done = np.flatnonzero(valid & ~live)
            best = src[done // vid.shape[1], e.reshape(-1, e.shape[-1])[done].argmax(axis=1)]
            p = base.reshape(-1, 3)[done]
            p[np.arange(len(done)), ax.reshape(-1)[done]] += final.reshape(-1)[done] * st.reshape(-1)[done]
            write(vid.reshape(-1)[done], p, g.reshape(-1, 3)[done], gn.reshape(-1)[done], best)
            if not live.any():
                return
            tt = np.where(live, new, tt)
            if 2 * np.count_nonzero(live) < live.size:
                valid, (vid, ax, base, u0, st, ab, tt, cv, lo, hi), (src, coef, kern) = _compact(
                    live, (vid, ax, base, u0, st, ab, tt, cv, lo, hi), (src, coef, kern))
                along = np.arange(0, u0.size, 3) + ax.reshape(-1)
            else:
                valid = live

    order = np.argsort(blk, kind="stable")  # nearly sorted already: batches read and write short runs
    if n < 2**31:  # (the batches' padded vertex ids, all made at once: half the memory)
        order = order.astype(np.int32)
    left = thread_map(first, refiner.batches(blk, order), threads)
    left = [np.concatenate(x) for x in zip(*left)]
    if left and len(left[0]):
        by = np.argsort(blk[left[0]], kind="stable")
        left = [x[by] for x in left]
        thread_map(lambda bt: rest(bt, left), refiner.batches(blk[left[0]], np.arange(len(by))), threads)
    return pos[:n], normal[:n], flat[:n], arg[:n]


def _project_kernel():
    """native/src/blobby_project.c's ``blobby_project`` with its argument types, or None."""
    i8, u8, b8, i32, i64, f32, f64 = (np.ctypeslib.ndpointer(k, flags="C_CONTIGUOUS")
                                      for k in (np.int8, np.uint8, np.bool_, np.int32, np.int64, np.float32, np.float64))
    n, x = ctypes.c_int64, ctypes.c_double
    return native.kernel("blobby_project", ctypes.c_int, [
        n, i64, i32, i8, u8, f64, f32, b8,  # vertices
        i64, i64, i64, f64, f64, f64, i64, n,  # blocks, Gaussians
        f64, f64, i64, n, x, x, x, x, n,  # grid, rules
        f32, f32, b8, i32])  # outputs


_PROJECT_CHUNK = 1 << 15
"""Vertices per call of the compiled projection (a few ms), handed to the threads as they come free."""


def _project_c(kernel, refiner, grid, blk, axis, node, t, curv, a_above, level, tol, threads):
    """:func:`_project` by the compiled kernel: chunks of the vertices sorted by block (each call gathers a
    block's Gaussians once) on threads."""
    b, blocks, n = refiner.b, refiner.blocks, len(t)
    order = np.argsort(blk, kind="stable").astype(np.int64, copy=False)
    c = np.ascontiguousarray
    periodic = grid.box is not None
    args = (c(blk, np.int32), c(axis, np.int8), c(node, np.uint8), c(t, np.float64), c(curv, _F32), c(a_above, bool),
            c(blocks.q, np.int64), c(blocks.fine_start, np.int64), c(blocks.fine_g, np.int64), c(b.c, np.float64),
            c(b.a, np.float64), c(b.lnw, np.float64), c(b.src, np.int64), int(refiner.count.max()),
            c(grid.h, np.float64), c(grid.box, np.float64) if periodic else np.zeros(3),
            # per axis the node lying at exactly L (periodic), else none
            c(BLOCK * grid.nb, np.int64) if periodic else np.full(3, np.iinfo(np.int64).max),
            BLOCK, level, tol, SETTLE_STEP, EDGE_MARGIN, NEWTON_STEPS)
    out = (np.empty((n, 3), _F32), np.empty((n, 3), _F32), np.empty(n, bool), np.empty(n, np.int32))

    def run(span):
        if kernel(span[1] - span[0], order[span[0] : span[1]], *args, *out):
            raise MemoryError("blobby: no memory for a block's Gaussian columns")

    thread_map(run, _chunks(n, _PROJECT_CHUNK), threads)
    return out


@functools.cache
def _malloc_trim():
    try:
        import ctypes

        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):  # not glibc (Windows: CDLL(None) is a TypeError)
        return None


def _release(big=True):
    """Hand freed heap pages back to the system (glibc's ``malloc_trim``; elsewhere nothing) if ``big``.
    The march's chunk-sized arrays live in malloc's heaps, not in pages of their own: freed while the
    assembled arrays are made, they would stay resident (20,000 bench ellipsoids: 1.3 GiB more at the
    peak).  Pages handed back cost page faults when the heap grows again (5,000 ellipsoids: some 0.6 s
    of 6.2), so only scenes of more than one :data:`MARCH_BATCH` (``big``) release them."""
    trim = _malloc_trim() if big else None
    if trim is not None:
        trim(0)


MARCH_BATCH = 1 << 17
"""Active blocks whose node values are held at once (256 MiB): the march runs batch by batch, each
batch's values made for its blocks and their +1 neighbours (a layer of blocks made twice)."""


def _march_batches(b, grid, blocks, level, threads):
    """Node values and marching cubes, :data:`MARCH_BATCH` active blocks at a time (in key order: slabs
    of block rows).  The chunks are those of one batch of every block: a chunk's output is block by
    block, so cutting the crossed blocks into other runs only moves chunk boundaries, and
    :func:`_assemble` numbers vertices and faces by (block, edge) all the same."""
    et = _edge_tables()
    per = max(1, 512 * 512 // BLOCK**3)
    na = len(blocks.q)
    parts = []
    loc = np.full(na, -1, np.int64) if na > MARCH_BATCH else None
    for a0, a1 in _chunks(na, MARCH_BATCH):
        sel = np.arange(a0, a1)
        if loc is None:
            need = sel
        else:
            nb = blocks.nbr[a0:a1, 1:]
            need = np.union1d(sel, nb[nb >= 0])
            loc[need] = np.arange(len(need))
        values = _node_values(b, grid, blocks, threads, need)
        crossed = _crossed(values, blocks, level, sel, loc)
        runs = [crossed[lo:hi] for lo, hi in _chunks(len(crossed), per)]
        parts += thread_map(functools.partial(_march, values, blocks, grid, level, et=et, loc=loc), runs, threads)
        del values
    if not parts:
        parts = [_march(np.zeros((0, BLOCK, BLOCK, BLOCK), _F32), blocks, grid, level, np.zeros(0, np.int64), et)]
    return parts


def _assemble(parts, nslot, threads, big=False):
    """Global vertex numbering: every chunk's own edges, then one representative per
    duplicated edge; faces refer to vertices, or (negative) to references resolved to
    (base vertex, shift) whose shift is not zero (periodic copies).  The chunks' arrays are
    dropped as they are copied (``parts`` is left holding empty chunks): the march's output
    and the assembled arrays are not held twice."""
    owned = np.array([p.n_owned for p in parts])
    offs = np.concatenate([[0], np.cumsum(owned)])
    n_own = int(offs[-1])
    face_key = np.concatenate([p.face_key for p in parts] + [[-1]])  # ascending; a sentinel at the end
    face_vid = np.concatenate([p.face_vid.astype(np.int64) + offs[ci] for ci, p in enumerate(parts)] + [[-1]])
    ndup = np.array([len(p.t) - p.n_owned for p in parts])
    dup_off = np.concatenate([[0], np.cumsum(ndup)])
    dup_keys = np.concatenate([p.dup_key for p in parts])
    ukey, rep, dup_index = np.unique(dup_keys, return_index=True, return_inverse=True)
    dup_index = dup_index.reshape(-1)

    def field(name):
        cols = [getattr(p, name) for p in parts]
        for p in parts:
            setattr(p, name, None)
        dup = np.concatenate([x[n:] for x, n in zip(cols, owned)])
        out = np.empty((n_own + len(rep),) + cols[0].shape[1:], cols[0].dtype)
        for ci, x in enumerate(cols):
            out[offs[ci] : offs[ci + 1]] = x[: owned[ci]]
            cols[ci] = None
        out[n_own:] = dup[rep]
        del dup
        _release(big)
        return out

    verts = tuple(field(name) for name in ("blk", "axis", "node", "t", "curv", "a_above"))
    rep_shift = np.concatenate([p.dup_shift for p in parts])[rep]

    ntri = np.cumsum([0] + [len(p.faces) for p in parts])
    faces = np.empty((int(ntri[-1]), 3), np.int32)  # (the mesh's type: vertex counts stay far below 2^31)
    nref = np.cumsum([0] + [len(p.ref_owner) for p in parts])

    def refer(ci):
        p = parts[ci]
        act = p.ref_owner >= 0
        base = np.empty(len(act), np.int64)
        own = p.ref_owner[act].astype(np.int64)
        want = own * nslot + p.ref_slot[act]
        at = np.minimum(np.searchsorted(face_key[:-1], want), len(face_key) - 1)
        base[act] = np.where(face_key[at] == want, face_vid[at], -1)
        d = ~act
        base[d] = n_own + dup_index[dup_off[ci] + p.ref_slot[d] - p.n_owned]
        out = faces[ntri[ci] : ntri[ci + 1]]
        np.add(p.faces, int(offs[ci]), out=out)
        neg = np.flatnonzero(p.faces.reshape(-1) < 0)
        r = -1 - p.faces.reshape(-1)[neg]
        shifted = np.any(p.ref_shift != 0, axis=1)
        out.reshape(-1)[neg] = np.where(shifted[r], -1 - (nref[ci] + r), base[r])
        p.faces = p.ref_owner = p.ref_slot = None
        return base

    ref_base = np.concatenate(thread_map(refer, range(len(parts)), threads))
    _release(big)
    if np.any(ref_base < 0):
        raise AssertionError("blobby: a face refers to an edge its owner did not cut")
    return verts, faces, ref_base, np.concatenate([p.ref_shift for p in parts]), rep_shift, n_own


def blobby_surface(
    centers, rotations, sigmas, weights, level, spacing, *, box=None, cutoff=4.0, attributes=None, threads=None
):
    """Triangle mesh of the level set of a sum of Gaussian ellipsoids.

    Parameters
    ----------
    centers : (n, 3) array
        Centres ``c_i``.
    rotations : (n, 3, 3) array
        Rotations ``R_i`` whose columns are the principal axes.
    sigmas : (n, 3) array
        Standard deviations along those axes (positive).
    weights : (n,) array
        Weights ``w_i >= 0``; zero-weight Gaussians are ignored.
    level : float
        Contour value (positive).  A lone Gaussian's surface is the ellipsoid
        of Mahalanobis radius ``sqrt(2 ln(w / level))``.
    spacing : float
        Grid spacing (sigma_min / 4 gives vertices about every quarter sigma).
    box : (3,) floats, optional
        Periodic box ``(Lx, Ly, Lz)``: every image counts and the mesh is the
        part in ``[0, L)``, with vertices on opposite faces exactly ``L`` apart.
        The grid spacing is then ``L / N`` with ``N`` the smallest multiple of
        :data:`BLOCK` giving at most ``spacing``.
    cutoff : float
        Each Gaussian is summed on the grid within ``cutoff`` sigma
        (Mahalanobis distance); vertices are projected onto the sum cut at
        ``cutoff + 1`` sigma, whose error is below ``exp(-(cutoff+1)^2 / 2)``
        of a weight per Gaussian left out.
    attributes : dict of str to (n,) arrays, optional
        Per-Gaussian values (molecule or part ids, colours) copied to every
        vertex from its most-contributing Gaussian.
    threads : int, optional
        Worker threads (default: :func:`~nephele.core.threads.default_threads`).

    Returns
    -------
    Mesh
        float32 vertices, counter-clockwise triangles seen from outside
        (normals point where the field falls), unit normals from the analytic
        gradient, attribute ``"blob"`` (int32, index of the Gaussian that
        contributes most at the vertex) and the ``attributes`` given.
        ``Mesh.empty`` when nothing reaches the level.

    References
    ----------
    .. [1] J. F. Blinn, "A generalization of algebraic surface drawing", ACM TOG 1(3), 1982.
    .. [2] W. E. Lorensen and H. E. Cline, "Marching cubes", SIGGRAPH 1987.
    .. [3] N. Max and R. Crawfis, "Advances in Scientific Visualization".
    """
    c, r, s, w = _check(centers, rotations, sigmas, weights)
    level = _positive(level, "level")
    spacing = _positive(spacing, "spacing")
    cutoff = _positive(cutoff, "cutoff")
    attributes = {str(k): np.asarray(v) for k, v in dict(attributes or {}).items()}
    for name, a in attributes.items():
        if a.shape[:1] != (len(c),):
            raise DataError(f"needs one value per Gaussian ({len(c)}), got shape {a.shape}", field=name)
    names = ["blob", *attributes]
    if box is not None:
        box = _check_box(box)
    threads = default_threads() if threads is None else max(1, int(threads))

    b = _blobs(c, r, s, w)
    if len(b.c) == 0:
        return Mesh.empty(names)
    fine = cutoff + REFINE_EXTRA
    if box is not None:
        b = _images(b, box, fine)
    grid = _grid(spacing, box)
    # (block, Gaussian) pairs, each Gaussian reaching over its cut-off box; 80-230 bytes per pair at the peak
    # (tracemalloc: 500-2,000 random ellipsoids, spacing 0.025-0.05 sigma-widths).
    pairs = float(np.sum((2 * fine * s.max(axis=1) / (spacing * BLOCK) + 1) ** 3))
    check_memory(256 * pairs, f"a blobby surface of {len(c):,} Gaussians at spacing {spacing:g}",
                 hint="raise the spacing or mesh fewer Gaussians", field="spacing")
    blocks = _find_blocks(b, grid, level, cutoff, fine, threads)
    if blocks is None:
        return Mesh.empty(names)
    big = len(blocks.q) > MARCH_BATCH
    _release(big)  # (the pair search's temporaries)
    parts = _march_batches(b, grid, blocks, level, threads)
    verts, faces, ref_base, ref_shift, rep_shift, n_own = _assemble(parts, len(_edge_tables().face_slots), threads, big)
    del parts

    smin = float(s[w > 0].min())
    refiner = _Refiner(b, grid, blocks)
    pos, normals, flat, arg = _project(refiner, grid, *verts, level, NEWTON_TOL * smin, threads)
    del verts
    _release(big)
    if grid.box is not None and len(rep_shift):
        # Representatives of duplicates were placed in their block's frame (a coordinate
        # across the seam exactly L): move them to the box's own frame (exactly 0).
        pos[n_own:] -= (rep_shift * grid.box).astype(_F32)  # (float32: L - L is exactly 0)

    # Periodic copies of seam vertices, one per (vertex, shift).
    final = ref_base.copy()
    moved = np.flatnonzero(np.any(ref_shift != 0, axis=1))
    if len(moved):
        key = ref_base[moved] * 27 + (ref_shift[moved] + 1) @ np.array([1, 3, 9])
        ukey, first, inv = np.unique(key, return_index=True, return_inverse=True)
        src = ref_base[moved][first]
        final[moved] = len(pos) + inv.reshape(-1)
        pos = np.concatenate([pos, pos[src] + (ref_shift[moved][first] * grid.box).astype(_F32)])
        normals = np.concatenate([normals, normals[src]])
        flat = np.concatenate([flat, flat[src]])
        arg = np.concatenate([arg, arg[src]])
    neg = faces < 0
    faces[neg] = final[-1 - faces[neg]]

    vertices = pos
    if flat.any():
        normals[flat] = vertex_normals(vertices, faces)[flat]
    attrs = {"blob": arg.astype(np.int32, copy=False)}
    attrs.update({k: v[arg] for k, v in attributes.items()})
    return Mesh(vertices, faces, normals, attrs)

