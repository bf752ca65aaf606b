"""The shooting passes' bookkeeping: bins grouped by sweep, unshot light shot and scattered
into the bins, the sub-directions of the peaked orders merged by quarters, and the
extrapolated tail of the passes (:class:`_Tail`)."""

import numpy as np

from ..threads import default_threads, split_map, thread_map
from . import _native, phase
from ._sweep import _as_slice


class _Tail:
    """The shooting passes' geometric tail, extrapolated (Aitken's delta-squared on the passes).

    Late passes repeat the iteration's slowest mode: each pass adds ``rho`` times what the
    pass before added to ``received``, ``total`` (where summed) and the exit power, so the passes still to
    come add ``rho / (1 - rho)`` times the last pass's increment (the "ambient" or overshoot
    term of progressive radiosity: Cohen et al. 1988, Feda & Purgathofer 1992).  ``rho`` is
    the ratio of the last two increments' power.  The extrapolation's own error comes from
    the faster modes, not yet died out: they shrink at most by ``rho`` per pass, so the
    extrapolated ``received`` still moves by at most ``rho / (1 - rho)`` times its last move
    (L1 over voxels and bins), the bound :meth:`end` returns.  Fig. 6 cloud 64x64x48: the
    bound is about twice the true error (against a solve to tol 1e-6).
    Memory: the pass's increment of ``received`` (:attr:`inc`: :func:`_shot_group` writes each
    group's catch there, each bin being shot once a pass, and :meth:`end` adds it to ``received``), a
    copy of ``total`` (None: not summed) at the pass start and the last increment; ``spares``: free float32 buffers,
    their pages touched, cut into arrays like ``received`` to hold them (fresh memory costs a page
    fault per 4 KiB when first written: up to 2 ms per MB on this VM).
    """

    def __init__(self, received, total, exit_flux, spares=()):
        self.arrays = (received, total, exit_flux)
        self.start = self.inc = self.last = self.factor = None
        n, shape = received.size, received.shape
        self.free = [b.reshape(-1)[i * n:(i + 1) * n].reshape(shape)  # received-sized, holding nothing
                     for b in spares if b is not None for i in range(b.size // n)]

    def _buffer(self):
        return self.free.pop() if self.free else np.empty_like(self.arrays[0])

    def reset(self):
        """A new run of passes (on other sub-directions): forget the increments, keep the buffers."""
        if self.last is not None:
            self.free.append(self.last[0])
        self.last = self.factor = None

    def begin(self):
        """Before a pass: a buffer for its increment, and where ``total`` and the exit power start."""
        self.inc = self._buffer()
        total = self.arrays[1]
        if self.start is None:
            self.start = [None if total is None else self._buffer(), np.empty_like(self.arrays[2])]
        if total is not None:
            fb, fa = (a.reshape(len(a), -1) for a in (self.start[0], total))
            split_map(lambda s: np.copyto(fb[:, s], fa[:, s]), fa.shape[1])
        np.copyto(self.start[1], self.arrays[2])

    def end(self):
        """After a pass: its increment added to ``received``; the bound on the extrapolated
        ``received``'s L1 error (inf until it has one)."""
        d = self.inc
        fd, fr = d.reshape(len(d), -1), self.arrays[0].reshape(len(d), -1)

        def add(s):  # the increment's L1 (signed after a warm start) with it in cache
            np.add(fr[:, s], fd[:, s], out=fr[:, s])
            return np.abs(fd[:, s]).sum(dtype=np.float64)

        power = float(sum(split_map(add, fd.shape[1], chunk=1 << 12)))
        factor, change = None, np.inf
        if self.last is not None and self.last[1] > 0 and 0 < power < self.last[1]:
            rho = power / self.last[1]
            factor = rho / (1.0 - rho)
            if self.factor is not None:
                change = factor * _l1_combination(d, np.float32(1.0 + factor), self.last[0],
                                                  -np.float32(self.factor))
        if self.last is not None:
            self.free.append(self.last[0])
        self.last, self.factor, self.inc = (d, power), factor, None
        return change

    def apply(self):
        """Add the extrapolated passes to ``received``, ``total`` and the exit power."""
        rec, tot, ex = self.arrays
        f = np.float32(self.factor)
        fr, fl = rec.reshape(len(rec), -1), self.last[0].reshape(len(rec), -1)
        if tot is not None:
            ft, fs = tot.reshape(len(tot), -1), self.start[0].reshape(len(tot), -1)

        def add(s):
            fr[:, s] += f * fl[:, s]
            if tot is not None:
                ft[:, s] += (ft[:, s] - fs[:, s]) * f

        split_map(add, fr.shape[1], chunk=1 << 12)
        ex += (ex - self.start[1]) * self.factor


def _l1_combination(x, a, y, b):
    """``sum |a x + b y|`` (float64) over two float32 arrays of one shape, in voxel ranges on
    threads so the temporaries stay small."""
    fx, fy = x.reshape(len(x), -1), y.reshape(len(y), -1)

    def part(s):
        buf = fx[:, s] * a
        buf += fy[:, s] * b
        return float(np.abs(buf, out=buf).sum(dtype=np.float64))

    return sum(split_map(part, fx.shape[1], chunk=1 << 11))



def _groups(periodic, sub, per_face=phase.N_PER_FACE, bands=True):
    """Bins grouped by (array axis of the sweep, sign); sub-directions and weights.

    A group is also a set of bins sharing one voxel profile of their unshot light, so where
    periodic axes send the bins of other cube faces along a free axis too (slabs), those go
    (``bands``) in two more groups, steep and grazing (cosine along the axis above or below
    0.4): light leaving a voxel at a grazing angle was caught elsewhere in it than light
    leaving steeply (g 0.8 slabs, voxel tau 1-2: one profile for all bins of a sign, fitted to
    the true in-voxel sources, misses their escape by -1.2 % to +0.3 %; three groups: +-0.3 %).
    """
    cen, omega, dirs, w = phase.bins(sub, per_face)
    free = [c for c in range(3) if not periodic[c]]
    if not free:
        raise ValueError("solve: at least one axis must be non-periodic")
    keys = {}
    for b in range(len(cen)):
        c = max(free, key=lambda c: abs(cen[b, c]))
        mu = abs(cen[b, c]) / np.linalg.norm(cen[b])
        band = 0 if not bands or abs(cen[b, c]) >= np.abs(cen[b]).max() else 1 + int(mu < 0.4)
        keys.setdefault((2 - c, float(np.sign(cen[b, c])), band), []).append(b)
    groups = [(axis, np.array(bs)) for (axis, _, _), bs in sorted(keys.items())]
    return groups, dirs, w / omega[:, None], w



def _occupied_box(sigma, periodic):
    """Slices (z, y, x) of the smallest box holding every voxel with ``sigma > 0`` along the
    non-periodic axes, or None when that is the whole grid (or the grid is empty)."""
    occ = sigma > 0
    if not occ.any():
        return None
    box = []
    for ax in range(3):
        if periodic[2 - ax]:
            box.append(slice(None))
            continue
        hit = np.flatnonzero(occ.any(axis=tuple(a for a in range(3) if a != ax)))
        box.append(slice(int(hit[0]), int(hit[-1]) + 1))
    box = tuple(box)
    return None if sigma[box].shape == sigma.shape else box


def _shot_group(bs, unshot, received, r, power, shot, albedo, omega=1.0, inc=None):
    """After a sweep of bins ``bs``: ``omega`` times their unshot light is shot (``1 - omega`` times
    it stays), what they caught (``r``) is added to ``received`` (or, unless ``inc`` is None, written
    to ``inc``: :meth:`_Tail.end` adds it at the pass end), and the unshot ``power`` per voxel loses
    ``omega`` times ``shot`` and gains albedo times ``r`` (the sweep added what they carried to the
    total); on threads, voxel ranges side by side (in one thread these whole-grid steps took 2.6 s,
    about 3 %, of a line-profiled 128x128x96 solve)."""
    bs = _as_slice(bs)
    if _native.shot_group(bs, unshot, received, r, power.reshape(-1), shot.reshape(-1), albedo, omega, inc):
        return
    fi = None if inc is None else inc.reshape(len(inc), -1)
    u, rec = (a.reshape(len(a), -1) for a in (unshot, received))
    rr, pw, sh = r.reshape(len(r), -1), power.reshape(-1), shot.reshape(-1)
    keep = np.float32(1.0 - omega)

    def run(s):
        u[bs, s] *= keep
        if fi is None:
            rec[bs, s] += rr[:, s]
        else:
            fi[bs, s] = rr[:, s]
        pw[s] -= omega * sh[s]
        pw[s] += albedo * rr[:, s].sum(0, dtype=np.float64)

    split_map(run, pw.size)


def _bin_sum(a, bs):
    """``a[bs].sum(0)`` in float64 over bins ``bs`` of ``a`` (nb, ...), on threads."""
    bs = bs if isinstance(bs, slice) else _as_slice(bs)
    out = _native.bin_sum(a, bs)
    if out is not None:
        return out
    flat, out = a.reshape(len(a), -1), np.empty(a.shape[1:], np.float64)

    def run(s):
        out.reshape(-1)[s] = flat[bs, s].sum(0, dtype=np.float64)

    split_map(run, out.size)
    return out


def _bin_powers(a):
    """Each bin's power, ``a.reshape(nb, -1).sum(1)`` in float64 (nb,), bins on threads (each
    row's sum as NumPy's own)."""
    flat = a.reshape(len(a), -1)
    return np.array(thread_map(lambda b: flat[b].sum(dtype=np.float64), range(len(flat))))


# Multiply-adds per BLAS product in _scatter_into: at most 2^18, where OpenBLAS still runs a product
# in the calling thread (above it, its own threads take every product, then spin beside ours).
# 96 bins on 6e5 voxels, 2 threads (2026-11-29, AMD EPYC, load 1.0), ms at 2^18 against 96 x 8192:
# k = 16 86 / 195, 64 200 / 474, 128 378 / 704, 256 647 / 1237; with no fewer than 8 voxels a
# product (not 16): k = 464 725 / 927 ms on 3e5 voxels.  (An Intel Xeon with AVX-512, whose OpenBLAS
# kernel keeps products up to ~1e6 in the calling thread, measured 96 x 8192 faster than 96 x 4096:
# k = 128 101 / 150 ms on 5e5 voxels; 2^18 was not timed there.)
_PRODUCT_MACS = 1 << 18


def _scatter_into(unshot, m_cols, recv, albedo, held=None):
    """``unshot += albedo * M[:, group] @ recv`` in float32 chunks; ``m_cols`` (nb, k) with
    ``recv`` (k, ...): k bins, or bins x sub-directions.  The compiled kernel computes only the
    voxels that caught something (native/src/scatter_shoot.c), and skips the groups of voxels that
    ``held`` (:func:`._native.held_groups` of the medium) says are empty without reading them; its
    NumPy twin, below, computes all of them.

    Chunks of ``_PRODUCT_MACS // (nb k)`` voxels keep each product under 2^18 multiply-adds,
    which OpenBLAS runs in the calling thread: larger ones it splits over its own threads, which
    then spin and take the cores from the sweeps (k = 16 on 5.2e5 voxels: 0.19 s CPU in chunks of
    65536, 0.057 s in chunks of 256, as with ``OPENBLAS_NUM_THREADS=1``; 64x64x48 solve
    17 -> 12 s CPU at load 5).  One ``matmul`` call takes a stack of 64 chunks (its loop over
    them runs in C without the GIL), and our own threads take every other stack:
    k = 256 on 5e5 voxels, one thread, 0.65 s as single chunks -> 0.38 s.
    """
    kernel = _native.scatter_kernel()
    if kernel is not None:
        _native.scatter_into(kernel, unshot, albedo * np.asarray(m_cols), np.asarray(recv, np.float32), held=held)
        return
    g = m_cols.shape[1]
    nb = len(unshot)
    u = unshot.reshape(nb, -1)
    r = recv.reshape(g, -1)
    m = (albedo * m_cols).astype(np.float32)
    chunk = max(8, _PRODUCT_MACS // (nb * g))
    stack = 64 * chunk
    n = r.shape[1]
    starts = range(0, n, stack)
    nthreads = max(1, min(default_threads(), len(starts)))

    def run(t):
        buf = np.empty((nb, 64, chunk), np.float32)
        for s in starts[t::nthreads]:
            k = (min(s + stack, n) - s) // chunk
            e = s + k * chunk
            if k:  # (g, k*chunk) -> (k, g, chunk): views, the rows are contiguous
                part = np.asarray(r[:, s:e], np.float32).reshape(g, k, chunk).transpose(1, 0, 2)
                out = buf[:, :k]  # (the products land in u's layout: one contiguous add, not a strided one
                np.matmul(m, part, out=out.transpose(1, 0, 2))  # in 16-voxel pieces, 15 % of the call)
                u[:, s:e] += out.reshape(nb, k * chunk)
            if e < min(s + stack, n):
                u[:, e:s + stack] += m @ np.asarray(r[:, e:s + stack], np.float32)

    thread_map(run, range(nthreads), nthreads)



def _quarters(first_sub, sub):
    """Indices (sub*sub, k*k) of the ``first_sub``-side sub-squares of a bin in each of its
    ``sub x sub`` quarters (``k = first_sub // sub``); an empty array when ``sub`` does not
    divide ``first_sub`` into bigger parts (nothing to merge)."""
    k = first_sub // sub
    if sub < 1 or k < 2 or k * sub != first_sub:
        return np.zeros((0, 0), int)
    return np.arange(first_sub ** 2).reshape(sub, k, sub, k).transpose(0, 2, 1, 3).reshape(sub * sub, k * k)


def _fine_bins(flux, kids, tol):
    """Which bins keep all their sub-directions: all but the weakest, as many of those as
    hold at most ``tol`` of the power of all ``flux`` (nb,) together (those are merged by
    quarters, :func:`_merge_quarters`); all when there is nothing to merge (``kids`` empty).

    Decided by the flux's values, not by the last bits of its sums: the shares are of the running
    sum's own total, so ``tol`` 1 merges every bin, and bins within 1e-6 of the first bin left
    whole stay whole with it.  (Against ``np.sum`` the brightest bin stayed whole or not by the
    last bit, and of two mirror bins of a slab, equal but for rounding, one was merged: the C and
    NumPy paths then parted by 2e-3 of the total flux.)"""
    fine = np.ones(len(flux), bool)
    if kids.size == 0 or tol <= 0:
        return fine
    order = np.argsort(flux, kind="stable")
    run = np.cumsum(flux[order])
    k = int(np.count_nonzero(run <= tol * run[-1]))
    merged = order[:k]
    if k < len(flux):
        merged = merged[flux[merged] < flux[order[k]] * (1.0 - 1e-6)]
    fine[merged] = False
    return fine


def _merge_quarters(dirs, weights, ushare, kids):
    """Merge the sub-directions of bins (g, s*s, 3) by quarters: the directions (g, q, 3)
    at each quarter's weighted mean, their weights (g, q), and each sub-direction's share
    of its quarter (g, q, k*k) (solid-angle shares in an unlit quarter)."""
    w, u = weights[:, kids], ushare[:, kids]
    wsum = w.sum(2, keepdims=True)
    share = np.where(wsum > 0, w / np.where(wsum > 0, wsum, 1.0), u / u.sum(2, keepdims=True))
    d = (dirs[:, kids] * share[..., None]).sum(2)
    return d / np.linalg.norm(d, axis=-1, keepdims=True), wsum[..., 0], share

