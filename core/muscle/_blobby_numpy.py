"""The NumPy twins of the blobby kernels: whole-array NumPy doing what ``native/src/blobby_*.c`` do.

They run where the ``nephele_native`` wheel is missing (or with ``NEPHELE_NATIVE=0``); the
tests compare them with the compiled kernels (:mod:`._blobby_c`) to the tolerances
tests/core/muscle states.  The algorithm that calls one or the other is :mod:`.blobby`.

References
----------
.. [1] W. E. Lorensen and H. E. Cline, "Marching cubes", SIGGRAPH 1987.
.. [2] J. F. Blinn, "A generalization of algebraic surface drawing",
   ACM Transactions on Graphics 1(3), 235-256 (1982).
"""

import numpy as np

from ..surface.contour import EDGE_MARGIN
from ..threads import thread_map
from ._blobby_base import _F32, _GHOSTS, BLOCK, NEWTON_STEPS, SETTLE_STEP, _amul, _Chunk, _chunks, _quad

_EXP_MAX = _F32(40.0)
"""Largest exponent of one of the three float32 factors (two of them multiply below exp(88.7), the overflow)."""


def _block_pairs_run(b, lo, cnt, tot, ra, size, index, cut, cut_fine, span):
    """The candidate pairs of the Gaussians ``span`` (start, stop): ``(key, g, on_grid, upper, lower)``
    (see :func:`.blobby._block_pairs`)."""
    start, stop = span
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


def _group_pairs(slot, cls, g, on_grid, na):
    """The pairs' Gaussians ``g`` listed by active block ``cls[slot]`` (the others dropped), in pair
    order: (fine_start, fine_g, grid_start, grid_g (on-grid pairs only), first pair of each block)."""
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


def _node_values(b, grid, blocks, threads, act=None):
    """Values of the active blocks ``act`` (default: all) at their own BLOCK^3 nodes, float32
    (len(act), B, B, B) in (k, j, i) order.  A block's values are the same bits in any subset: every
    operation is elementwise per (block, Gaussian) pair, summed in the block's own Gaussian order."""
    B = BLOCK
    act = np.arange(len(blocks.q)) if act is None else act
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


def _march(values, blocks, grid, level, bl, et, loc=None):
    """Marching cubes over blocks ``bl`` (ascending): owned edges get vertices, edges owned by a
    neighbour become references to its face slot (resolved once every chunk is done).  ``values``
    row ``loc[q]`` holds block q (default: row q)."""
    E = BLOCK + 1
    ext = _extended(values, blocks, level, bl, loc)
    run, own, ghost = _cut_edges(ext, et, level)
    n = len(bl)
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
    flat = ext.reshape(-1)
    va = flat[vb * E**3 + rest_own]
    vz = flat[vb * E**3 + rest_own + np.array([1, E, E * E])[vax]]
    vk, rest = np.divmod(rest_own, E * E)
    vj, vi = np.divmod(rest, E)
    vijk = np.stack([vi, vj, vk], axis=1)
    vcoord = vijk[np.arange(len(vax)), vax]

    g = _ghost_edges(ghost, blocks, grid, bl, et, len(own))
    vblk, vaxis, vnode = bl[vb], vax, vijk
    if len(g["dup"]):  # vertices of our own, merged with their twins from other blocks by key at the end
        va = np.concatenate([va, flat[g["dflat"]]])
        vz = np.concatenate([vz, flat[g["dflat"] + np.array([1, E, E * E])[g["dax"]]]])
        vblk = np.concatenate([vblk, g["dblk"]])
        vaxis = np.concatenate([vax, g["dax"]])
        vnode = np.concatenate([vijk, g["dlocal"]])
    faces = _cell_faces(run, et, lut, n)

    n_owned = len(own)
    lvl = _F32(level)
    va64 = va.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (level - va64) / (vz.astype(np.float64) - va64)
    t = np.clip(np.where(np.isfinite(t), t, 0.5), EDGE_MARGIN, 1 - EDGE_MARGIN)
    t_own, curv = _edge_guess(
        flat, vb * E**3 + rest_own, vax, vcoord, blocks.nbr[bl[vb], 1 << vax] >= 0, level, t[:n_owned]
    )
    t[:n_owned] = t_own
    curv = np.concatenate([curv, np.full(len(t) - n_owned, np.nan)]).astype(_F32)
    return _Chunk(
        vblk.astype(np.int32), vaxis.astype(np.int8), vnode.astype(np.uint8), t, curv, va >= lvl, faces,
        np.where(g["owner"] < 0, -1, g["owner"]).astype(np.int32), g["ref_slot"].astype(np.int32),
        g["shift"].astype(np.int8), n_owned, g["dup_key"], g["dup_shift"], face_key, on_face.astype(np.int32),
    )


def _extended(values, blocks, level, bl, loc):
    """The blocks ``bl``'s node values with the +1 layer read from their neighbours, ``(n, E, E, E)``."""
    B, E = BLOCK, BLOCK + 1
    lvl = _F32(level)
    row = (lambda q: q) if loc is None else (lambda q: loc[q])
    ext = np.empty((len(bl), E, E, E), _F32)
    ext[:, :B, :B, :B] = np.take(values, row(bl), axis=0)
    for code, dst, src in _GHOSTS:
        nb = blocks.nbr[bl, code]
        got = values[(row(np.maximum(nb, 0)),) + src]
        # A node of an inactive block: its sign is its block's class; the value is only a first guess.
        guess = np.where(nb == -2, _F32(2) * lvl, _F32(0))[:, None, None, None]
        ext[(slice(None),) + dst] = np.where((nb >= 0)[:, None, None, None], got, guess)
    return ext


def _cut_edges(ext, et, level):
    """Node signs as one padded run, and the cut edges the block owns and those a neighbour owns
    (flat indices ``(block, axis, node)`` over ``3 E^3`` slots per block)."""
    E = BLOCK + 1
    n = len(ext)
    # Node signs in one flat run (padded): a neighbour along x, y, z is 1, E, E^2 further on, so
    # the edge and cell tests are whole-run operations; where they pair nodes of different rows
    # (x at i = B, ...) the edge does not exist (et.kind 0) or the cell is not read.
    N = n * E**3
    run = np.zeros(N + 1 + E + E * E, bool)
    np.greater_equal(ext.reshape(-1), _F32(level), out=run[:N])
    cut = np.empty((n, 3, E**3), bool)
    for a, d in enumerate((1, E, E * E)):
        np.not_equal(run[:N].reshape(n, E**3), run[d : N + d].reshape(n, E**3), out=cut[:, a])
    at = np.flatnonzero(cut)
    kind = et.kind[at % (3 * E**3)]
    return run, at[kind == 1], at[kind == 2]


def _ghost_edges(ghost, blocks, grid, bl, et, n_owned):
    """Ghost edges: owned by a neighbour (refer to its face store) or, if it is inactive, by nobody
    (a vertex of the chunk's own, ``dup``, after the ``n_owned`` owned ones)."""
    B, E = BLOCK, BLOCK + 1
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
    out = {"owner": owner, "shift": shift, "ref_slot": ref_slot, "dup": dup, "dup_key": np.zeros(0, np.int64),
           "dup_shift": np.zeros((0, 3), np.int64)}
    if len(dup):
        ref_slot[dup] = n_owned + np.arange(len(dup))
        dlocal = np.stack([gi[dup], gj[dup], gk[dup]], axis=1)
        dnode = blocks.q[bl[gb[dup]]] * B + dlocal
        wrapped = dnode if grid.box is None else dnode % (B * grid.nb)
        out.update(dup_key=_edge_key(wrapped, gax[dup], blocks), dup_shift=shift[dup], dlocal=dlocal,
                   dflat=gb[dup] * E**3 + (gk[dup] * E + gj[dup]) * E + gi[dup], dblk=bl[gb[dup]], dax=gax[dup])
    return out


def _cell_faces(run, et, lut, n):
    """The triangles of every cell of the ``n`` blocks: table rows of each cell's configuration,
    corners mapped through ``lut`` (vertex ids, or ``-1 - ghost`` references)."""
    B, E = BLOCK, BLOCK + 1
    N = n * E**3
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
    return np.take(lut, idx)


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
    the same per vertex in float64 (:func:`._blobby_c._project_c`).
    """
    pj = _Projection(refiner, grid, axis, node, t, curv, a_above, level, tol)
    n = len(t)
    order = np.argsort(blk, kind="stable")  # nearly sorted already: batches read and write short runs
    if n < 2**31:  # (the batches' padded vertex ids, all made at once: half the memory)
        order = order.astype(np.int32)
    left = thread_map(pj.first, refiner.batches(blk, order), threads)
    left = [np.concatenate(x) for x in zip(*left)]
    if left and len(left[0]):
        by = np.argsort(blk[left[0]], kind="stable")
        left = [x[by] for x in left]
        thread_map(lambda bt: pj.rest(bt, left), refiner.batches(blk[left[0]], np.arange(len(by))), threads)
    return pj.pos[:n], pj.normal[:n], pj.flat[:n], pj.arg[:n]


class _Projection:
    """The steps of :func:`_project`: its outputs (row ``n`` takes the batches' padding) and the per-batch work."""

    def __init__(self, refiner, grid, axis, node, t, curv, a_above, level, tol):
        self.refiner, self.grid, self.level, self.tol = refiner, grid, level, tol
        self.axis, self.node, self.t, self.curv, self.a_above = axis, node, t, curv, a_above
        n = self.n = len(t)
        self.pos = np.empty((n + 1, 3), _F32)  # row n: where padding is written
        self.normal = np.empty((n + 1, 3), _F32)
        self.flat = np.empty(n + 1, bool)
        self.arg = np.empty(n + 1, np.int32)
        self.pos_rows, self.normal_rows = _rows(self.pos), _rows(self.normal)

    def setup(self, vid, ub):
        ax = self.axis[vid]
        # (a row of vid holds vertices of block ub only: its coordinates broadcast, not gathered per vertex)
        base = self.grid.coords(self.refiner.blocks.q[ub][:, None, :] * BLOCK + np.take(self.node, vid, axis=0))
        u0 = base - self.refiner.x0[ub][:, None, :]
        along = np.arange(0, u0.size, 3) + ax.reshape(-1)  # the edge's coordinate in (..., 3) rows
        # ab: f - level >= 0 at the lower node
        return ax, base, u0, along, self.grid.h[ax], self.a_above[vid], np.abs(self.curv[vid])

    def evaluate(self, u0, along, tt, st, coef, kern, keep=True):
        """The field at offsets ``u0`` moved ``tt`` along the edges (``keep=False``: in place)."""
        u = u0.copy() if keep else u0
        u.reshape(-1)[along] += (tt * st).reshape(-1)
        f, g, e = self.refiner.evaluate(u, coef, kern)
        return f, g, np.sqrt(np.einsum("...i,...i", g, g)), e

    def step(self, f, g, gn, valid, tt, lo, hi, ab, cv, along, st):
        """Newton (or bisection) along the edge: (the position to write, the next one, still moving, lo, hi)."""
        diff = f - self.level
        slack = self.tol * np.maximum(gn, 1e-300)
        go = valid & (np.abs(diff) >= slack)
        side = (diff > 0) == ab  # still on the lower node's side
        lo = np.where(go & side, tt, lo)
        hi = np.where(go & ~side, tt, hi)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            new = tt - diff / (g.reshape(-1)[along].reshape(tt.shape) * st)
        good = (new > lo) & (new < hi)  # False for NaN
        new = np.clip(np.where(good, new, 0.5 * (lo + hi)), EDGE_MARGIN, 1 - EDGE_MARGIN)
        # (and a short one: the normal comes from where the step starts; False for NaN)
        settled = good & (2 * cv * (new - tt) ** 2 < slack) & (np.abs(new - tt) * st < SETTLE_STEP * self.tol)
        return np.where(go & settled, new, tt), new, go & (new != tt) & ~settled, lo, hi

    def write(self, ids, p, g, gn, best):
        """Outputs of vertices ``ids`` (rows of the other arguments)."""
        self.pos_rows[ids] = _rows(p.astype(_F32))
        np.divide(g, np.where(gn > 0, gn, 1)[:, None], out=g)  # (g: the caller's temporary, contiguous)
        self.normal_rows[ids] = _rows(np.negative(g, out=g))
        self.flat[ids] = gn <= 0
        self.arg[ids] = best

    def first(self, batch):
        """Evaluate and write every vertex of the batch (its padding to row n); return those still moving
        (their ids, next edge parameters and brackets)."""
        vid, nv, ub = batch
        src, coef, kern = self.refiner.gather(ub)
        valid = np.arange(vid.shape[1]) < nv[:, None]
        ax, base, u0, along, st, ab, cv = self.setup(vid, ub)
        tt = self.t[vid]
        f, g, gn, e = self.evaluate(u0, along, tt, st, coef, kern, keep=False)
        lo, hi = np.zeros(vid.shape), np.ones(vid.shape)
        final, new, live, lo, hi = self.step(f, g, gn, valid, tt, lo, hi, ab, cv, along, st)
        best = np.take_along_axis(src, e.argmax(axis=-1), axis=1)
        base.reshape(-1)[along] += (final * st).reshape(-1)
        self.write(np.where(valid, vid, self.n).reshape(-1), base.reshape(-1, 3), g.reshape(-1, 3), gn.reshape(-1),
                   best.reshape(-1))
        at = np.flatnonzero(live)
        return vid.reshape(-1)[at], new.reshape(-1)[at], lo.reshape(-1)[at], hi.reshape(-1)[at]

    def rest(self, batch, left):
        """Iterate the vertices ``left`` (ids, t, lo, hi) at the batch's positions into them until done."""
        at, nv, ub = batch
        vid, tt, lo, hi = (x[at] for x in left)
        src, coef, kern = self.refiner.gather(ub)
        valid = np.arange(vid.shape[1]) < nv[:, None]
        ax, base, u0, along, st, ab, cv = self.setup(vid, ub)
        for it in range(1, NEWTON_STEPS + 1):
            f, g, gn, e = self.evaluate(u0, along, tt, st, coef, kern)
            live = np.zeros(vid.shape, bool)
            final = tt
            if it < NEWTON_STEPS:
                final, new, live, lo, hi = self.step(f, g, gn, valid, tt, lo, hi, ab, cv, along, st)
            done = np.flatnonzero(valid & ~live)
            best = src[done // vid.shape[1], e.reshape(-1, e.shape[-1])[done].argmax(axis=1)]
            p = base.reshape(-1, 3)[done]
            p[np.arange(len(done)), ax.reshape(-1)[done]] += final.reshape(-1)[done] * st.reshape(-1)[done]
            self.write(vid.reshape(-1)[done], p, g.reshape(-1, 3)[done], gn.reshape(-1)[done], best)
            if not live.any():
                return
            tt = np.where(live, new, tt)
            if 2 * np.count_nonzero(live) < live.size:
                valid, (vid, ax, base, u0, st, ab, tt, cv, lo, hi), (src, coef, kern) = _compact(
                    live, (vid, ax, base, u0, st, ab, tt, cv, lo, hi), (src, coef, kern))
                along = np.arange(0, u0.size, 3) + ax.reshape(-1)
            else:
                valid = live
