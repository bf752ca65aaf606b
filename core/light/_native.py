"""Call sites of the scattering solve's compiled kernels (``native/src/scatter_*.c``, through
:mod:`..native`): the sweeps, the shooting step and the views' plane march.  Each has its NumPy
twin in the module that calls it (:func:`._sweep._sweep_block`, :func:`._passes._scatter_into`,
:func:`._views._march_rays`), used where the kernels
are not installed or with ``NEPHELE_NATIVE=0``; the C runs on Python's threads (ctypes lets go of
the GIL during a call), never threads of its own."""

import ctypes

import numpy as np

from .. import native
from ..threads import default_threads, thread_map

_P = ctypes.c_void_p
_I = ctypes.c_int64


class SweepArgs(ctypes.Structure):
    """``struct nph_sweep`` of native/src/scatter_sweep.c (same order; every field 8 bytes)."""

    _fields_ = [("L", _I), ("A", _I), ("B", _I), ("sign", _I), ("periodic_a", _I), ("periodic_b", _I), ("comp", _I),
                ("sig", _P), ("spans", _P), ("soff", _P), ("g", _I), ("ns", _I), ("ia", _P), ("ib", _P),
                ("wa", _P), ("wb", _P), ("cross", _P), ("ell", _P), ("w", _P), ("inflow", _P),
                ("em", _P), ("em_s", _I * 4), ("kap", _P), ("kap_s", _I * 4), ("qa", _P), ("qa_s", _I * 3),
                ("var", _P), ("var_s", _I * 3), ("recv", _P), ("recv_s", _I * 5), ("per_sub", _I),
                ("total", _P), ("total_s", _I * 4), ("exit_power", _P), ("mom", _P), ("mom_s", _I * 5),
                ("slot_kept", _I), ("slot_m2", _I), ("slot_dep", _I), ("cache", _P), ("cache_mode", _I),
                ("obins", _P), ("rbin", _P), ("rbin_s", _I * 4), ("caught", _P), ("stage_min", _I),
                ("dark_zero", _I), ("shared", _P)]

# Voxels in a layer from which the sweep stages arrays whose layers lie next to one another in
# memory (the sweeps along x) in blocks of 16 layers.  Fig. 6 cloud, warm solves alternated
# (2026-11-29, load 1.9): 128x128x96 (x layers of 5472 voxels) 14.1-16.6 s instead of 15.0-15.8 s,
# the solve's CPU median 26.8 s instead of 29.2 s; 64x64x48 (1368 voxels) staged ran no faster and
# its single sub-beams slower, so its layers stay in place.
STAGE_MIN = 4096


def sweep_kernel():
    """``scatter_sweep`` with its types, or None (no compiled kernels, or ``NEPHELE_NATIVE=0``)."""
    return native.kernel("scatter_sweep", None, [ctypes.POINTER(SweepArgs), _I, _I, _P])


def scatter_kernel():
    """``scatter_shoot`` (native/src/scatter_shoot.c) with its types, or None."""
    return native.kernel("scatter_shoot", None, [_I, _I, _I, _I, _P, _P, _I, _P, _I, _P])


def _strides(a, n):
    """``a``'s strides in elements (``n`` of them), checked to be whole elements."""
    st = [s // a.itemsize for s in a.strides]
    if any(s * a.itemsize != t for s, t in zip(st, a.strides, strict=True)) or len(st) != n:
        raise ValueError("scatter kernels: arrays must have whole-element strides")
    return st


def _ptr(a, n=None):
    """(pointer, strides) of a float32 array view, or (None, zeros) for None."""
    if a is None:
        return None, [0] * (n or 0)
    if a.dtype != np.float32:
        raise TypeError("scatter kernels take float32 arrays")
    return a.ctypes.data, _strides(a, n or a.ndim)


def _taps(shift):
    """Per beam, the plane shift's three taps (:class:`._sweep._Shifter`): offset of the centre tap
    and weights (previous, centre, next) in float32; one cell or less as the plane shift, more as
    its gathers (:func:`._sweep._shift_indices`)."""
    shift = np.asarray(shift, np.float64)
    small = np.abs(shift) <= 1.0 + 1e-12
    fp = np.maximum(shift, 0.0).astype(np.float32)
    fm = np.maximum(-shift, 0.0).astype(np.float32)
    i0 = np.floor(shift).astype(np.int64)
    f = (shift - i0).astype(np.float32)
    w = np.stack([np.where(small, fp, f), np.where(small, np.float32(1) - fp - fm, np.float32(1) - f),
                  np.where(small, fm, np.float32(0))], -1).astype(np.float32)
    return np.ascontiguousarray(np.where(small, 0, i0)), np.ascontiguousarray(w)


def sweep(kernel, sig, geom, beams, sources, outputs, cache, fresh, threads, scratch, dark_zero=False):
    """Sweep every bin of a group by the compiled kernel, bins on ``threads`` threads.

    ``geom`` = (sign, periodic_a, periodic_b, comp); ``beams`` = (cross (K, 3), ell (K,), sa (K,),
    sb (K,), w (g, ns), inflow (g, ns)); ``sources`` = (em, kap, qa, var) sweep-order views or None;
    ``outputs`` = (recv, per_sub, total, exit_power, mom, slot, into) with ``slot`` the moments'
    slots and ``into`` None or (rbin, bins, caught): ``total`` and ``rbin`` (None or, per_sub, the
    catch summed over sub-directions) are then sweep-order views of the solve's arrays of all bins,
    this group's bins at rows ``bins`` (int64), the total added to them; ``caught`` (g, ns) float64
    zeros or None, gets the power each sub-beam caught.
    ``cache``: the group's dict (kept between passes) or None, ``fresh`` as :func:`._sweep._sweep`'s.
    ``scratch``: a :class:`._sweep._Scratch` holding each thread's workspace from call to call, or None.
    ``dark_zero``: ``recv``, ``mom`` and ``rbin`` already hold zero outside the cloud's voxels (memory
    zeroed once and written only by sweeps, whose every write there is zero), so the kernel leaves
    them as they are there instead of zeroing each bin's first: the per-sub-direction catches of the
    peaked orders are 32 MB a bin at 128x128x96.  Its precondition, emission only in non-empty voxels,
    is every sweep's.
    """
    sign, pa, pb, comp = geom
    cross, ell, sa, sb, w, inflow = beams
    em, kap, qa, var = sources
    L, A, B = sig.shape
    if A * B >= STAGE_MIN:  # the inputs every bin shares, contiguous in sweep order for scatter_shared
        kap, qa, var = (None if x is None else _sweep_order(x) for x in (kap, qa, var))
    recv, per_sub, total, exit_power, mom, slot, into = outputs
    rbin, obins, caught = (None, None, None) if into is None else into
    g, ns = w.shape
    if caught is not None and (caught.dtype != np.float64 or not caught.flags.c_contiguous or caught.size != g * ns):
        raise TypeError("scatter kernels: caught must be contiguous float64 (g, ns)")
    spans, soff = _spans(sig) if scratch is None else scratch.memo(("spans", id(sig)), sig, lambda: _spans(sig))
    ia, wa = _taps(sa)
    ib, wb = _taps(sb)
    vecs = [np.ascontiguousarray(x, np.float32) for x in (cross, ell, w, inflow)]
    mode, buf = 0, None
    if kap is not None and cache is not None and fresh is not None:
        buf = cache.get("c")
        mode = 2 if buf is not None and fresh is False else 1
        if buf is None:
            buf = cache["c"] = np.empty((3, g * ns, int(soff[-1])), np.float32)
    a = SweepArgs(L=L, A=A, B=B, sign=int(sign), periodic_a=int(pa), periodic_b=int(pb), comp=int(comp),
                  sig=sig.ctypes.data, spans=spans.ctypes.data, soff=soff.ctypes.data, g=g, ns=ns,
                  ia=ia.ctypes.data, ib=ib.ctypes.data, wa=wa.ctypes.data, wb=wb.ctypes.data,
                  cross=vecs[0].ctypes.data, ell=vecs[1].ctypes.data, w=vecs[2].ctypes.data,
                  inflow=vecs[3].ctypes.data, per_sub=int(per_sub), exit_power=exit_power.ctypes.data,
                  slot_kept=slot.get("kept", -1), slot_m2=slot.get("m2", -1), slot_dep=slot.get("dep", -1),
                  cache=None if buf is None else buf.ctypes.data, cache_mode=mode,
                  obins=None if obins is None else obins.ctypes.data,
                  caught=None if caught is None else caught.ctypes.data, stage_min=STAGE_MIN,
                  dark_zero=int(dark_zero))
    for name, arr, n in (("em", em, 4), ("kap", kap, 4), ("qa", qa, 3), ("var", var, 3), ("recv", recv, 5),
                         ("total", total, 4), ("mom", mom, 5), ("rbin", rbin, 4)):
        if name == "recv" and not per_sub:  # (bin, layer, row, column): no sub axis
            p, st = _ptr(arr, 4)
            st = st[:1] + [0] + st[1:]
        else:
            p, st = _ptr(arr, n)
        setattr(a, name, p)
        getattr(a, name + "_s")[:] = st
    if exit_power.dtype != np.float64 or not exit_power.flags.c_contiguous:
        raise TypeError("scatter kernels: exit power must be contiguous float64")
    ref = ctypes.byref(a)
    # the inputs all bins share, on the spans once (scatter_shared), not gathered for each bin
    span = (6, int(soff[-1]))
    shared = np.empty(span, np.float32) if scratch is None else scratch.empty("shared", span)
    fill = native.kernel("scatter_shared", None, [ctypes.POINTER(SweepArgs), _I, _I, _P])
    thread_map(lambda r: fill(ref, r[0], r[1], shared.ctypes.data), _ranges(L, max(1, -(-L // 8))))
    a.shared = shared.ctypes.data
    size = native.kernel("scatter_sweep_work", _I, [ctypes.POINTER(SweepArgs)])(ref)
    n = max(1, min(int(threads or default_threads()), g))
    work = [np.empty(size, np.float32) if scratch is None else scratch.empty(("sweep", t), (size,)) for t in range(n)]
    # (bins of one group cost alike: each thread takes every n-th)
    thread_map(lambda t: [kernel(ref, b, b + 1, work[t].ctypes.data) for b in range(t, g, n)], range(n), n)


def _spans(sig):
    """Per row of ``sig`` (L, A, B), the span of its non-empty voxels (L, A, 2) and the spans'
    offsets, one after another (L A + 1): the twin's rectangles hold empty ones too."""
    L, A, B = sig.shape
    occ = sig > 0
    some = occ.any(2)
    spans = np.zeros((L, A, 2), np.int64)
    spans[..., 0] = np.where(some, np.argmax(occ, 2), 0)
    spans[..., 1] = np.where(some, B - np.argmax(occ[..., ::-1], 2), 0)
    return spans, np.concatenate([[0], np.cumsum(spans[..., 1] - spans[..., 0])]).astype(np.int64)


def _sweep_order(x):
    """``x`` (..., L, A, B), a sweep-order view, as a contiguous copy where its layers lie next to one
    another (the sweeps along x), so that scatter_shared gathers each row of its spans from one run of
    memory, not a cache line a voxel (when the kernel still gathered the profile rates for each bin, the
    copy took the Fig. 6 cloud's 128x128x96 x sweeps from 6.15-6.28 to 5.53-5.59 s).  Copied in ranges
    of layers on threads."""
    if x.strides[-3] != x.itemsize:
        return x
    out, L = np.empty(x.shape, x.dtype), x.shape[-3]
    step = max(1, -(-L // 4))
    parts = [(i, slice(s, s + step)) for i in np.ndindex(x.shape[:-3]) for s in range(0, L, step)]
    thread_map(lambda p: np.copyto(out[p[0]][p[1]], x[p[0]][p[1]]), parts)
    return out


def held_groups(sigma):
    """A byte per group of 8 voxels of ``sigma`` (flattened), 1 where one of them holds medium: what
    :func:`scatter_into` reads for the voxels' ``held``."""
    occ = np.asarray(sigma).reshape(-1) > 0
    return np.pad(occ, (0, -occ.size % 8)).reshape(-1, 8).any(1).astype(np.uint8)


def scatter_into(kernel, unshot, m, recv, threads=None, held=None):
    """``unshot += m @ recv`` (``m`` (nb, k) with the albedo in it, ``recv`` (k, n)) by the compiled
    kernel, voxel ranges on threads.  ``held``: :func:`held_groups` of the voxels' medium, whose
    empty groups (where ``recv`` is zero: an empty voxel catches nothing) are skipped unread."""
    nb, k = m.shape
    u = unshot.reshape(nb, -1)
    r = recv.reshape(k, -1)
    n = u.shape[1]
    if not (u.flags.c_contiguous and r.strides[1] == 4 and u.dtype == r.dtype == np.float32):
        raise TypeError("scatter_shoot: float32 arrays with contiguous voxels")
    mt = np.ascontiguousarray(np.asarray(m).T, np.float32)
    step = 1 << 14
    if held is not None and held.size * 8 < n:
        raise ValueError(f"scatter_shoot: {held.size} groups of 8 held for {n} voxels")
    hp = None if held is None else held.ctypes.data
    thread_map(lambda s: kernel(nb, k, s, min(s + step, n), mt.ctypes.data, r.ctypes.data, r.strides[0] // 4,
                                u.ctypes.data, n, hp), range(0, n, step), threads)


def _kernel(name, argtypes):
    return native.kernel(name, None, argtypes)


def bin_rows(bs, nb):
    """Bin indices ``bs`` (a slice or indices into ``nb`` bins) as a contiguous int64 array."""
    return np.ascontiguousarray(np.arange(nb)[bs] if isinstance(bs, slice) else bs, np.int64)


def _rows(a):
    """``a`` (bins, ...) as contiguous (bins, voxels) float32 rows, or TypeError."""
    flat = a.reshape(len(a), -1)
    if flat.dtype != np.float32 or not flat.flags.c_contiguous:
        raise TypeError("scatter kernels: contiguous float32 (bins, voxels) arrays")
    return flat


def _ranges(n, step=1 << 14):
    return [(s, min(s + step, n)) for s in range(0, n, step)]


def bin_sum(a, bs):
    """:func:`._passes._bin_sum` by the compiled kernel, or None without it."""
    k = _kernel("scatter_bin_sum", [_I, _P, _P, _I, _I, _I, _P])
    if k is None:
        return None
    flat = _rows(a)
    bins = bin_rows(bs, len(a))
    out = np.empty(a.shape[1:], np.float64)
    n = flat.shape[1]
    thread_map(lambda r: k(len(bins), bins.ctypes.data, flat.ctypes.data, n, r[0], r[1], out.ctypes.data),
               _ranges(n))
    return out


def shot_group(bs, unshot, received, r, power, shot, albedo, omega, inc=None):
    """:func:`._passes._shot_group` by the compiled kernel; False without it."""
    k = _kernel("scatter_shot", [_I, _P, _I, _I, _I, _P, _P, _P, _P, _P, _P, ctypes.c_double, ctypes.c_double])
    if k is None:
        return False
    u, rec, rr = _rows(unshot), _rows(received), _rows(np.ascontiguousarray(r, np.float32))
    ip = None if inc is None else _rows(inc).ctypes.data
    if not (power.dtype == shot.dtype == np.float64 and power.flags.c_contiguous and shot.flags.c_contiguous):
        raise TypeError("scatter_shot: contiguous float64 power and shot")
    bins = bin_rows(bs, len(unshot))
    n = u.shape[1]
    thread_map(lambda q: k(len(bins), bins.ctypes.data, n, q[0], q[1], u.ctypes.data, rec.ctypes.data, ip,
                           rr.ctypes.data, power.ctypes.data, shot.ctypes.data, float(albedo), float(omega)),
               _ranges(n))
    return True


def moments(mw, bm, comp, slot, d, m2, scale, out, held, threads=None, also=None):
    """The moments' sums of :func:`._sweep._sweep` by the compiled kernel; False without it.
    ``bm`` (g, slots, voxels) float32, ``out`` (and ``also``, when given) (sets, order, 3, voxels)
    float64; ``held``: :func:`held_groups` of the voxels' medium (nothing is caught where there is none,
    so its empty blocks are skipped)."""
    k = _kernel("scatter_moments", [_I, _I, _I, _I, _I, _I, _P, _P, _I, _I, _I, _I, _P, _P, ctypes.c_float, _P,
                                    _P, _P])
    if k is None:
        return False
    sets, g = mw.shape
    mw = np.ascontiguousarray(mw, np.float32)
    for o in (out, also) if also is not None else (out,):
        if bm.dtype != np.float32 or not bm.flags.c_contiguous or o.dtype != np.float64 or not o.flags.c_contiguous:
            raise TypeError("scatter_moments: contiguous float32 moments and float64 sums")
    d = None if d is None else np.ascontiguousarray(d, np.float32)
    m2 = None if m2 is None else np.ascontiguousarray(m2, np.float32)
    n = bm.shape[-1]
    if held.dtype != np.uint8 or held.size * 8 < n:
        raise ValueError(f"scatter_moments: {held.size} groups of 8 held for {n} voxels")
    thread_map(lambda q: k(sets, g, bm.shape[1], n, q[0], q[1], mw.ctypes.data, bm.ctypes.data, comp,
                           slot.get("kept", -1), slot.get("m2", -1), slot.get("dep", -1),
                           None if d is None else d.ctypes.data, None if m2 is None else m2.ctypes.data,
                           float(scale), out.ctypes.data, None if also is None else also.ctypes.data,
                           held.ctypes.data), _ranges(n), threads)
    return True


def profile(mom, power, second, tables):
    """:meth:`._solve._Solve.unshot_profile`'s profiles by the compiled kernel, or None without it:
    ``mom`` (1 + second, 3, ...) float64, ``power`` (...) float64, ``tables`` = (rtab, rstep, dlo,
    dhi, dscale) of :func:`._escape._rate_of_offset`; returns (2 + 2 second, 3, voxels) float32."""
    k = _kernel("scatter_profile", [_I, _I, _I, _I, _P, _P, _P, _P, ctypes.c_float, ctypes.c_float, ctypes.c_float,
                                    _P])
    if k is None:
        return None
    m = np.ascontiguousarray(mom, np.float64).reshape(len(mom), 3, -1)
    p = np.ascontiguousarray(power, np.float64).reshape(-1)
    rtab, rstep, dlo, dhi, dscale = tables
    n = p.size
    out = np.empty((4 if second else 2, 3, n), np.float32)
    thread_map(lambda q: k(n, q[0], q[1], int(second), m.ctypes.data, p.ctypes.data, rtab.ctypes.data,
                           rstep.ctypes.data, dlo, dhi, dscale, out.ctypes.data), _ranges(n))
    return out


def march_kernel():
    """``scatter_march`` (native/src/scatter_view.c) with its types, or None."""
    d = ctypes.c_double
    return native.kernel("scatter_march", None, [_P, _I, _I, _P, _I, d, d, _P, _P, _P, _P, _I, _I, _I, _P, _P,
                                                 _P, _P, _P, _P])


def march(kernel, stack, nbp, xs, lim, coef, start, end, first, block):
    """:func:`._views._march_rays` by the compiled kernel: ``stack`` (samples, texels) complex64 holds
    the samples' planes; returns (sum, transmittance) per ray, float32."""
    if stack.dtype != np.complex64 or not stack.flags.c_contiguous or len(stack) != len(xs):
        raise TypeError("scatter_march: the planes must be contiguous complex64, one per sample")
    if stack.shape[1] >= 1 << 30:
        raise ValueError(f"scatter_march: planes of {stack.shape[1]} texels (at most 2^30)")
    n = len(start)
    c = np.ascontiguousarray(np.stack(coef[:4]), np.float64)
    ns = np.ascontiguousarray(coef[4], np.float32)
    xs, start, end = (np.ascontiguousarray(a, t) for a, t in ((xs, np.float64), (start, np.int64), (end, np.int64)))
    acc, tr = np.empty(n, np.float32), np.empty(n, np.float32)
    act, dw = np.empty(n, np.int64), np.empty(4 * n, np.float64)
    fw, qw = np.empty(5 * n, np.float32), np.empty(n, np.int32)
    kernel(stack.ctypes.data, stack.shape[1], nbp, xs.ctypes.data, len(xs), float(lim[0]), float(lim[1]),
           c.ctypes.data, ns.ctypes.data, start.ctypes.data, end.ctypes.data, n, int(first), int(block),
           acc.ctypes.data, tr.ctypes.data, act.ctypes.data, dw.ctypes.data, fw.ctypes.data, qw.ctypes.data)
    return acc, tr
