"""Independent truths for plane-parallel scattering (not in core), shared by the
voxel-depth tests and ``benchmarks/bench_scatter.py``: single scattering of a
slab in closed form, Chandrasekhar's H-function of a semi-infinite isotropic
medium (iterated from its integral equation) and a small adding-doubling for
isotropic slabs at any sun angle.
"""

import numpy as np


def gauss01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def h_function(omega, n=200):
    """Chandrasekhar's H for isotropic scattering, from
    ``1/H(mu) = sqrt(1 - omega) + omega/2 int_0^1 mu' H(mu') / (mu + mu') dmu'``."""
    mu, w = gauss01(n)
    h = np.ones(n)
    for _ in range(5000):
        new = 1.0 / (np.sqrt(1 - omega) + 0.5 * omega * ((w * mu * h)[None] / (mu[:, None] + mu[None])).sum(1))
        done = np.max(np.abs(new - h)) < 1e-14
        h = new
        if done:
            break
    return lambda m: 1.0 / (np.sqrt(1 - omega) + 0.5 * omega * np.sum(w * mu * h / (m + mu)))


def single_scattering_r(omega, g, tau, mu0, n=64, nphi=256):
    """Once-scattered plane albedo of a slab (HG phase, collimated sun at ``mu0``):
    ``R1 = omega / (4 pi) int p(cos) mu / (mu + mu0) (1 - exp(-tau (1/mu0 + 1/mu))) dOmega``."""
    mu, w = gauss01(n)
    phi = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    s0 = np.sqrt(1 - mu0 * mu0)
    # sun travels down (-mu0); scattered upward at (mu, phi)
    cos = -mu0 * mu[:, None] + s0 * np.sqrt(1 - mu[:, None] ** 2) * np.cos(phi)[None]
    p = (1 - g * g) / (1 + g * g - 2 * g * cos) ** 1.5
    ang = (mu / (mu + mu0) * (1 - np.exp(-tau * (1 / mu0 + 1 / mu))))[:, None]
    return omega / (4 * np.pi) * np.sum(w[:, None] * p * ang) * 2 * np.pi / nphi


def adding_doubling_iso(tau, omega, mu0, n=32, doublings=30):
    """(R, T) plane albedo and total transmission of an isotropic slab, collimated sun at ``mu0``.

    Azimuth-averaged radiances on ``n`` Gauss nodes; a layer ``tau / 2^doublings``
    thin is doubled up.  Checks: the H-function albedo of a thick slab to 1e-6;
    facts.md's tau=1 omega=1 (0.34130/0.65864) to 3e-5.
    """
    mu, w = gauss01(n)
    d = tau / 2.0 ** doublings
    r = omega * d * w[None] / (2 * mu[:, None])  # thin layer, diffuse in -> diffuse out
    t = np.diag(np.exp(-d / mu)) + r
    r0 = omega * d / (4 * np.pi * mu)  # thin layer, unit collimated irradiance in
    t0 = r0.copy()
    e = np.exp(-d / mu0)
    eye = np.eye(n)
    for _ in range(doublings):
        gm = np.linalg.inv(eye - r @ r)
        down = gm @ (t0 + e * (r @ r0))
        up = e * r0 + r @ down
        r0, t0 = r0 + t @ up, e * t0 + t @ down
        tg = t @ gm
        r, t = r + tg @ r @ t, tg @ t
        e = e * e
    flux = lambda v: 2 * np.pi * np.sum(w * mu * v) / mu0  # noqa: E731
    return flux(r0), flux(t0) + e
