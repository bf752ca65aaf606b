"""The discrete-ordinates sweeps of the scattering solve: beams of a group of bins moved layer
by layer through the grid, catching and carrying light (:func:`_sweep`)."""

import numpy as np

from ..threads import default_threads, split_map, thread_map
from . import _native
from ._escape import _escape_centroid, _offset, _p2_escape, _phi, _variance


class _Shifter:
    """Moves ``K`` beams (K, A, B) sideways by ``sa``, ``sb`` cells per layer (bilinear).

    With ``|shift| <= 1`` a shift is ``new = (1 - |s|) old + s+ old[c-1] + s- old[c+1]``
    (``s+ = max(s, 0)``, ``s- = max(-s, 0)``) on a buffer with one ghost cell each side
    holding the beam's ``inflow`` (or the wrapped values on periodic axes): whole-plane
    slices instead of gathers.  Larger shifts (very flat voxels) use index gathers.
    """

    def __init__(self, sa, sb, pa, pb, A, B, inflow):
        self.A, self.B, self.pa, self.pb = A, B, pa, pb
        self.inflow = inflow
        self.small = max(np.max(np.abs(sa)), np.max(np.abs(sb))) <= 1.0 + 1e-12
        col = (len(sa), 1, 1)
        if self.small:
            self.fa = [np.maximum(x, 0.0).astype(np.float32).reshape(col) for x in (sa, -sa)]
            self.fb = [np.maximum(x, 0.0).astype(np.float32).reshape(col) for x in (sb, -sb)]
            self.skip_a = [not np.any(f) for f in self.fa]
            self.skip_b = [not np.any(f) for f in self.fb]
            self.wa = np.float32(1) - self.fa[0] - self.fa[1]
            self.wb = np.float32(1) - self.fb[0] - self.fb[1]
            self.buf = np.empty((len(sa), A + 2, B + 2), np.float32)
            self.buf[:] = inflow.reshape(col)
        else:
            self.ga = _shift_indices(A, sa, pa)
            self.gb = _shift_indices(B, sb, pb)

    def start(self):
        return np.broadcast_to(self.inflow[:, None, None], (len(self.inflow), self.A, self.B)).copy()

    def __call__(self, beam):
        if not self.small:
            return _gather_shift(_gather_shift(beam, self.ga, self.inflow, 1), self.gb, self.inflow, 2)
        b = self.buf
        b[:, 1:-1, 1:-1] = beam
        if self.pa:
            b[:, 0, 1:-1], b[:, -1, 1:-1] = beam[:, -1], beam[:, 0]
        out = b[:, 1:-1] * self.wa
        if not self.skip_a[0]:
            out += self.fa[0] * b[:, :-2]
        if not self.skip_a[1]:
            out += self.fa[1] * b[:, 2:]
        if self.pb:
            out[:, :, 0], out[:, :, -1] = out[:, :, -2], out[:, :, 1]
        res = out[:, :, 1:-1] * self.wb
        if not self.skip_b[0]:
            res += self.fb[0] * out[:, :, :-2]
        if not self.skip_b[1]:
            res += self.fb[1] * out[:, :, 2:]
        return res


def _shift_indices(n, shift, periodic):
    """Gather indices and weights moving a beam by ``shift`` cells (bilinear in 1-D);
    indices -1 and n mean 'outside' on a non-periodic axis."""
    i0 = np.floor(shift).astype(np.int64)
    f = (shift - i0).astype(np.float32)
    base = np.arange(n)[None, :] - i0[:, None]  # new[c] = (1-f) old[c-i0] + f old[c-i0-1]
    i1 = base - 1
    if periodic:
        return base % n, i1 % n, 1.0 - f, f
    return np.clip(base, -1, n), np.clip(i1, -1, n), 1.0 - f, f


def _gather_shift(beam, idx, inflow, ax):
    """Bilinear shift of ``beam`` along array axis ``ax`` by gathers (outside: ``inflow``)."""
    i0, i1, w0, w1 = idx
    n = beam.shape[ax]
    pad = np.broadcast_to(inflow[:, None, None], beam.shape[:ax] + (1,) + beam.shape[ax + 1:])
    ext = np.concatenate([beam, pad, pad], ax)  # index n -> inflow, -1 -> inflow (last)
    i0, i1 = np.where(i0 < 0, n + 1, i0), np.where(i1 < 0, n + 1, i1)
    kk = np.arange(len(beam))[:, None]
    w0, w1 = w0[:, None, None], w1[:, None, None]
    if ax == 1:
        return w0 * ext[kk, i0] + w1 * ext[kk, i1]
    e = np.swapaxes(ext, 1, 2)
    return np.swapaxes(w0 * e[kk, i0] + w1 * e[kk, i1], 1, 2)


_BLOCK = 1 << 16  # values per beam-block layer (a few hundred kB per temporary)


class _Scratch:
    """Zeroed float32 arrays on memory kept from call to call (per name): the first touch of a
    fresh array's pages costs a page fault each, on this VM up to 2 ms per MB, and the sweeps'
    outputs are 0.1-0.6 GB per call (128x128x96 solve: 5.9 s of system time)."""

    def __init__(self):
        self.bufs = {}
        self.made = {}

    def memo(self, key, source, make):
        """``make()``, kept under ``key`` for as long as it is asked for with the same ``source``
        object (arrays a solve does not change: its media in sweep order, their spans)."""
        hit = self.made.get(key)
        if hit is None or hit[0] is not source:
            hit = self.made[key] = (source, make())
        return hit[1]

    def empty(self, name, shape):
        """The array ``name`` of ``shape``, its values left as they were (zero on new memory): for
        outputs written whole, or the compiled sweeps' outputs, zero outside the cloud (``dark_zero``
        of native/src/scatter_sweep.c)."""
        n = int(np.prod(shape))
        buf = self.bufs.get(name)
        if buf is None or buf.size < n:
            buf = self.bufs[name] = np.zeros(n, np.float32)
        return buf[:n].reshape(shape)

    def zeros(self, name, shape):
        return _zero(self.empty(name, shape))

    def take(self, name):
        """The flat buffer ``name`` (its pages touched), no longer kept here; None if there is none."""
        return self.bufs.pop(name, None)


def _zero(a):
    """``a`` (contiguous) filled with zeros on threads; returns it."""
    flat = a.reshape(-1)
    split_map(lambda s: flat[s].fill(0), flat.size)
    return a


def _sweep(sigma, h, dirs, wsub, emis, inflow, periodic, axis, cache=None, per_sub=False, profile=None,
           moments=None, fresh=True, threads=None, scratch=None, into=None):
    """Sweep a group of beams through ``sigma`` layer by layer along array ``axis``.

    ``dirs`` (g, ns, 3): ``ns`` sub-directions for each of ``g`` bins, all with
    the same sign along the sweep; ``wsub`` (g, ns): share of the bin's flux
    each carries; ``emis`` (g, nz, ny, nx) or None: unshot power per bin and
    voxel; ``inflow`` (g, ns): beam power per transverse cell entering from
    outside (upstream face and non-periodic sides).
    ``cache``: a dict kept between calls with the same beams; it stores the
    per-layer transmittances and deposit centroids (float32) so later passes skip them.
    ``threads``: beam blocks swept side by side (default :func:`..threads.default_threads`).
    ``scratch``: a :class:`_Scratch` for the outputs, which then hold until its next use.  With it
    the compiled sweep takes its outputs and ``into``'s ``rec`` to hold zero outside the cloud already
    (memory zeroed once and written only by sweeps: the solve's) and leaves them so there.

    Sources inside a voxel are not spread evenly: with ``profile = (kappa, delta, m2, q)``
    (each (3, nz, ny, nx), x y z) the emission in a voxel is
    ``exp(-kappa . u) + q_a P2(2 u_a - 1)`` over the voxel's unit cube ``u`` (``a`` the sweep
    axis; ``P2`` the Legendre polynomial, normalised to the exponential's power), ``delta``
    its centroid offset (:func:`_offset` of ``kappa``), ``m2`` its second moment about the
    voxel's centre per axis.  Along a beam ``d`` crossing the layer (path length ``l``,
    optical depth ``tau``) ``u`` moves by ``c = l d / h``, so the exponential falls as
    ``exp(-beta v)``, ``beta = kappa . c``, and escapes with :func:`_exp_source_escape`, and
    ``u_a`` is ``v`` or ``1 - v``: the P2 term adds ``q_a`` times :func:`_p2_escape`.
    Without a profile the uniform ``(1 - e^-tau)/tau``.
    ``moments = (w, out, scale[, also])`` or None: also add ``scale`` times ``m`` first and second
    moments of the received power about each voxel's centre to ``out`` (m, 2, 3, nz, ny, nx;
    in voxel units, x y z), set ``s`` summing bin ``b``'s moments times ``w[s, b]`` (``w``
    (m, g): e.g. the share of what bin ``b`` catches that is scattered into the bins of set
    ``s``): a beam deposits ``exp(-tau v)``, centroid ``_offset(tau) c``, second moment
    :func:`_second_moment` along the sweep axis (sideways: spread evenly, 1/12); the power a
    source keeps in its own voxel sits downstream of the source's centroid (closed forms below)
    and sideways where the source was.
    With a ``cache``, the profile's escape fractions are kept too and reused unless ``fresh``
    (``fresh=None``: recomputed and not kept, for callers that refresh them every time).
    Emission must sit only in voxels with ``sigma > 0`` (a source needs extinction): each
    layer is transported only on the rectangle around its non-empty voxels, elsewhere the
    beams pass unchanged.
    ``into = (rec, total, bins)`` or None: the solve's arrays of all bins (nb, ...); the sweep's
    total is added to ``total[bins]`` instead of being returned (``total`` None: not summed), and
    with ``per_sub`` and ``rec`` not None ``rec[bins]`` becomes the catch summed over
    sub-directions (the compiled sweep does both as it goes, saving whole-grid passes over the
    outputs).
    Returns received (g, ...) (``per_sub``: (g, ns, ...) per sub-direction), total (g, ...)
    (with ``into``: the power caught per bin and sub-direction (g, ns) float64 where ``rec`` is
    filled, else None) and the exit power (g,) through the far face.
    """
    g, ns, _ = dirs.shape
    comp = 2 - axis  # xyz component along the sweep
    others = [a for a in range(3) if a != axis]
    def order():
        return np.ascontiguousarray(np.moveaxis(sigma, axis, 0), dtype=np.float32)

    # (the medium in sweep order: kept by the scratch, the same for every sweep of a solve along an axis)
    sig = order() if scratch is None else scratch.memo(("sig", id(sigma), axis), sigma, order)
    L, A, B = sig.shape
    dl = dirs[..., comp]
    sign = np.sign(dl.flat[0])
    if sign == 0 or np.any(np.sign(dl) != sign):
        raise ValueError("_sweep: beams must share the sign of the sweep component")
    # received in the grid's own layout, written through a view in sweep order: callers
    # flatten it (phase-matrix products), which would copy a transposed array
    lead = 2 if per_sub else 1
    kernel = _native.sweep_kernel()
    if kernel is not None:  # the compiled sweeps write every value of their outputs
        zeros = (lambda name, shape: np.empty(shape, np.float32)) if scratch is None else scratch.empty
    else:
        zeros = (lambda name, shape: np.zeros(shape, np.float32)) if scratch is None else scratch.zeros
    recv_grid = zeros("recv", (g, ns) + sigma.shape if per_sub else (g,) + sigma.shape)
    recv = np.moveaxis(recv_grid, lead + axis, lead)
    exit_power = np.zeros(g)
    sums = None
    if kernel is not None and into is not None:  # the kernel adds to the solve's arrays itself
        rec_all, total_all, bins = into
        rbin = None if rec_all is None or not per_sub else np.moveaxis(rec_all, axis + 1, 1)
        sums = None if rbin is None else np.zeros((g, ns))
        total = None if total_all is None else np.moveaxis(total_all, axis + 1, 1)
        out = total_all if total is not None else rec_all if rbin is not None else None  # (what bins index)
        into_kernel = (rbin, None if out is None else _native.bin_rows(bins, len(out)), sums)
    else:
        total = None if into is not None and into[1] is None else zeros("total", (g, L, A, B))
        into_kernel = None
    em = None if emis is None else np.moveaxis(np.asarray(emis, np.float32), axis + 1, 1)
    kap = None if profile is None else np.moveaxis(np.asarray(profile[0], np.float32), axis + 1, 1)
    mw = None if moments is None else np.asarray(moments[0], np.float32).reshape(-1, g)
    second = mw is not None and moments[1].shape[1] == 2
    # the profile along the sweep axis: its P2 weight (None without, e.g. the sun's first
    # scattering) and, when second moments are tracked, its variance
    qa = None if profile is None or profile[3] is None or not np.any(profile[3][comp]) else profile[3][comp]
    var = None if profile is None or not second else profile[2][comp] - np.square(profile[1][comp])
    shape2 = tuple(None if x is None else np.moveaxis(np.asarray(x, np.float32), axis, 0) for x in (qa, var))
    inflow = np.asarray(inflow, dtype=np.float32).reshape(g, ns)
    wsub = np.asarray(wsub, dtype=np.float32).reshape(g, ns)
    # Beams are independent: blocks of bins, each swept through all layers, keep the
    # temporaries of one layer (block beams x plane, ~_BLOCK values) in cache, and run
    # on threads (NumPy releases the GIL in its loops); blocks never share a bin.
    per = max(1, _BLOCK // (ns * A * B))
    blocks = [np.arange(s, min(s + per, g)) for s in range(0, g, per)]
    nthreads = max(1, min(int(threads or default_threads()), len(blocks)))
    # per bin (blocks never share a bin, so the threads share it), in the grid's layout: the
    # first moment along the sweep axis, (with profiles) the power its sources keep in their
    # voxel, whose sideways moments (the source's: profile[1], profile[2] times it) are added
    # after the sweep, and (second moments) the second moment along the axis and the power the
    # beams deposit (spread evenly sideways); the bins go to the sets once
    slot = {n: i for i, n in enumerate(["m1"] + (["kept"] if em is not None and kap is not None else [])
                                       + (["m2", "dep"] if second else []))}
    slots = len(slot)
    bmom_grid = None if mw is None else zeros("moments", (g, slots) + sigma.shape)
    bmom = None if mw is None else np.moveaxis(bmom_grid, axis + 2, 2)
    if kernel is not None:
        d = dirs.reshape(-1, 3)
        ca, cb = 2 - others[0], 2 - others[1]
        ell = h[comp] / np.abs(d[:, comp])
        shifts = [d[:, c] / np.abs(d[:, comp]) * (h[comp] / h[c]) for c in (ca, cb)]
        _native.sweep(kernel, sig, (sign, periodic[ca], periodic[cb], comp),
                      (ell[:, None] * d / np.asarray(h, float)[None], ell, *shifts, wsub, inflow),
                      (em, kap, *shape2), (recv, per_sub, total, exit_power, bmom, slot, into_kernel), cache, fresh,
                      threads, scratch, dark_zero=scratch is not None)
    else:
        geom = (h, comp, others, periodic, sign, L, A, B, _layer_boxes(sig), slot)

        def work(t):
            for ib in range(t, len(blocks), nthreads):
                bs = blocks[ib]
                bm = None if mw is None else bmom[bs[0]:bs[-1] + 1]  # a view: blocks are ranges of bins
                _sweep_block(sig, geom, dirs[bs], wsub[bs], None if em is None else em[bs], inflow[bs],
                             kap, shape2, cache, ib, fresh, bm, recv, total, exit_power, bs, per_sub)

        thread_map(work, range(nthreads), nthreads)
    if mw is not None:
        held = (_native.held_groups(sigma) if scratch is None
                else scratch.memo(("held", id(sigma)), sigma, lambda: _native.held_groups(sigma)))
        _moment_sums(moments, mw, bmom_grid.reshape(g, slots, -1), comp, slot, profile, second, threads, held)
    return _outputs(recv_grid, total, axis, exit_power, into, sums, into_kernel is not None)


def _moment_sums(moments, mw, bm, comp, slot, profile, second, threads, held):
    """:func:`_sweep`'s moments: the bins' (``bm`` (g, slots, voxels), grid layout) summed into the
    sets of ``moments`` with weights ``mw`` (sets, g), by the compiled kernel (which skips the groups
    of voxels that ``held`` says are empty) or its NumPy twin."""
    out, scale = moments[1].reshape(len(mw), 1 + second, 3, -1), np.float32(moments[2])
    also = None if len(moments) < 4 or moments[3] is None else moments[3].reshape(out.shape)
    d, m2 = (None if profile is None or profile[i] is None else np.asarray(profile[i], np.float32).reshape(3, -1)
             for i in (1, 2))
    side = [c for c in range(3) if c != comp]
    if _native.moments(mw, bm, comp, slot, d, m2, scale, out, held, threads, also):
        return

    def add(s):
        # (einsum, not a BLAS product: OpenBLAS's threads would spin beside the solve's own
        # afterwards; 64x64x48 on 2 threads 19.4 s CPU that way, 13.3 s so)
        m = scale * np.einsum("sb,bkn->ksn", mw, bm[:, :, s])
        for o in (out, also) if also is not None else (out,):
            o[:, 0, comp, s] += m[slot["m1"]]
            if "kept" in slot:
                for c in range(3):
                    o[:, 0, c, s] += d[c, s] * m[slot["kept"]]
            if second:
                o[:, 1, comp, s] += m[slot["m2"]]
                for c in side:
                    o[:, 1, c, s] += np.float32(1 / 12) * m[slot["dep"]]
                    if "kept" in slot:
                        o[:, 1, c, s] += m2[c, s] * m[slot["kept"]]

    split_map(add, bm.shape[2], threads)


def _outputs(recv, total, axis, exit_power, into, sums, done):
    """:func:`_sweep`'s return, ``total`` (g, L, A, B) in sweep order; with ``into`` it goes to the
    solve's arrays (``done``: the compiled sweep put it there, and ``sums`` its per-sub catch)."""
    if into is None:
        return recv, np.moveaxis(total, 1, axis + 1), exit_power
    if done:
        return recv, sums, exit_power
    rec_all, total_all, bins = into
    fill = rec_all is not None and recv.ndim == 5  # (per sub-direction)
    if total is None and not fill:
        return recv, None, exit_power
    bs = bins if isinstance(bins, slice) else _as_slice(np.asarray(bins))
    if total is not None:
        ft = np.moveaxis(total, 1, axis + 1).reshape(len(total), -1)
        fa = total_all.reshape(len(total_all), -1)
    if fill:
        fr, fo = recv.reshape(recv.shape[0], recv.shape[1], -1), rec_all.reshape(len(rec_all), -1)

    def run(s):
        if total is not None:
            fa[bs, s] += ft[:, s]
        if fill:
            fo[bs, s] = fr[:, :, s].sum(1, dtype=np.float32)
            return fr[:, :, s].sum(2, dtype=np.float64)
        return 0.0

    parts = split_map(run, int(np.prod(recv.shape[-3:])))
    return recv, np.sum(parts, axis=0) if fill else None, exit_power


def _as_slice(bs):
    """Bin indices ``bs`` as a slice where they are a run (a view instead of a gather)."""
    return slice(int(bs[0]), int(bs[-1]) + 1) if len(bs) and np.all(np.diff(bs) == 1) else bs


def _layer_boxes(sig):
    """Per layer of ``sig`` (L, A, B): slices (a, b) of the rectangle around its voxels with
    ``sig > 0``, or None for an empty layer."""
    occ = sig > 0
    rows, cols = occ.any(2), occ.any(1)
    out = []
    for ra, rb in zip(rows, cols):
        ia, jb = np.flatnonzero(ra), np.flatnonzero(rb)
        out.append((slice(int(ia[0]), int(ia[-1]) + 1), slice(int(jb[0]), int(jb[-1]) + 1)) if len(ia) else None)
    return out


def _layer_area(sigma):
    """The most voxels any sweep axis transports over all its layers' rectangles (:func:`_layer_boxes`)."""
    return max(sum(0 if r is None else (r[0].stop - r[0].start) * (r[1].stop - r[1].start)
                   for r in _layer_boxes(np.moveaxis(sigma, ax, 0))) for ax in range(3))


def _sweep_block(sig, geom, dirs, wsub, em, inflow, kap, shape2, cache, ib, fresh, mom, recv, total, exit_power,
                 bs, per_sub):
    """One block of bins of :func:`_sweep`, all layers; writes its bins of ``recv``, ``total``,
    ``exit_power`` and its bins' moments (block bins, slots, ...) to ``mom``: the first and
    second moments along the sweep axis, the power deposited by the beams and, with profiles,
    the power sources keep in their voxel."""
    h, comp, others, periodic, sign, L, A, B, rects, slot = geom
    g, ns, _ = dirs.shape
    K = g * ns
    d = dirs.reshape(-1, 3)
    ca, cb = 2 - others[0], 2 - others[1]
    dl = d[:, comp]
    ell = h[comp] / np.abs(dl)  # path length across one layer
    cross = (ell[:, None] * d / np.asarray(h, float)[None]).astype(np.float32)  # (K, 3) unit-cube move per layer
    sa = d[:, ca] / np.abs(dl) * (h[comp] / h[ca])
    sb = d[:, cb] / np.abs(dl) * (h[comp] / h[cb])
    shifter = _Shifter(sa, sb, periodic[ca], periodic[cb], A, B, inflow.reshape(K))
    beam = shifter.start()
    w = wsub.reshape(g, ns, 1, 1)
    ell32 = ell.astype(np.float32)[:, None, None]
    f1 = np.float32(1)
    if mom is not None:  # each beam's move along the axis per layer, by bin
        cw = cross[:, comp].reshape(g, ns)
    order = range(L) if sign > 0 else range(L - 1, -1, -1)
    for n, k in enumerate(order):
        if n:  # move to this layer: bilinear transverse shift, inflow outside the grid
            beam = shifter(beam)
        if total is not None:
            total[bs, k] = beam.reshape(g, ns, A, B).sum(1)
        if rects[k] is None:  # empty layer: the beams pass unchanged
            continue
        wa, wb = rects[k]
        box = (slice(None), wa, wb)
        sh = (K, wa.stop - wa.start, wb.stop - wb.start)
        bm = beam[box]
        tau = sig[k][wa, wb][None] * ell32
        if cache is not None and (ib, k) in cache:
            t, offb = cache[(ib, k)]
        else:
            t = np.exp(-tau)
            offb = _offset(tau) if mom is not None else None
            if cache is not None:
                cache[(ib, k)] = (t, offb)
        bt = bm * t
        if em is None:
            r = bm - bt
            beam[box] = bt
        else:
            if kap is not None:
                if cache is not None and ("p", ib, k) in cache and not (fresh is None or fresh):
                    esc, shift, kept2 = cache[("p", ib, k)]
                else:
                    beta = (cross @ kap[:, k, wa, wb].reshape(3, -1)).reshape(sh)
                    esc, vs = _escape_centroid(tau, beta)
                    qa, var = (None if x is None else x[k, wa, wb][None] for x in shape2)
                    if qa is not None:
                        esc = np.clip(esc + qa * _p2_escape(tau, t), np.float32(0), f1)
                    kept2 = None
                    if mom is not None:
                        # what a source keeps sits downstream of it: with v_s its centroid along
                        # the path, the photons' mean end point v_s + (1 - esc) / tau (escapers
                        # stop at 1) gives the kept part's centroid x = (v_s - esc) / (1 - esc) + 1 / tau
                        kept = np.maximum(f1 - esc, np.float32(1e-30))
                        shift = (vs - esc) / kept + f1 / np.maximum(tau, np.float32(1e-2)) - vs
                        # thin (tau < 0.01): the limit 1/6; the clip keeps the blend finite
                        shift = np.clip(shift, -f1, f1)
                        shift += (tau < np.float32(1e-2)) * (np.float32(1 / 6) - shift)
                        # and its second moment about the centre, per unit of source: the mean
                        # squared end point v^2 + 2 v / tau + 2 / tau^2 - (2 / tau + 2 / tau^2) e^-(tau (1 - v)),
                        # less the escapers' (at 1), about 1/2.  Thin (tau < 0.1, where float32 loses
                        # it in the 1 / tau^2): where the source is
                        if var is not None:
                            ti = f1 / np.maximum(tau, np.float32(0.1))
                            m2s = var + np.square(vs - np.float32(0.5))
                            kept2 = (m2s + (vs + vs - f1 - esc) * ti + np.float32(2) * kept * ti * ti
                                     - np.float32(0.25) * esc)
                            kept2 += (tau < np.float32(0.1)) * (kept * m2s - kept2)
                            kept2 = np.clip(kept2, np.float32(0), np.float32(0.25) * kept)
                    else:
                        shift = None
                    if cache is not None and fresh is not None:
                        cache[("p", ib, k)] = (esc, shift, kept2)
            else:
                esc = _phi(tau)
            e = (em[:, k, wa, wb][:, None] * w).reshape(sh)
            rb = bm - bt
            ee = e * esc
            re = e - ee
            r = rb + re
            beam[box] = bt + ee
            if total is not None:
                total[bs, k, wa, wb] += e.reshape((g, ns) + sh[1:]).sum(1)
        if mom is not None:
            rb = r if em is None else rb
            # Moments along the sweep axis only: a beam crosses the whole layer there, while
            # sideways it enters anywhere in its cell and its deposit spills into the
            # neighbours.  Counting its sideways move as if it crossed the voxel's centre gave
            # thin layers of cubic voxels a skewed profile (g 0.8, sun at 60 deg: R -15 %).
            dep = rb * offb
            per_bin = (g, ns) + sh[1:]
            if "kept" in slot:
                mom[:, slot["kept"], k, wa, wb] += re.reshape(per_bin).sum(1)
                dep = dep + re * shift
            mom[:, 0, k, wa, wb] += np.einsum("gs,gsx->gx", cw, dep.reshape(g, ns, -1)).reshape((g,) + sh[1:])
            if "m2" in slot:
                dep2 = rb * (_variance(tau, t) + offb * offb)
                if "kept" in slot:
                    dep2 += e * kept2
                mom[:, slot["m2"], k, wa, wb] += dep2.reshape(per_bin).sum(1)
                mom[:, slot["dep"], k, wa, wb] += rb.reshape(per_bin).sum(1)
        if per_sub:
            recv[bs, :, k, wa, wb] = r.reshape((g, ns) + sh[1:])
        else:
            recv[bs, k, wa, wb] = r.reshape((g, ns) + sh[1:]).sum(1)
    exit_power[bs] = beam.reshape(g, ns, A, B).sum((1, 2, 3), dtype=np.float64)

