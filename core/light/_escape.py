"""Closed forms for light emitted inside a voxel: escape fractions and centroids of
exponential (and Legendre P2) source profiles, in the sweeps' float32.

The sweeps (:mod:`._sweep`) spend their time in these elementwise functions over
(beams x plane) float32 arrays, at a few tenths of a ns per value each: NumPy's float32
``exp``, ``expm1`` and ``tanh`` are all vectorised (0.35-0.5 ns per value here, NumPy 1.26
and 2.5) while ``np.where`` costs 2-3 ns and a Python float operand makes float32
arithmetic ~3x slower than a float32 one.  So the helpers below use ``expm1``/``tanh``
instead of series behind ``where``, and float32 constants.
"""

import numpy as np


def _phi(x):
    """``(1 - exp(-x)) / x`` for ``x >= 0`` (1 at 0), in ``x``'s float type: ``-expm1(-x) / x``
    (about 1 ulp; ``x`` raised to the smallest normal number so 0 gives 1)."""
    x = np.asarray(x)
    t = x.dtype.type if x.dtype.kind == "f" else np.float64
    n = -np.maximum(x, t(np.finfo(t).tiny))
    return np.expm1(n) / n


def _transport_factors(tau):
    """``exp(-tau)`` and the mean escape ``(1 - exp(-tau)) / tau`` (1 at tau = 0), overflow-safe."""
    return np.exp(-tau), _phi(tau)


def _exp_source_escape(tau, beta):
    """Escape fraction of a source ``~ exp(-beta v)`` along a path ``v in [0, 1]`` of optical depth ``tau``.

    ``esc = int exp(-beta v - tau (1 - v)) dv / int exp(-beta v) dv``, written as
    ``exp(min(0, beta) - min(tau, beta)) phi(|beta - tau|) / phi(|beta|)`` with
    ``phi(x) = (1 - e^-x) / x`` so no exponential overflows for any ``beta`` (either
    sign) or ``tau``.  ``beta = 0`` gives the uniform source's ``(1 - e^-tau) / tau``.
    """
    zero = np.asarray(beta).dtype.type(0)
    return np.exp(np.minimum(beta, zero) - np.minimum(tau, beta)) * _phi(np.abs(beta - tau)) / _phi(np.abs(beta))


def _escape_centroid(tau, beta):
    """:func:`_exp_source_escape` (clipped to [0, 1]) and the source's centroid along the path
    ``0.5 + _offset(beta)``, for float32 arrays, sharing ``expm1(-|beta|)``: from ``|beta| = 0.5``
    on ``_offset(|b|) = 1/|b| + 1/expm1(-|b|) + 1/2``, below it the series (skipped where no
    ``|beta|`` reaches 0.5)."""
    f1, half, tiny = np.float32(1), np.float32(0.5), np.float32(np.finfo(np.float32).tiny)
    a = np.abs(beta)
    na = -np.maximum(a, tiny)
    ma = np.expm1(na)
    nd = -np.maximum(np.abs(beta - tau), tiny)
    esc = np.exp(np.minimum(beta, np.float32(0)) - np.minimum(tau, beta)) * (np.expm1(nd) / nd) * (na / ma)
    k2 = beta * beta
    vs = beta * (np.float32(-1 / 12) + k2 * (np.float32(1 / 720) - k2 * np.float32(1 / 30240)))
    if a.size and a.max() >= half:
        big = np.copysign(f1 / ma - f1 / na + half, -beta)  # _offset(|b|) <= 0, odd in b
        vs = big + (a < half) * (vs - big)  # a blend, not np.where
    return np.clip(esc, np.float32(0), f1, out=esc), vs + half



def _offset(kappa):
    """Centroid offset ``1/k - 1/(e^k - 1) - 1/2 = 1/k - 1/(2 tanh(k/2))`` (in ``(-1/2, 1/2)``,
    odd in ``k``) of a source ``exp(-k u)`` on ``u in [0, 1]``; overflow-safe for any ``k``.

    From ``|k| = 0.5`` on the tanh form (float32 error < 3e-7); below it the series
    ``-k/12 + k^3/720 - k^5/30240`` (error < 7e-9) avoids the cancellation.
    """
    k = np.asarray(kappa)
    f = k.dtype.type if k.dtype.kind == "f" else np.float64
    a = np.abs(k)
    kc = np.copysign(np.maximum(a, f(0.5)), k)
    big = f(1) / kc - f(0.5) / np.tanh(f(0.5) * kc)
    k2 = k * k
    series = k * (f(-1 / 12) + k2 * (f(1 / 720) - k2 * f(1 / 30240)))
    return big + (a < f(0.5)) * (series - big)  # a blend, not np.where (~3 ns per value)


def _variance(kappa, e=None):
    """Variance of a source ``exp(-k u)`` on ``u in [0, 1]`` (1/12 at k = 0, even in k):
    ``1/k^2 - e / (1 - e)^2`` with ``e = exp(-|k|)`` (pass it if known: the sweeps keep the
    transmittances), no overflow; below ``|k| = 0.5`` the series ``1/12 - k^2/240 + k^4/6048``
    (error < 1e-7) avoids the cancellation."""
    k = np.asarray(kappa)
    f = k.dtype.type if k.dtype.kind == "f" else np.float64
    a = np.abs(k)
    e = np.minimum(np.exp(-a) if e is None else e, f(np.exp(-0.5)))  # the closed form at |k| >= 0.5 only
    ac = np.maximum(a, f(0.5))
    big = f(1) / (ac * ac) - e / np.square(f(1) - e)
    k2 = k * k
    series = f(1 / 12) - k2 * (f(1 / 240) - k2 * f(1 / 6048))
    return big + (a < f(0.5)) * (series - big)


def _second_moment(kappa):
    """``E[(u - 1/2)^2]`` of a source ``exp(-k u)`` on ``u in [0, 1]``: :func:`_variance` plus
    :func:`_offset` squared."""
    return _variance(kappa) + np.square(_offset(kappa))


# (-1)^n c_n / n!, c_n = int_0^1 P2(2w - 1) w^n dw (c_0 = c_1 = 0): the series of _p2_escape
_P2_SERIES = [(-1.0) ** n * (6 / (n + 3) - 6 / (n + 2) + 1 / (n + 1)) / np.prod(np.arange(1, n + 1, dtype=float))
              for n in range(2, 11)]


def _p2_escape(tau, e=None):
    """``int_0^1 P2(2v - 1) exp(-tau (1 - v)) dv`` (``P2`` the Legendre polynomial, on the voxel):
    how much a source's second-moment term ``q P2`` adds to its escape over an optical depth
    ``tau >= 0`` (``P2`` has no power and no first moment, so it moves neither).  Closed form
    ``(T^2 - 6T + 12 - e (T^2 + 6T + 12)) / T^3``, ``e = exp(-T)`` (pass it if known), from
    ``T = 1`` on; below it the series ``sum_n (-T)^n c_n / n!`` (``~T^2 / 60``; float32 error
    < 5e-7, on values up to 0.04)."""
    t = np.asarray(tau)
    f = t.dtype.type if t.dtype.kind == "f" else np.float64
    a = np.clip(t, f(1), f(1e12))  # (at 1e12, ~1/T: 1e-12, and no overflow in T^3)
    e = np.minimum(np.exp(-t) if e is None else e, f(np.exp(-1.0)))
    a2 = a * a
    big = (a2 - f(6) * a + f(12) - e * (a2 + f(6) * a + f(12))) / (a2 * a)
    ts = np.minimum(t, f(1))
    series = f(_P2_SERIES[-1])
    for c in _P2_SERIES[-2::-1]:
        series = series * ts + f(c)
    series = series * ts * ts
    return big + (t < f(1)) * (series - big)


_KGRID = np.sinh(np.linspace(-np.arcsinh(400.0), np.arcsinh(400.0), 2001))
_OGRID = _offset(_KGRID)
# the inverse tabulated on 2^16 equal steps of the offset, for a lookup without a search
# (np.interp's binary search: 75 ns per value; this: a few); |rate| <= 400 as on _KGRID
_DLO, _DHI = float(_OGRID[-1]), float(_OGRID[0])
_DSCALE = np.float32((1 << 16) / (_DHI - _DLO))
_RTAB = np.interp(-(_DLO + np.arange((1 << 16) + 2) * (_DHI - _DLO) / (1 << 16)), -_OGRID, _KGRID).astype(np.float32)
_RSTEP = np.diff(_RTAB)


def _rate_of_offset(delta):
    """Inverse of :func:`_offset`: the exponential rate (float32) whose source has centroid offset
    ``delta``; linear between 2^16 + 1 tabulated offsets (``_offset`` of the result is within
    1.5e-6 of ``delta`` for ``|delta| < 0.49``, as with np.interp on ``_KGRID``)."""
    x = (np.clip(np.asarray(delta, np.float32), np.float32(_DLO), np.float32(_DHI)) - np.float32(_DLO)) * _DSCALE
    i = x.astype(np.int32)
    return _RTAB[i] + (x - i.astype(np.float32)) * _RSTEP[i]


