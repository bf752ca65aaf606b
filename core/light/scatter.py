"""Multiple scattering in a cloud: the 96-bin volume radiosity solve of Fig. 6.

Method
------
Each voxel keeps, for each of the 96 direction bins (:mod:`.phase`), the
``received`` flux (power intercepted by its droplets), the ``total`` flux
passing through it, and the ``unshot`` scattered flux not yet propagated.

* The sun is a parallel beam swept through the grid first.  Its first
  scattering is *not* binned for rendering: at render time each voxel adds
  ``albedo * R_sun * p(sun . view) / V`` with the exact phase function, so the
  narrow forward lobe (silver lining) is sharp.  For further scattering the
  sun's received flux is distributed over the bins with exact integrals of the
  phase function about the true sun direction (:func:`.phase.direct_fractions`),
  on 4x4 sub-directions per bin.  That once-scattered flux, and the
  twice-scattered flux it makes, are still peaked inside their bins, so they
  are swept on weighted sub-directions, intercepted per sub-direction and
  scattered again from each sub-direction (:func:`.phase.sub_phase_matrix`)
  and, at render time, toward the viewer with the same weights.
* Skylight (constant radiance from the upper hemisphere) enters through the
  boundary as 96 binned beams and is received like scattered flux.
* Shooting passes (Gauss-Seidel by groups of bins): all voxels shoot the unshot
  flux of a group of bins at once.  For each bin, 2x2 (``sub``) sub-directions
  carry the flux, each swept through the grid layer by layer along the
  dominant axis (a discrete-ordinates sweep): in each layer a beam loses
  ``1 - exp(-sigma l)`` (``l`` = path length across the layer) to ``received``,
  a voxel's own emission escapes its voxel with the exact mean transmission
  ``(1 - exp(-tau)) / tau``, and the beam moves sideways by its transverse
  offset with bilinear weights.  Sub-directions plus bilinear spreading spread
  a bin's flux over its solid angle, which reduces ray effects.  The received
  flux of the group is scattered at once by the 96x96 phase matrix into unshot,
  times the albedo.  Passes repeat until the unshot power falls below
  ``tol`` times the power that entered the cloud, or ``max_passes``.

Cost: one pass shoots all N voxels in all 96 bins with ``96 * sub^2`` sweeps of
O(N) work each, i.e. O(N) per pass for all O(N^2) voxel-to-voxel interactions
(Max 1994 amortises them to O(N log N)); the number of passes depends on the
optical thickness and albedo, not on N.  Memory: a few 96 x N float arrays.

Rendering (:func:`view_source`, :func:`render`): the in-scattered radiance
toward a camera per unit length at each voxel is
``S = albedo / V * (R_sun p(sun . w) + sum_j R_j pbar_j(w))`` with ``w`` the
direction from the voxel to the camera and ``pbar_j`` the phase function
averaged over bin ``j``; an emission-absorption ray march of ``S`` and the
extinction gives the image.

Conventions: arrays ``(nz, ny, nx)``, voxel centres at ``(i+.5) dx`` in the box
``[0,Lx]x[0,Ly]x[0,Lz]``; ``sun_dir`` points *toward* the sun; the sun's
irradiance is per unit area perpendicular to its rays.

References
----------
N. Max, R. Crawfis, "Advances in Scientific Visualization" ("Cloud rendering").
N. Max, "Efficient light propagation for multiple anisotropic volume
scattering", Eurographics Rendering Workshop 1994.
M. F. Cohen et al., "A progressive refinement approach to fast radiosity
image generation", SIGGRAPH 1988.
K. D. Lathrop, "Ray effects in discrete ordinates equations", Nucl. Sci. Eng. 32 (1968).
"""

import json
import os
from dataclasses import dataclass, field

import numpy as np

from . import phase
from ..errors import DataError
from ..files import atomic_write

NB = phase.NBINS


# --------------------------------------------------------------------------- sweeps

def _transport_factors(tau):
    """``exp(-tau)`` and the mean escape ``(1 - exp(-tau)) / tau`` (1 at tau = 0), overflow-safe."""
    t = np.exp(-tau)
    small = tau < 1e-6
    esc = np.where(small, 1.0 - 0.5 * tau, -np.expm1(-tau) / np.where(small, 1.0, tau))
    return t, esc


def _phi(x):
    """``(1 - exp(-x)) / x`` for ``x >= 0`` (1 at 0), overflow-safe."""
    x = np.maximum(x, 1e-30)  # expm1 is exact to first order: 1 at 0
    return -np.expm1(-x) / x


def _exp_source_escape(tau, beta):
    """Escape fraction of a source ``~ exp(-beta v)`` along a path ``v in [0, 1]`` of optical depth ``tau``.

    ``esc = int exp(-beta v - tau (1 - v)) dv / int exp(-beta v) dv``, written as
    ``exp(min(0, beta) - min(tau, beta)) phi(|beta - tau|) / phi(|beta|)`` with
    ``phi(x) = (1 - e^-x) / x`` so no exponential overflows for any ``beta`` (either
    sign) or ``tau``.  ``beta = 0`` gives the uniform source's ``(1 - e^-tau) / tau``.
    """
    return np.exp(np.minimum(0.0, beta) - np.minimum(tau, beta)) * _phi(np.abs(beta - tau)) / _phi(np.abs(beta))


def _shift_indices(n, shift, periodic, margin):
    """Gather indices and weights moving a beam by ``shift`` cells (bilinear in 1-D)."""
    i0 = np.floor(shift).astype(np.int64)
    f = shift - i0
    base = np.arange(n)[None, :] - i0[:, None]  # new[c] = (1-f) old[c-i0] + f old[c-i0-1]
    if periodic:
        return base % n, (base - 1) % n, 1.0 - f, f
    return base + margin, base - 1 + margin, 1.0 - f, f


def _offset(kappa):
    """Centroid offset ``1/k - 1/(e^k - 1) - 1/2 = 1/k - 1/(2 tanh(k/2))`` (in ``(-1/2, 1/2)``,
    odd in ``k``) of a source ``exp(-k u)`` on ``u in [0, 1]``; overflow-safe for any ``k``."""
    small = np.abs(kappa) < 1e-2
    k = np.where(small, 1.0, kappa)
    return np.where(small, -kappa / 12.0, 1.0 / k - 0.5 / np.tanh(0.5 * k))


_KGRID = np.sinh(np.linspace(-np.arcsinh(400.0), np.arcsinh(400.0), 2001))
_OGRID = _offset(_KGRID)


def _rate_of_offset(delta):
    """Inverse of :func:`_offset`: the exponential rate whose source has centroid offset ``delta``."""
    return np.interp(-delta, -_OGRID, _KGRID).astype(np.float32)


def _sweep(sigma, h, dirs, wsub, emis, inflow, periodic, axis, cache=None, per_sub=False, profile=None,
           moments=False, fresh=True):
    """Sweep a group of beams through ``sigma`` layer by layer along array ``axis``.

    ``dirs`` (g, ns, 3): ``ns`` sub-directions for each of ``g`` bins, all with
    the same sign along the sweep; ``wsub`` (g, ns): share of the bin's flux
    each carries; ``emis`` (g, nz, ny, nx) or None: unshot power per bin and
    voxel; ``inflow`` (g, ns): beam power per transverse cell entering from
    outside (upstream face and non-periodic sides).
    ``cache``: a dict kept between calls with the same beams; it stores the
    per-layer transmittances (float32) so later passes skip the exponentials.

    Sources inside a voxel are not spread evenly: with ``profile = (kappa, delta)``
    (each (3, nz, ny, nx), x y z) the emission in a voxel falls as
    ``exp(-kappa . u)`` over the voxel's unit cube ``u``, ``delta`` its centroid
    offset (:func:`_offset` of ``kappa``).  Along a beam ``d`` crossing the layer
    (path length ``l``, optical depth ``tau``) ``u`` moves by ``c = l d / h``, so the
    source falls as ``exp(-beta v)``, ``beta = kappa . c``, and escapes with
    :func:`_exp_source_escape`; without a profile the uniform ``(1 - e^-tau)/tau``.
    ``moments``: also return the first moment of the received power about each
    voxel's centre (3, nz, ny, nx; in voxel units, x y z, summed over beams): a beam
    deposits ``exp(-tau v)``, centroid ``_offset(tau) c``; the power a source keeps in
    its own voxel sits downstream of the source's centroid (closed form below).
    With a ``cache``, the profile's escape fractions are kept too and reused unless ``fresh``.
    Returns received (g, ...) (``per_sub``: (g, ns, ...) per sub-direction),
    total (g, ...), the exit power (g,) through the far face and the moments (or None).
    """
    g, ns, _ = dirs.shape
    d = dirs.reshape(-1, 3)
    comp = 2 - axis  # xyz component along the sweep
    others = [a for a in range(3) if a != axis]
    sig = np.moveaxis(sigma, axis, 0)
    sig32 = sig.astype(np.float32) if profile is not None else None
    L, A, B = sig.shape
    ca, cb = 2 - others[0], 2 - others[1]
    dl = d[:, comp]
    sign = np.sign(dl[0])
    if sign == 0 or np.any(np.sign(dl) != sign):
        raise ValueError("_sweep: beams must share the sign of the sweep component")
    ell = h[comp] / np.abs(dl)  # path length across one layer
    cross = (ell[:, None] * d / np.asarray(h, float)[None]).astype(np.float32)  # (K, 3) unit-cube move per layer
    sa = d[:, ca] / np.abs(dl) * (h[comp] / h[ca])
    sb = d[:, cb] / np.abs(dl) * (h[comp] / h[cb])
    pa, pb = periodic[ca], periodic[cb]
    ma = 0 if pa else int(np.ceil(np.max(np.abs(sa)))) + 1
    mb = 0 if pb else int(np.ceil(np.max(np.abs(sb)))) + 1
    ia0, ia1, wa0, wa1 = _shift_indices(A, sa, pa, ma)
    ib0, ib1, wb0, wb1 = _shift_indices(B, sb, pb, mb)
    K = g * ns
    kk = np.arange(K)[:, None]
    kb = kk[:, :, None]
    ar = np.arange(A)[None, :, None]
    wa0, wa1, wb0, wb1 = (x[:, None, None] for x in (wa0, wa1, wb0, wb1))
    recv = np.zeros((g, ns, L, A, B) if per_sub else (g, L, A, B), np.float32)
    total = np.zeros((g, L, A, B), np.float32)
    mom = np.zeros((3, L, A, B), np.float32) if moments else None
    em = None if emis is None else np.moveaxis(emis, axis + 1, 1)
    if profile is not None:
        kap = np.moveaxis(np.asarray(profile[0], np.float32), axis + 1, 1)
        dlt = np.moveaxis(np.asarray(profile[1], np.float32), axis + 1, 1)
    pad = np.asarray(inflow, dtype=np.float32).reshape(K, 1, 1)
    beam = np.broadcast_to(pad, (K, A, B)).copy()
    w = np.asarray(wsub, dtype=np.float32).reshape(g, ns, 1, 1)
    wa0, wa1, wb0, wb1 = (x.astype(np.float32) for x in (wa0, wa1, wb0, wb1))
    ell32 = ell.astype(np.float32)[:, None, None]
    order = range(L) if sign > 0 else range(L - 1, -1, -1)
    for n, k in enumerate(order):
        if n:  # move to this layer: bilinear transverse shift, inflow outside the grid
            if ma:
                beam = np.concatenate([np.broadcast_to(pad, (K, ma, B)), beam, np.broadcast_to(pad, (K, ma, B))], 1)
            beam = wa0 * beam[kk, ia0] + wa1 * beam[kk, ia1]
            if mb:
                beam = np.concatenate([np.broadcast_to(pad, (K, A, mb)), beam, np.broadcast_to(pad, (K, A, mb))], 2)
            beam = wb0 * beam[kb, ar, ib0[:, None, :]] + wb1 * beam[kb, ar, ib1[:, None, :]]
        if cache is not None and k in cache:
            t, esc, offb = cache[k]
        else:
            tau = sig[k][None] * ell[:, None, None]
            t, esc = _transport_factors(tau)
            t, esc, offb = t.astype(np.float32), esc.astype(np.float32), _offset(tau).astype(np.float32)
            if cache is not None:
                cache[k] = (t, esc, offb)
        if em is None:
            r = beam * (1.0 - t)
            tot = beam
            beam = beam * t
        else:
            if profile is not None:
                tau = sig32[k][None] * ell32
                if cache is not None and ("p", k) in cache and not fresh:
                    esc, shift = cache[("p", k)]
                else:
                    beta = (cross @ kap[:, k].reshape(3, -1)).reshape(K, A, B)
                    esc = np.clip(_exp_source_escape(tau, beta), 0.0, 1.0)
                    if moments:
                        # what a source keeps sits downstream of it: with v_s its centroid along
                        # the path, the photons' mean end point v_s + (1 - esc) / tau (escapers
                        # stop at 1) gives the kept part's centroid x = (v_s - esc) / (1 - esc) + 1 / tau
                        vs = 0.5 + _offset(beta)
                        kept = np.maximum(1.0 - esc, 1e-30)
                        shift = np.where(tau < 1e-2, 1.0 / 6.0, (vs - esc) / kept + 1.0 / np.maximum(tau, 1e-2) - vs)
                    else:
                        shift = None
                    if cache is not None:
                        cache[("p", k)] = (esc, shift)
            e = (em[:, k][:, None] * w).reshape(K, A, B)
            rb = beam * (1.0 - t)
            re = e * (1.0 - esc)
            r = rb + re
            tot = beam + e
            beam = beam * t + e * esc
        if moments:
            rb = r if em is None else rb
            mk = (cross.T @ (rb * offb).reshape(K, -1)).reshape(3, A, B)
            if em is not None and profile is not None:
                mk += dlt[:, k] * re.sum(0) + (cross.T @ (re * shift).reshape(K, -1)).reshape(3, A, B)
            mom[:, k] = mk
        if per_sub:
            recv[:, :, k] = r.reshape(g, ns, A, B)
        else:
            recv[:, k] = r.reshape(g, ns, A, B).sum(1)
        total[:, k] = tot.reshape(g, ns, A, B).sum(1)
    exit_power = beam.reshape(g, ns, A, B).sum((1, 2, 3), dtype=np.float64)
    if moments:
        mom = np.moveaxis(mom, 1, axis + 1)
    return np.moveaxis(recv, -3, axis - 3), np.moveaxis(total, 1, axis + 1), exit_power, mom


# --------------------------------------------------------------------------- solve

@dataclass
class Progress:
    """What :func:`solve_steps` yields: ``pass_index`` (0 = sun and sky), bins
    done in this pass, and ``residual`` = unshot / power that entered the cloud."""

    pass_index: int
    group: int
    groups: int
    residual: float


@dataclass
class Solution:
    """Result of :func:`solve` (all arrays ``(…, nz, ny, nx)``, float32).

    Attributes
    ----------
    sigma : extinction per unit length.
    size : box size (Lx, Ly, Lz).
    received : (96, …) power intercepted per bin from scattered light and sky.
    total : (96, …) power passing through each voxel per bin (the paper's 'total' flux).
    received_sun : power intercepted from the direct sun beam.
    received_peaked : (2, 96, …) the parts of ``received`` scattered once and twice (sun light).
    peaked_weights : (2, 96, s*s) how those are distributed over the sub-directions of each bin.
    unshot : (96, …) scattered power left unpropagated when the solve stopped.
    exit_flux : (96,) power leaving the grid through the far face of each bin's sweep.
    sun_exit : direct sun power leaving through the far face of the sun sweep.
    injected : power that entered the cloud (first interception of sun and sky).
    passes, residual, converged, history : the convergence report.
    albedo_binned, g_binned, delta_f : albedo, asymmetry and delta-M fraction of the
        scaled medium the binned flux was transported in; ``received`` is in that medium,
        except the first ``real_orders`` of ``received_peaked``, caught in the real medium.
    """

    sigma: np.ndarray
    size: tuple
    albedo: float
    g: float
    sun_dir: tuple
    sun_irradiance: float
    sky_radiance: float
    received: np.ndarray
    total: np.ndarray
    received_sun: np.ndarray
    received_peaked: np.ndarray
    peaked_weights: np.ndarray
    unshot: np.ndarray
    exit_flux: np.ndarray
    sun_exit: float
    injected: float
    passes: int
    residual: float
    converged: bool
    history: list = field(default_factory=list)
    sub: int = 2
    periodic: tuple = (False, False, False)
    albedo_binned: float = 0.0
    g_binned: float = 0.0
    delta_f: float = 0.0
    real_orders: int = 0

    @property
    def report(self):
        """One line: passes, residual, converged or stopped at the pass limit."""
        state = "converged" if self.converged else "stopped at the pass limit (not converged)"
        return f"{self.passes} passes, residual {self.residual:.3g} of the entered power: {state}"


def _groups(periodic, sub):
    """Bins grouped by (array axis of the sweep, sign); sub-directions and weights."""
    cen, omega, dirs, w = phase.bins(sub)
    free = [c for c in range(3) if not periodic[c]]
    if not free:
        raise ValueError("solve: at least one axis must be non-periodic")
    keys = {}
    for b in range(NB):
        c = max(free, key=lambda c: abs(cen[b, c]))
        keys.setdefault((2 - c, float(np.sign(cen[b, c]))), []).append(b)
    groups = [(axis, np.array(bs)) for (axis, _), bs in sorted(keys.items())]
    return groups, dirs, w / omega[:, None], w


def _check_inputs(sigma, size, albedo, g, sun_dir, sun_irradiance, sky_radiance):
    sigma = np.asarray(sigma)
    if sigma.ndim != 3 or min(sigma.shape) < 1:
        raise DataError(f"extinction must be a 3-D array, got shape {sigma.shape}", field="sigma")
    if not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
        raise DataError("extinction must be finite and >= 0 everywhere", field="sigma")
    size = tuple(float(s) for s in size)
    if len(size) != 3 or min(size) <= 0:
        raise DataError(f"box size must be three positive lengths, got {size}", field="size")
    if not 0.0 <= albedo <= 1.0:
        raise DataError(f"albedo must be in [0, 1], got {albedo}", field="albedo")
    if not -1.0 < g < 1.0:
        raise DataError(f"asymmetry g must be in (-1, 1), got {g}", field="g")
    s = np.asarray(sun_dir, dtype=np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.linalg.norm(s) == 0:
        raise DataError(f"sun direction must be a non-zero 3-vector, got {sun_dir}", field="sun_dir")
    if sun_irradiance < 0 or sky_radiance < 0:
        raise DataError("sun irradiance and sky radiance must be >= 0", field="sun")
    return sigma.astype(np.float64), size, s / np.linalg.norm(s)


def _scatter_into(unshot, m_cols, recv, albedo, chunk=1 << 16):
    """``unshot += albedo * M[:, group] @ recv`` in float32 chunks (memory stays small);
    ``m_cols`` (96, k) with ``recv`` (k, ...): k bins, or bins x sub-directions."""
    g = m_cols.shape[1]
    u = unshot.reshape(NB, -1)
    r = recv.reshape(g, -1)
    m = (albedo * m_cols).astype(np.float32)
    for s in range(0, r.shape[1], chunk):
        u[:, s:s + chunk] += m @ r[:, s:s + chunk].astype(np.float32)


def solve_steps(sigma, size, *, albedo=0.99, g=0.8, sun_dir=(0.0, 0.0, 1.0), sun_irradiance=1.0,
                sky_radiance=0.0, tol=1e-3, max_passes=100, sub=2, periodic=(False, False, False),
                delta_m=True, phase_sub=6, first_sub=4, source_profile=True,
                peaked_orders=2, real_orders=1, profile_every=1):
    """The shooting solve as a generator: yields :class:`Progress` after each group of bins,
    returns the :class:`Solution` (``StopIteration.value``; :func:`solve` unwraps it).

    Parameters
    ----------
    sigma : (nz, ny, nx) extinction per unit length (>= 0, finite).
    size : (Lx, Ly, Lz) box size.
    albedo : single-scattering albedo in [0, 1].
    g : Henyey-Greenstein asymmetry in (-1, 1).
    sun_dir : direction toward the sun.
    sun_irradiance : sun power per unit area perpendicular to its rays.
    sky_radiance : constant radiance of the sky (light travelling downward).
    tol : stop when unshot power <= tol * entered power.
    max_passes : stop after this many passes even if not converged (see ``Solution.report``).
    sub : sub-directions per bin side in the sweeps (flux spread over the bin).
    periodic : (x, y, z) periodic axes (slabs); at least one axis must not be.
    delta_m : transport the binned flux in the delta-M scaled medium (Wiscombe 1977):
        the fraction ``f = g^4`` (g > 0) of scattering inside the forward peak counts as
        unscattered, ``sigma* = sigma (1 - albedo f)``, ``albedo* = albedo (1-f)/(1-albedo f)``,
        ``g* = (g - f)/(1 - f)``; the smooth remainder suits 96 bins.  The sun's first
        scattering toward a viewer stays exact (unscaled medium, full HG).  On the
        slab tests ``f = g^4`` beat ``g^2`` (too much truncation for thin slabs) and
        ``g^8`` / no scaling (thick slabs), and it needs fewer passes.
    phase_sub : sub-squares per bin side for the phase matrix integrals.
    profile_every : after pass 8, recompute the escape fractions of the unshot light's
        voxel profiles only every this many passes (cached between; the moments are
        tracked on every pass).  The profiles settle as passes go on, but slowly deep
        inside: isotropic slab tau 32, voxel tau 2, T -0.6% with 1 (default), -1.3% with 2;
        semi-infinite R +0.40% / +0.42%.  2 saves ~40% of a pass.
    peaked_orders : how many scattering orders of sunlight are shot per sub-direction
        (weighted inside each bin as the previous order filled it) before the rest is
        binned; at least 1.
    real_orders : how many of the peaked flights of scattered sunlight travel in the
        real medium and are scattered on with the full HG(g) (at most ``peaked_orders``);
        delta-M applies after them.
    source_profile : sources inside a voxel follow where the light was caught (an
        exponential profile; exact for the sun's first scattering) instead of being
        spread evenly, so optically thick voxels (tau ~ 1-2) keep their accuracy.
        False gives the even spread (for comparisons).
    first_sub : sub-directions per bin side (a divisor of 48) carrying the sun's first
        scattering (weighted by the exact phase function within each bin) and its second
        (weighted by the first's interceptions scattered per sub-direction).

    References
    ----------
    Max & Crawfis, "Cloud rendering"; Max 1994; Cohen et al. 1988; Wiscombe 1977;
    Nakajima & Tanaka, JQSRT 40 (1988) 51-69 (exact single scattering with delta-M).
    """
    sigma, size, sun = _check_inputs(sigma, size, albedo, g, sun_dir, sun_irradiance, sky_radiance)
    if int(peaked_orders) < 1:
        raise DataError(f"peaked_orders must be >= 1, got {peaked_orders}", field="peaked_orders")
    real_orders = min(int(real_orders), int(peaked_orders))
    if int(max_passes) < 1 or not tol > 0:
        raise DataError("max_passes must be >= 1 and tol > 0", field="tol")
    periodic = tuple(bool(p) for p in periodic)
    f = g ** 4 if (delta_m and g > 0) else 0.0
    sig_s = sigma * (1.0 - albedo * f)
    alb_s = albedo * (1.0 - f) / (1.0 - albedo * f) if albedo * f < 1 else 0.0
    g_s = (g - f) / (1.0 - f)
    shape = sigma.shape
    h = np.array(size) / np.array(shape[::-1])  # (dx, dy, dz)
    groups, dirs, wsub, wabs = _groups(periodic, sub)
    M = phase.phase_matrix(g_s, sub=phase_sub, transport_sub=sub)
    unshot = np.zeros((NB,) + shape, np.float32)
    received = np.zeros((NB,) + shape, np.float32)
    total = np.zeros((NB,) + shape, np.float32)
    exit_flux = np.zeros(NB)
    history = []

    # The sun: one parallel beam along its dominant non-periodic axis, swept in the
    # real medium (exact single scattering at render time) and, with delta-M, in the
    # scaled one (its scattering feeds the bins).
    prop = -sun
    free = [c for c in range(3) if not periodic[c]]
    c = max(free, key=lambda c: abs(prop[c]))
    if abs(prop[c]) < 1e-9:
        raise DataError("the sun must not shine parallel to the periodic layers", field="sun_dir")
    area = np.prod([h[o] for o in range(3) if o != c])
    inflow = np.array([[sun_irradiance * abs(prop[c]) * area]])

    def sun_sweep(sig):
        r, _, ex, _ = _sweep(sig, h, prop[None, None, :], np.ones((1, 1)), None, inflow, periodic, 2 - c)
        return r[0], float(ex[0])

    # The sun beam and its first scattering are exact (real medium, full HG(g)); only the
    # scattered light travels in the delta-M scaled medium.  Scattering the sun in the
    # scaled medium too (HG(g*) has more back-scatter than HG(g)) put the slab tau=1,
    # g=0.8 reflectance 9% high.
    r_sun, sun_exit = sun_sweep(sigma)
    injected = float(r_sun.sum())

    # The sun's first scattering, shot on first_sub x first_sub sub-directions per bin
    # weighted by the exact phase function about the true sun direction, so the
    # forward lobe keeps its shape inside its bins.  This once-scattered flux, and
    # the twice-scattered flux it makes, are still peaked inside their bins:
    # treating them as spread evenly over a bin (the 96x96 matrix) overstates the
    # next scattering's reflectance (slab tau=4, g=0.8 against adding-doubling:
    # R +0.0114 evenly, +0.0088 with order 1 per sub-direction, +0.0070 with
    # orders 1 and 2).  So both are intercepted per sub-direction and scattered
    # from each sub-direction's own direction (phase.sub_phase_matrix); order 2
    # is shot on sub-direction weights of each bin summed over the grid
    # (phase.sub_sub_phase_matrix applied to order 1's interceptions).
    qs = phase.direct_fractions(prop, g, sub=48, into_sub=first_sub)
    q = qs.sum(1)
    wq = np.where(q[:, None] > 1e-12, qs / np.maximum(q[:, None], 1e-300), 1.0 / qs.shape[1])
    fdirs = phase.bins(first_sub)[2]
    m_sub = phase.sub_phase_matrix(g_s, first_sub)  # (96, 96, first_sub**2)
    m_real = phase.sub_phase_matrix(g, first_sub) if real_orders > 0 else None
    per = max(1, (1 << 24) // (fdirs.shape[1] * sigma.size))  # bins per sweep: <= 64 MB of float32

    # Where inside its voxel the unshot light sits (issue 18): light is caught mostly
    # near the face it entered by, so a thick voxel's scattered light escapes more
    # easily back through that face.  ``umom`` is the first moment (voxel units, x y z)
    # of all unshot power about each voxel centre, shared by all bins; a group's
    # emission gets the exponential profile with that centroid (_rate_of_offset).
    # The sun's first scattering has its exact profile: the sun beam falls as
    # exp(-sigma* x_c / prop_c) along its sweep axis c, i.e. rate sigma* h_c / prop_c.
    umom = np.zeros((3,) + shape, np.float64) if source_profile else None

    def unshot_profile(power):
        if umom is None:
            return None
        dlt = np.clip(umom / np.where(power > 0, power, np.inf), -0.49, 0.49).astype(np.float32)
        return _rate_of_offset(dlt), dlt

    def keep_moments(mom, shot, prof, alb=alb_s):
        """Unshot moments after a sweep: less what was shot, plus albedo times what was caught."""
        if umom is not None:
            if prof is not None:
                umom[:] -= prof[1] * shot
            umom[:] += alb * mom

    if source_profile:
        kap = np.zeros((3,) + shape, np.float32)
        kap[c] = sigma * (h[c] / prop[c])
        sun_profile = (kap, np.zeros_like(kap))
        sun_profile[1][c] = _offset(kap[c])
    else:
        sun_profile = None

    def shoot_peaked(emission, weights, prof, real):
        """Shoot ``emission(bins)`` on the sub-directions with ``weights`` and the voxel
        source profile ``prof``; scatter per sub-direction.  ``real``: fly in the real
        medium and scatter with the full HG(g) (else the delta-M scaled medium)."""
        rec = np.zeros((NB,) + shape, np.float32)
        rsub = np.zeros(weights.shape)
        sig_k, m_k, alb_k = (sigma, m_real, albedo) if real else (sig_s, m_sub, alb_s)
        for axis, group in groups:
            for s in range(0, len(group), per):
                bs = group[s:s + per]
                r, tot, ex, mom = _sweep(sig_k, h, fdirs[bs], weights[bs], emission(bs), np.zeros(weights[bs].shape),
                                         periodic, axis, per_sub=True, profile=prof, moments=umom is not None)
                keep_moments(mom, 0.0, None, alb_k)
                rec[bs] = r.sum(1, dtype=np.float32)
                rsub[bs] = r.reshape(len(bs), r.shape[1], -1).sum(2, dtype=np.float64)
                total[bs] += tot.astype(np.float32)
                exit_flux[bs] += ex
                _scatter_into(unshot, m_k[:, bs].reshape(NB, -1), r.reshape((-1,) + shape), alb_k)
        received[:] += rec
        return rec, rsub

    rec, rsub = shoot_peaked(lambda bs: ((albedo * q[bs])[:, None] * r_sun.reshape(1, -1))
                             .reshape((len(bs),) + shape), wq, sun_profile, real_orders > 0)
    peaked, pweights = [rec], [wq]
    for k in range(1, int(peaked_orders)):
        wk = np.einsum("ibja,ja->ib", phase.sub_sub_phase_matrix(g if k <= real_orders else g_s, first_sub), rsub)
        wk = np.where(wk.sum(1, keepdims=True) > 0, wk / np.maximum(wk.sum(1, keepdims=True), 1e-300),
                      1.0 / wk.shape[1])
        nxt = unshot.copy()
        unshot[:] = 0.0
        prof = unshot_profile(nxt.sum(0, dtype=np.float64))
        if umom is not None:
            umom[:] = 0.0
        rec, rsub = shoot_peaked(lambda bs: nxt[bs], wk, prof, k < real_orders)
        peaked.append(rec)
        pweights.append(wk)
        del nxt, prof

    # The sky: binned beams entering through the boundary, travelling downward.
    if sky_radiance > 0:
        for axis, bs in groups:
            cc = 2 - axis
            down = dirs[bs][..., 2] < 0
            area = np.prod([h[o] for o in range(3) if o != cc])
            sky_in = sky_radiance * wabs[bs] * np.abs(dirs[bs][..., cc]) * area * down
            r, tot, ex, mom = _sweep(sig_s, h, dirs[bs], wsub[bs], None, sky_in, periodic, axis,
                                     moments=umom is not None)
            keep_moments(mom, 0.0, None)
            received[bs] += r.astype(np.float32)
            total[bs] += tot.astype(np.float32)
            exit_flux[bs] += ex
            injected += float(r.sum())
            _scatter_into(unshot, M[:, bs], r, alb_s)
    ref = max(injected, 1e-300)
    residual = float(unshot.sum(dtype=np.float64)) / ref
    history.append(residual)
    yield Progress(0, len(groups), len(groups), residual)

    passes = 0
    converged = residual <= tol
    # transmittance caches per group (float32, 3 or 5 x beams x voxels each) when they fit
    fits = (5 if source_profile else 3) * NB * dirs.shape[1] * sigma.size <= 1 << 27
    caches = [{} if fits else None for _ in groups]
    while not converged and passes < int(max_passes):
        passes += 1
        refresh = passes <= 8 or passes % int(profile_every) == 0
        for gi, (axis, bs) in enumerate(groups):
            shot = unshot[bs].sum(0, dtype=np.float64) if umom is not None else None
            prof = unshot_profile(unshot.sum(0, dtype=np.float64)) if umom is not None else None
            r, tot, ex, mom = _sweep(sig_s, h, dirs[bs], wsub[bs], unshot[bs], np.zeros(wsub[bs].shape),
                                     periodic, axis, caches[gi], profile=prof, moments=umom is not None,
                                     fresh=refresh)
            unshot[bs] = 0.0
            keep_moments(mom, shot, prof)
            received[bs] += r.astype(np.float32)
            total[bs] += tot.astype(np.float32)
            exit_flux[bs] += ex
            _scatter_into(unshot, M[:, bs], r, alb_s)
            residual = float(unshot.sum(dtype=np.float64)) / ref
            yield Progress(passes, gi + 1, len(groups), residual)
        history.append(residual)
        converged = residual <= tol
    return Solution(
        sigma=sigma.astype(np.float32), size=size, albedo=float(albedo), g=float(g),
        sun_dir=tuple(float(v) for v in sun), sun_irradiance=float(sun_irradiance),
        sky_radiance=float(sky_radiance), received=received, total=total,
        received_sun=r_sun.astype(np.float32), received_peaked=np.stack(peaked),
        peaked_weights=np.stack(pweights).astype(np.float32), unshot=unshot, exit_flux=exit_flux,
        sun_exit=sun_exit, injected=injected, passes=passes, residual=residual,
        converged=bool(converged), history=history, sub=int(sub), periodic=periodic,
        albedo_binned=float(alb_s), g_binned=float(g_s), delta_f=float(f), real_orders=real_orders)


def solve(sigma, size, progress=None, **kw):
    """Run :func:`solve_steps` to the end; ``progress(Progress)`` is called after each step.

    Returns
    -------
    Solution
    """
    gen = solve_steps(sigma, size, **kw)
    while True:
        try:
            p = next(gen)
        except StopIteration as stop:
            return stop.value
        if progress is not None:
            progress(p)


def slab_reflectance(sol):
    """(R, T) of a periodic slab lit from +z (sun overhead): diffuse power leaving the
    top, and diffuse plus unscattered power leaving the bottom, per incident power.

    Only meaningful for grids periodic in x and y (nothing leaves sideways).
    """
    cen = phase.bins(1)[0]
    s = np.asarray(sol.sun_dir)
    nz, ny, nx = sol.sigma.shape
    incident = sol.sun_irradiance * abs(s[2]) * sol.size[0] * sol.size[1]
    up = cen[:, 2] > 0
    r = sol.exit_flux[up].sum() / incident
    t = (sol.exit_flux[~up].sum() + sol.sun_exit) / incident
    return float(r), float(t)


# --------------------------------------------------------------------------- views

@dataclass(frozen=True)
class Camera:
    """A pinhole camera: ``fov`` is the horizontal field of view in radians
    (Blender: ``sensor_fit='HORIZONTAL'``, ``angle=fov``), image ``width x height``."""

    position: tuple
    target: tuple
    fov: float = np.radians(40.0)
    width: int = 128
    height: int = 96
    up: tuple = (0.0, 0.0, 1.0)

    def basis(self):
        """(forward, right, up) unit vectors."""
        f = np.asarray(self.target, float) - np.asarray(self.position, float)
        f /= np.linalg.norm(f)
        r = np.cross(f, np.asarray(self.up, float))
        if np.linalg.norm(r) < 1e-9:
            raise ValueError("Camera: view direction parallel to up")
        r /= np.linalg.norm(r)
        return f, r, np.cross(r, f)

    def rays(self):
        """Unit ray directions (height, width, 3), row 0 at the top of the image."""
        f, r, u = self.basis()
        t = np.tan(0.5 * self.fov)
        xs = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * t
        ys = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * t * self.height / self.width
        d = f[None, None] + xs[None, :, None] * r[None, None] + ys[:, None, None] * u[None, None]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def orbit_camera(angle, size=(1.0, 1.0, 0.75), *, distance=1.7, elevation=np.radians(15.0),
                 fov=np.radians(40.0), width=128, height=96):
    """A camera on a circle around the box centre, ``angle`` radians from +x, looking at the centre."""
    c = 0.5 * np.asarray(size, float)
    pos = c + distance * np.array([np.cos(angle) * np.cos(elevation), np.sin(angle) * np.cos(elevation),
                                   np.sin(elevation)])
    return Camera(tuple(pos), tuple(c), fov, int(width), int(height))


def _sun_view_escape(sol, w):
    """Per voxel, how much better the sun's first scattering escapes toward the viewer
    than a source spread evenly through the voxel (what the ray march assumes).

    The sun beam falls inside a voxel as ``exp(-sigma x_c / prop_c)`` along the sun
    sweep's axis ``c``; across the voxel toward the viewer ``w`` (path ``l = min_i
    h_i / |w_i|``, optical depth ``tau = sigma l``) that source escapes with
    :func:`_exp_source_escape` (``beta = sigma h_c / prop_c * l w_c / h_c``) instead of
    ``(1 - e^-tau) / tau``.  Without it a thick voxel's sunlit face was rendered too dark:
    single scattering off a slab seen from above -9% at voxel tau 1, -26% at 2 (sun overhead).
    """
    shape = sol.sigma.shape
    h = np.asarray(sol.size, float) / np.asarray(shape[::-1])
    prop = -np.asarray(sol.sun_dir, float)
    free = [c for c in range(3) if not sol.periodic[c]]
    c = max(free, key=lambda c: abs(prop[c]))
    with np.errstate(divide="ignore"):
        ell = np.min(h[None] / np.abs(w), axis=1)
    tau = sol.sigma.reshape(-1).astype(np.float64) * ell
    beta = tau * w[:, c] / prop[c]
    return _exp_source_escape(tau, beta) / _phi(tau)


def view_source(sol, camera_position, chunk=1 << 15):
    """In-scattered radiance per unit length toward ``camera_position`` at every voxel.

    ``S = albedo R_sun p(sun . w) / V + albedo / (1 - albedo f) sum_j R_j pbar_j(w) / V``
    with ``w`` the unit vector from the voxel centre to the camera: the exact
    first scattering of the sun plus the full phase function ``p`` (averaged
    over each bin) applied to the binned radiance ``R_j / (sigma* V Omega_j)``,
    ``sigma* = sigma (1 - albedo f)`` the delta-M scaled extinction the bins were
    transported in (multiple scattering and sky).  For the once- and twice-scattered
    parts of ``R_j`` (``received_peaked``) ``pbar_j`` weights the bin's
    sub-directions as the solve filled them (``peaked_weights``).

    Returns
    -------
    ndarray float32 (nz, ny, nx): emission coefficient for an emission-absorption render.
    """
    from ..volume.cloud_density import voxel_centres

    shape = sol.sigma.shape
    cam = np.asarray(camera_position, dtype=np.float64)
    if cam.shape != (3,) or not np.all(np.isfinite(cam)):
        raise ValueError(f"view_source: camera position must be a finite 3-vector, got {camera_position}")
    x, y, z = voxel_centres(shape, sol.size)
    pts = np.stack(np.broadcast_arrays(x, y, z), -1).reshape(-1, 3)
    w = cam[None] - pts
    nrm = np.linalg.norm(w, axis=1, keepdims=True)
    w = w / np.where(nrm > 0, nrm, 1.0)
    vol = np.prod(np.asarray(sol.size) / np.asarray(shape[::-1]))
    prop = -np.asarray(sol.sun_dir)
    out = sol.albedo * sol.received_sun.reshape(-1) * phase.hg(w @ prop, sol.g)
    out *= _sun_view_escape(sol, w)
    rec = sol.received.reshape(NB, -1)
    # Binned radiance in the real medium: L_j = R_j / (sigma* V Omega_j) with
    # sigma* = sigma (1 - albedo f), scattered by the full HG(g) of the real medium.
    diffuse = sol.albedo / (1.0 - sol.albedo * sol.delta_f) if sol.albedo * sol.delta_f < 1 else 0.0
    peaked = sol.received_peaked.reshape(len(sol.received_peaked), NB, -1)
    fw = np.asarray(sol.peaked_weights, np.float64)
    sub = int(round(np.sqrt(fw.shape[2])))
    for s in range(0, len(pts), chunk):
        ww = w[s:s + chunk]
        rest = rec[:, s:s + chunk] - peaked[:, :, s:s + chunk].sum(0)
        acc = np.einsum("nj,jn->n", phase.bin_phase_toward(ww, sol.g), rest)
        out[s:s + chunk] += diffuse * acc
        for k in range(len(peaked)):
            pk = phase.bin_phase_toward(ww, sol.g, res=48, sub=sub, weights=fw[k])
            # flights in the real medium: L_j = R_j / (sigma V Omega_j), scattered by albedo
            fac = sol.albedo if k < sol.real_orders else diffuse
            out[s:s + chunk] += fac * np.einsum("nj,jn->n", pk, peaked[k][:, s:s + chunk])
    return (out / vol).reshape(shape).astype(np.float32)


def _trilinear(grid, idx):
    """Trilinear samples of ``grid`` (nz, ny, nx) at fractional voxel-centre indices
    ``idx`` (..., 3) as (i, j, k); zero beyond half a voxel outside the grid."""
    from scipy.ndimage import map_coordinates

    g = np.pad(grid, 1)
    coords = [idx[..., 2] + 1.0, idx[..., 1] + 1.0, idx[..., 0] + 1.0]
    return map_coordinates(g, coords, order=1, mode="constant", cval=0.0, prefilter=False)


def render(sigma, source, size, camera, *, step=0.4, background=0.0, chunk=8192):
    """Emission-absorption ray march: ``L = int S T ds + T_total * background`` per pixel.

    ``sigma`` and ``source`` are voxel values interpolated trilinearly (as Cycles
    samples a VDB grid); steps of ``step`` voxels, each segment integrated
    exactly for piecewise constant values.

    Returns
    -------
    ndarray float32 (height, width).
    """
    sigma = np.asarray(sigma, np.float64)
    source = np.asarray(source, np.float64)
    if sigma.shape != source.shape or sigma.ndim != 3:
        raise ValueError("render: sigma and source must be 3-D arrays of one shape")
    shape = sigma.shape
    h = np.asarray(size, float) / np.asarray(shape[::-1])
    o = np.asarray(camera.position, float)
    # march only through the box around the non-empty voxels (+ the half-voxel ramp)
    nz = np.nonzero((sigma > 0) | (source != 0))
    if len(nz[0]) == 0:
        return np.full((camera.height, camera.width), float(background), np.float32)
    first = np.array([nz[2].min(), nz[1].min(), nz[0].min()], float)
    last = np.array([nz[2].max(), nz[1].max(), nz[0].max()], float)
    lo, hi = first * h - 0.5 * h, (last + 1.0) * h + 0.5 * h
    d = camera.rays().reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo[None] - o[None]) * inv
        t1 = (hi[None] - o[None]) * inv
    tn = np.nanmax(np.minimum(t0, t1), axis=1).clip(0.0)
    tf = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = tf > tn
    n = int(np.ceil(np.linalg.norm(hi - lo) / (step * h.min())))
    img = np.full(len(d), float(background))
    for s in range(0, len(d), chunk):
        sl = slice(s, s + chunk)
        m = hit[sl]
        if not m.any():
            continue
        dd, a, b = d[sl][m], tn[sl][m], tf[sl][m]
        ds = (b - a) / n
        t = a[:, None] + (np.arange(n)[None] + 0.5) * ds[:, None]
        p = o[None, None] + t[..., None] * dd[:, None]
        idx = p / h - 0.5
        sg = _trilinear(sigma, idx)
        sc = _trilinear(source, idx)
        tau = sg * ds[:, None]
        tr, esc = _transport_factors(tau)
        before = np.exp(-np.concatenate([np.zeros((len(a), 1)), np.cumsum(tau, 1)[:, :-1]], 1))
        rad = (sc * ds[:, None] * esc * before).sum(1)
        img_s = img[sl]
        img_s[m] = rad + before[:, -1] * tr[:, -1] * background
        img[sl] = img_s
    return img.reshape(camera.height, camera.width).astype(np.float32)


# --------------------------------------------------------------------------- files

_ARRAYS = ("sigma", "received", "total", "received_sun", "received_peaked", "peaked_weights", "unshot",
           "exit_flux")


def solution_arrays(sol):
    """A :class:`Solution` as a dict of plain arrays (metadata as a JSON string array)."""
    meta = {k: getattr(sol, k) for k in sol.__dataclass_fields__ if k not in _ARRAYS}
    meta = json.loads(json.dumps(meta, default=float))
    return {"meta": np.array(json.dumps(meta)), **{k: getattr(sol, k) for k in _ARRAYS}}


def solution_from_arrays(arrays):
    """Inverse of :func:`solution_arrays`."""
    meta = json.loads(str(arrays["meta"]))
    for k in ("size", "sun_dir", "periodic"):
        meta[k] = tuple(meta[k])
    return Solution(**{k: np.asarray(arrays[k]) for k in _ARRAYS}, **meta)


def save_solution(sol, path):
    """Write a :class:`Solution` to ``path`` (.npz: plain arrays + JSON metadata, no pickle), atomically."""
    path = os.fspath(path)
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **solution_arrays(sol))
    return path


def load_solution(path):
    """Read a :class:`Solution` written by :func:`save_solution`."""
    try:
        z = np.load(path, allow_pickle=False)
        return solution_from_arrays({k: z[k] for k in ("meta",) + _ARRAYS})
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise DataError(f"not a scattering solution file ({exc})", path=path) from exc
