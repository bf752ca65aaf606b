"""Warm starts for clouds that change from frame to frame: the previous frame's binned light as the
first guess of this frame's, so the shooting passes carry only the difference the new density makes.

The binned part of the solve (the light scattered after the peaked orders, and the sky) is the fixed
point ``R = T(u0) + T(a M R)``: ``u0`` the emission the peaked orders and the sky leave, ``T`` the
sweeps through this frame's medium, ``a M`` the scattering into the bins.  With a guess ``G``, the
remainder ``D = R - G`` solves the same equation with ``T(u0 + a M G) - G`` in place of ``T(u0)``: one
Jacobi pass sweeps ``u0 + a M G`` through the new medium (its catch ``C``), and the passes after it
shoot ``a M (C - G)``, the difference, signed.  Whatever the guess, the passes end where a cold
solve ends, to the same tolerance (no drift from frame to frame); a good guess leaves them little to
do.  The sun's beam and its peaked orders are computed afresh each frame (they follow the density
exactly: the silver lining).
"""

import numpy as np


def compatible(prev, sigma_shape, nb):
    """Whether solution ``prev`` can seed a solve of a grid of ``sigma_shape`` with ``nb`` bins."""
    return prev is not None and tuple(prev.sigma.shape) == tuple(sigma_shape) and len(prev.received) == nb


def on_box(a, from_origin, origin, shape):
    """``a`` (..., z, y, x) on the box at ``from_origin`` moved onto the box at ``origin`` of
    ``shape``: the voxels the two share, zero elsewhere (float32)."""
    out = np.zeros(a.shape[:-3] + tuple(shape), np.float32)
    lo = [max(p, q) for p, q in zip(origin, from_origin)]
    hi = [min(p + n, q + m) for p, n, q, m in zip(origin, shape, from_origin, a.shape[-3:])]
    if all(h > low for low, h in zip(lo, hi)):
        here = (Ellipsis,) + tuple(slice(p - o, q - o) for p, q, o in zip(lo, hi, origin))
        there = (Ellipsis,) + tuple(slice(p - o, q - o) for p, q, o in zip(lo, hi, from_origin))
        out[here] = a[there]
    return out


def guess(prev, origin, sigma):
    """The previous frame's binned light (``received`` less its peaked orders: the light scattered
    after them and the sky's) on this frame's solved box (``origin`` (z y x), extinction ``sigma``);
    zero where the previous box did not reach, and in voxels empty now, which catch nothing (as a
    guess's light there, its scattering would be emission where no sweep takes it: the sweeps carry
    the light of non-empty voxels only).  float32 (nb, ...)."""
    binned = prev.received - prev.received_peaked.sum(0, dtype=np.float32)
    out = on_box(binned, prev.origin, origin, sigma.shape)
    out *= sigma > 0
    return out


def moments(prev, origin, sigma, like):
    """``prev``'s :attr:`.Solution.moments_binned` on this frame's box (zero in voxels empty now,
    as :func:`guess`), or None where they are not there or have another layout than ``like`` (this
    solve's unshot moments)."""
    m = getattr(prev, "moments_binned", None)
    if m is None or like is None or m.shape[:-3] != like.shape[:-3]:
        return None
    out = on_box(m, prev.origin, origin, sigma.shape)
    out *= sigma > 0
    return out
