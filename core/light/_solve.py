"""The shooting solve of the scattering cloud (:func:`solve_steps`) in named stages: the checked
inputs and the delta-M scaled medium, the sun's beam, the peaked orders of sunlight, the sky,
the shooting passes with their extrapolated tail, and the :class:`.Solution`.

Measured choices behind the defaults
------------------------------------
(All on 2 shared cores; slabs against adding-doubling, tests/core/light/radiative_truth.py.)

* ``extrapolate``: Fig. 6 cloud 64x64x48, tol 1e-3: 13 passes instead of 20, L1 error of
  ``received`` 3.8e-4 of the entered power instead of 2.3e-3 (against a solve to tol 1e-6).
* ``overrelax``: the passes' residual falls by a steady ratio, 0.70 on the Fig. 6 cloud (its
  thick interior diffuses slowly); shooting omega times each group's light with Young's omega
  for that ratio (1.32) makes it 0.56-0.58.  64x64x48, tol 1e-3 (2026-11-29): 8 passes instead
  of 11, L1 error of ``received`` 2.65e-4 of the entered power instead of 3.24e-4 (against a
  Gauss-Seidel solve to tol 1e-6), solve 3.3-3.6 s instead of 4.7-5.0 s.  g 0.8 slabs at tol
  1e-6 (tau 1-16, sun at 90, 30 and 15 deg, 4 and 16 layers): R and T within 8.8e-5 (rel.) of
  Gauss-Seidel's, tau 16 in 82 passes instead of 140.  A 12x16x16 cloud to tol 1e-6 ends 2.0e-4
  (L1) from Gauss-Seidel's end: the voxel profiles and the switch to ``late_sub`` follow the
  order light is shot in.  Isotropic scattering stays plain: its one shared profile made the
  semi-infinite slab's R -0.7 % off with signed light.  A cloud 3x as thick (g 0.5) converged
  in 64 passes, Gauss-Seidel not in 100; omega is capped at ``OMEGA_MAX`` (1.4: 1.5 and more
  made the tail's error bound miss, 1.28e-3 at tol 1e-3).
* ``delta_m``: on the slab tests ``f = g^4`` beat ``g^2`` (too much truncation for thin
  slabs) and ``g^8`` / no scaling (thick slabs), and it needs fewer passes.
* ``profile_every``: the profiles settle as passes go on, but slowly deep inside: isotropic
  slab tau 32, voxel tau 2, T -0.6% with 1 (default), -1.3% with 2; semi-infinite R +0.40% /
  +0.42%.  2 saves ~40% of a pass.
* ``peaked_orders``: isotropic scattering fills its bins evenly (2 put the semi-infinite
  slab on voxel tau 2 at R +0.4 %, 4 at +0.8 %, 1 at +0.03 %).  g 0.8 slabs (voxel tau
  0.5-2): overhead sun R +1.3 % with 2, +0.7 % with 4 (tau 4); sun 15 deg up (on 4x4
  sub-directions) T -1.4 % / -1.1 % (tau 16).  Fig. 6 cloud 128x128x96: the peaked orders
  take 27 s instead of 20 s but the passes stop after 11 instead of 13, the solve as long
  (57.9 s against 58.5 s, one after the other); against Cycles 4096 spp (640x480) mean
  -0.00 % / 4x4 1.78 % instead of +0.16 % / 1.83 %.
* ``second_moments``: g 0.8 slabs, voxel tau 2 against 0.5 (the same settings otherwise):
  R and T then agree within 0.2 % (tau 1 on one layer, mu0 0.5: R -0.66 % against -0.63 %;
  tau 16 on 8 layers, sun 15 deg up: T -0.91 % against -0.75 %); without, they differ by up
  to 0.3 % (that T: -1.05 % against -0.75 %).  Isotropic scattering shares one profile
  between all groups, whose moments drift with the Gauss-Seidel order: with second moments
  the semi-infinite slab on voxel tau 2 went from R +0.4 % to -1.2 %, so they stay off
  there.  Cost: about a quarter more per pass (Fig. 6 cloud 64x64x48, whose voxels stay
  below 0.4 in the scaled medium, so the default leaves them off: 12.1 s instead of 9.7 s,
  the same picture to 1e-4).
* ``first_sub``: a low sun's forward lobe leaves the layers at a grazing angle, where 4x4
  cannot follow its shape: g 0.8 slabs, sun 15 deg up, voxel tau 0.25-2, worst R or T error
  1.05 % with 4 (tau 16 T on voxel tau 2), 0.89 % with 8; single scattering (g 0.8) +0.96 %
  / +0.28 % (from the sub-squares' centres +2.3 % / +0.6 %).  8 costs 4 times 4 in the
  first two peaked orders (the later ones are merged into quarters either way).  With the
  sun 30 deg up or higher 4 stays within 0.82 % (single scattering 0.45 %).
* ``merge_tol_later`` 1 sweeps all bins of the third and later peaked orders on merged
  quarters, so each costs about a pass (g 0.8 slabs within 0.1 % of 0.2; the 128x128x96
  solve 60.4 s instead of 67.7 s).
* ``merge_tol``: Fig. 6 cloud 64x64x48 (96 bins), 0.1: 47 bins on all sub-directions,
  ``received`` changes by 1.7e-4 of the entered power (L1), small beside the 4x4
  sub-directions' own error (2.32e-3 against 8x8 sub-directions; 2.37e-3 merged).  0.2
  (default): 26 bins; on the 12x16x16 test cloud merged vs all 2.2e-4 (0.1: 1.3e-4, 0.3:
  3.5e-4) beside all vs 8x8 2.8e-3; the 64x64x48 cloud against Cycles (with the earlier bin
  matrix, :func:`.phase.phase_matrix`): mean +1.48-1.49%, 4x4 2.00-2.01% at 0.1, 0.2 and
  0.3.  Merging the first order as much (3.0e-4) put the back-scatter off (slab single
  scattering R +0.57% -> +1.12%, tests/core/light/test_scatter_voxel_depth.py).
* ``merge_tol_first`` 0.01 merges 16 of 96 bins for the Fig. 6 sun; single scattering off a
  g 0.8 slab moves by at most 0.04% of R (sun at 90, 60, 15 deg; 0.02: 0.08%, 0.05: 0.5%),
  the 64x64x48 view against Cycles by 0.01%, and the first pass at 64x64x48 takes 3.2 s
  instead of 3.7 s.
* ``late_sub``: light that many orders old is smooth in space and angle, so the
  sub-directions' fight against ray effects buys little there, and 1x1 costs a quarter (its
  transmittances fit the cache at 128x128x96 too).  Fig. 6 cloud 64x64x48 against Cycles
  4096 spp (earlier bin matrix): mean +1.49% / 4x4 2.04% with 2x2 throughout, +1.48% / 2.01%
  with 1x1 from 0.1 (solve 14.1 -> 10.9 s CPU); 128x128x96: 87.7 -> 77.4 s CPU.  Thick slabs
  (tau 32 isotropic, tau 4-16 g 0.8) change R and T by at most 0.15% (rel.), T toward
  adding-doubling.
* ``bins_per_face``: finer bins resolve a forward peak better at about ``(n / 4)^2`` times
  the memory and more time (Fig. 6 cloud 64x64x48, 216 bins: solve 22.1 s wall instead of
  8.3 s, peak memory 1.22 GB instead of 0.56 GB).  g 0.8 slabs on voxel tau 0.5
  (2026-11-28): tau 16, sun 15 deg up, T -0.75 % with 96 bins, -0.47 % with 216; tau 4
  overhead R +0.72 % / +0.64 %.
"""

import numpy as np

from ..errors import DataError
from ..threads import split_map
from . import _native, _warm, phase
from ._escape import _DHI, _DLO, _DSCALE, _RSTEP, _RTAB, _offset, _rate_of_offset, _second_moment, _variance
from ._passes import (
    _as_slice,
    _bin_powers,
    _bin_sum,
    _fine_bins,
    _groups,
    _merge_quarters,
    _occupied_box,
    _quarters,
    _scatter_into,
    _shot_group,
    _Tail,
)
from ._solution import Progress, Solution, _check_sky
from ._sweep import _layer_area, _Scratch, _sweep, _zero

MERGE_TOL = 0.2
MERGE_TOL_FIRST = 0.01
MERGE_TOL_LATER = 1.0
PEAKED_ORDERS = 4
LOW_SUN = 0.5  # sin of the sun's elevation below which its peaked orders take 8x8 sub-directions
SECOND_MOMENTS_TAU = 0.5
OMEGA_MAX = 1.4


def _check_inputs(sigma, size, albedo, g, sun_dir, sun_irradiance, sky_radiance, per_face):
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
    if sun_irradiance < 0:
        raise DataError("sun irradiance must be >= 0", field="sun")
    return sigma.astype(np.float64), size, s / np.linalg.norm(s), _check_sky(sky_radiance, 6 * per_face ** 2)


class _Options:
    """:func:`solve_steps`' keywords, checked, with the defaults that depend on the sun and g filled in."""

    def __init__(self, sigma, size, kw):
        self.__dict__.update(kw)
        self.per_face = phase.check_per_face(kw["bins_per_face"])
        self.nb = 6 * self.per_face ** 2
        self.sigma, self.size, self.sun, self.sky_radiance = _check_inputs(
            sigma, size, kw["albedo"], kw["g"], kw["sun_dir"], kw["sun_irradiance"], kw["sky_radiance"], self.per_face)
        self.periodic = tuple(bool(p) for p in kw["periodic"])
        if self.peaked_orders is None:
            self.peaked_orders = PEAKED_ORDERS if self.g != 0.0 else 1
        if self.first_sub is None:
            self.first_sub = 8 if abs(self.sun[2]) < LOW_SUN else 4
        if int(self.peaked_orders) < 1:
            raise DataError(f"peaked_orders must be >= 1, got {self.peaked_orders}", field="peaked_orders")
        self.peaked_orders = int(self.peaked_orders)
        self.real_orders = min(int(self.real_orders), self.peaked_orders)
        if int(self.max_passes) < 1 or not self.tol > 0:
            raise DataError("max_passes must be >= 1 and tol > 0", field="tol")
        if self.late_sub is not None and int(self.late_sub) < 1:
            raise DataError(f"late_sub must be >= 1 or None, got {self.late_sub}", field="late_sub")


class _Solve:
    """One solve's state (the medium, the flux arrays, the voxel profiles of the unshot light)
    and its stages, run in order by :func:`solve_steps`."""

    def __init__(self, sigma, size, kw):
        o = self.o = _Options(sigma, size, kw)
        self.full_sigma, self.full_size = o.sigma, o.size
        self.box = _occupied_box(o.sigma, o.periodic)
        sigma, size = o.sigma, o.size
        if self.box is not None:
            # Sun and sky are uniform, so the empty space around the cloud only translates the
            # beams: solve inside the box of non-empty voxels (Fig. 6 cloud: 1/3 of the grid).
            h_full = np.array(size) / np.array(sigma.shape[::-1])
            sigma = sigma[self.box]
            size = tuple(float(v) for v in h_full * np.array(sigma.shape[::-1]))
        self.sigma = sigma
        self.held = _native.held_groups(sigma)  # (empty voxels catch nothing: the products skip them)
        albedo, g = o.albedo, o.g
        self.f = f = g ** 4 if (o.delta_m and g > 0) else 0.0
        self.sig_s = sigma * (1.0 - albedo * f)
        self.alb_s = albedo * (1.0 - f) / (1.0 - albedo * f) if albedo * f < 1 else 0.0
        self.g_s = (g - f) / (1.0 - f)
        self.shape = shape = sigma.shape
        self.h = np.array(size) / np.array(shape[::-1])  # (dx, dy, dz)
        # (isotropic scattering: all groups share one profile, in the passes)
        self.groups, self.dirs, self.wsub, self.wabs = _groups(o.periodic, o.sub, o.per_face, bands=self.g_s != 0.0)
        self.M = phase.phase_matrix(self.g_s, sub=o.phase_sub, transport_sub=o.sub, per_face=o.per_face)
        nb = o.nb
        self.unshot = np.zeros((nb,) + shape, np.float32)
        self.received = np.zeros((nb,) + shape, np.float32)
        self.total = np.zeros((nb,) + shape, np.float32) if o.total else None
        self.exit_flux = np.zeros(nb)
        self.history = []
        self.scratch = _Scratch()
        self.spare = None  # a free array like unshot, its pages already touched: the next one to fill
        self.passes, self.residual, self.converged = 0, 0.0, False

    # ------------------------------------------------------------------ the sun's beam

    def sun_beam(self):
        """The sun: one parallel beam along its dominant non-periodic axis, swept in the real
        medium (exact single scattering at render time; only the scattered light travels in
        the delta-M scaled medium: scattering the sun in the scaled medium too, HG(g*) having
        more back-scatter than HG(g), put the slab tau=1, g=0.8 reflectance 9% high)."""
        o, h = self.o, self.h
        self.prop = prop = -o.sun
        free = [c for c in range(3) if not o.periodic[c]]
        self.c = c = max(free, key=lambda c: abs(prop[c]))
        if abs(prop[c]) < 1e-9:
            raise DataError("the sun must not shine parallel to the periodic layers", field="sun_dir")
        area = np.prod([h[k] for k in range(3) if k != c])
        inflow = np.array([[o.sun_irradiance * abs(prop[c]) * area]])
        r, _, ex = _sweep(self.sigma, h, prop[None, None, :], np.ones((1, 1)), None, inflow, o.periodic, 2 - c)
        self.r_sun, self.sun_exit = r[0], float(ex[0])
        self.injected = float(self.r_sun.sum())

    def first_flight_bins(self):
        """The sun's first scattering, shot on first_sub x first_sub sub-directions per bin
        weighted by the exact phase function about the true sun direction, so the forward lobe
        keeps its shape inside its bins.  This once-scattered flux, and the twice-scattered flux
        it makes, are still peaked inside their bins: treating them as spread evenly over a bin
        (the nb x nb matrix) overstates the next scattering's reflectance (slab tau=4, g=0.8
        against adding-doubling: R +0.0114 evenly, +0.0088 with order 1 per sub-direction,
        +0.0070 with orders 1 and 2).  So both are intercepted per sub-direction and scattered
        from each sub-direction's own direction (phase.sub_phase_matrix); order 2 is shot on
        sub-direction weights of each bin summed over the grid (phase.sub_sub_phase_matrix
        applied to order 1's interceptions)."""
        o, prop = self.o, self.prop
        qs = phase.direct_fractions(prop, o.g, sub=48, into_sub=o.first_sub, per_face=o.per_face)
        self.q = q = qs.sum(1)
        self.wq = np.where(q[:, None] > 1e-12, qs / np.maximum(q[:, None], 1e-300), 1.0 / qs.shape[1])
        # The sun's sub-directions: each sub-square's phase-weighted mean direction, not its centre
        # (the centres, fdirs, carry the later orders, whose shape inside a sub-square is not known).
        self.sun_dirs = phase.direct_directions(prop, o.g, o.first_sub, sub=48, per_face=o.per_face)
        _, f_omega, self.fdirs, f_w = phase.bins(o.first_sub, o.per_face)
        self.ushare = f_w / f_omega[:, None]
        self.kids = _quarters(o.first_sub, o.sub)
        self.m_sub = phase.sub_phase_matrix(self.g_s, o.first_sub, per_face=o.per_face)  # (nb, nb, first_sub**2)
        self.m_real = phase.sub_phase_matrix(o.g, o.first_sub, per_face=o.per_face) if o.real_orders > 0 else None

    # ------------------------------------------------------------------ voxel profiles

    def profile_moments(self):
        """Where inside its voxel the unshot light sits (issue 18): light is caught mostly near
        the face it entered by, so a thick voxel's scattered light escapes more easily back
        through that face.  ``umom[s]`` is the first moment (voxel units, x y z) about each
        voxel centre of the unshot power in sweep group s's bins (a caught beam's moment goes to
        each group in the share its bin scatters into that group's bins); a group's emission
        gets the exponential profile with its own centroid (_rate_of_offset).  One moment for
        all bins put the light scattered back toward the sun as deep as the forward-scattered
        majority: slab g 0.8 tau 1 on one layer R -1.6 % -> -0.5 % (sun overhead), tau 16 on 8
        layers T -1.2 % -> -0.5 %.  The sun's first scattering has its exact profile: the sun
        beam falls as exp(-sigma* x_c / prop_c) along its sweep axis c, i.e. rate sigma* h_c /
        prop_c.  ``umom[s, 1]``: the second moments about the centre; with them a group's
        profile gets a P2 term along each axis (:func:`._sweep._sweep`): a thick voxel's light
        scattered more than once is caught away from its faces, more than any exponential with
        the same centroid puts it (slab g 0.8 tau 1 on one layer, mu0 0.5: that exponential
        lets it escape +3.3 % upward and +3.1 % downward, with the P2 term +0.2 % and -0.2 %)."""
        o, c, h = self.o, self.c, self.h
        second_moments = o.second_moments
        if second_moments is None:
            second_moments = self.g_s != 0.0 and float(self.sig_s.max()) * float(h.max()) >= SECOND_MOMENTS_TAU
        self.second = bool(o.source_profile and second_moments)
        self.umom = (np.zeros((len(self.groups), 1 + self.second, 3) + self.shape, np.float64)
                     if o.source_profile else None)
        self.mom_binned = None if self.umom is None else np.zeros_like(self.umom)
        if o.source_profile:
            kap = np.zeros((3,) + self.shape, np.float32)
            kap[c] = self.sigma * (h[c] / self.prop[c])
            self.sun_profile = (kap, np.zeros_like(kap), np.full_like(kap, 1 / 12), None)
            self.sun_profile[1][c] = _offset(kap[c])
            self.sun_profile[2][c] = _second_moment(kap[c])
        else:
            self.sun_profile = None

    def unshot_profile(self, gi, power):
        """The profile of sweep group ``gi``'s unshot light, ``power`` its unshot power per voxel:
        (kappa, delta, m2, q), each (3, ...); m2 and q None without second moments."""
        if self.umom is None:
            return None
        second = self.second
        mom = self.umom[gi]
        out = _native.profile(mom, power, second, (_RTAB, _RSTEP, _DLO, _DHI, _DSCALE))
        if out is not None:
            prof = tuple(x.reshape(mom.shape[1:]) for x in out)
            return prof if second else prof + (None, None)
        m, p = mom.reshape(len(mom), 3, -1), power.reshape(-1)
        out = np.empty((2 + 2 * second,) + m.shape[1:], np.float32)
        f32 = np.float32

        def run(s):
            inv = 1.0 / np.where(p[s] > 0, p[s], np.inf)
            dlt = np.clip(m[0][:, s] * inv, -0.49, 0.49).astype(f32)
            kap = _rate_of_offset(dlt)
            out[0][:, s], out[1][:, s] = kap, dlt
            if not second:
                return
            m2e = _variance(kap) + dlt * dlt
            # the P2 weight from the excess second moment (P2's is 1/30), held where the source
            # stays >= 0: with a = |kappa|, a / expm1(a) + q >= 0 at the faces, a / (2 sinh(a / 2))
            # - q / 2 >= 0 at the middle (no power: q = 0)
            q = f32(30) * (np.clip(m[1][:, s] * inv, 0.0, 0.25).astype(f32) - m2e)
            a = np.maximum(np.abs(kap), f32(1e-6))
            half = np.minimum(f32(0.5) * a, f32(40))
            q = np.clip(q, -a / np.expm1(np.minimum(a, f32(80))), half / np.sinh(half) * f32(2)) * (inv > 0)
            out[2][:, s], out[3][:, s] = m2e + q / f32(30), q

        split_map(run, p.size)
        prof = tuple(x.reshape(mom.shape[1:]) for x in out)
        return prof if second else prof + (None, None)

    def moment_sets(self, cols, alb, binned=False):
        """:func:`._sweep._sweep`'s ``moments``: add albedo times what is caught to ``umom``, each
        of ``k`` scattering columns (nb, k) into each sweep group by the share it scatters into
        the group's bins (``binned``: the binned light's, kept for the next frame's warm start,
        also to ``mom_binned``); None without profiles."""
        if self.umom is None:
            return None
        return (np.stack([cols[bs].sum(0) for _, bs in self.groups]), self.umom, alb,
                self.mom_binned if binned else None)

    # ------------------------------------------------------------------ peaked orders of sunlight

    def shoot_peaked(self, emission, sdirs, weights, prof, real, flux, tol, rec):
        """Shoot ``emission(bins)`` on the sub-directions ``sdirs`` with ``weights`` and the voxel
        source profile ``prof(group index)``; scatter per sub-direction.  ``real``: fly in the real
        medium and scatter with the full HG(g) (else the delta-M scaled medium).
        ``flux`` (nb,): the power of each bin; the weakest, holding ``tol`` of it, are swept
        merged by quarters (:func:`._passes._fine_bins`), the others on all sub-directions.
        Writes what is caught into ``rec`` (nb, ...); returns it per sub-direction (nb, s*s)."""
        o, kids, nb, shape = self.o, self.kids, self.o.nb, self.shape
        rsub = np.zeros(weights.shape)
        sig_k, m_k, alb_k = (self.sigma, self.m_real, o.albedo) if real else (self.sig_s, self.m_sub, self.alb_s)
        fine = _fine_bins(flux, kids, tol)
        for gi, (axis, group) in enumerate(self.groups):
            for merged in (False, True):
                sel = group[fine[group] != merged]
                if not len(sel):  # (none merged, e.g. when sub does not divide first_sub)
                    continue
                ns = weights.shape[1] if not merged else len(kids)
                step = max(1, (1 << 26) // (ns * self.sigma.size))
                for s in range(0, len(sel), step):
                    bs = sel[s:s + step]
                    if merged:
                        bdirs, bw, share = _merge_quarters(sdirs[bs], weights[bs], self.ushare[bs], kids)
                        cols = np.einsum("ibqk,bqk->ibq", m_k[:, bs][:, :, kids], share)
                    else:
                        bdirs, bw, cols = sdirs[bs], weights[bs], m_k[:, bs]
                    sets = self.moment_sets(np.einsum("iba,ba->ib", cols, bw), alb_k)
                    r, caught, ex = _sweep(sig_k, self.h, bdirs, bw, emission(bs), np.zeros(bw.shape), o.periodic,
                                           axis, per_sub=True, profile=prof(gi), moments=sets, scratch=self.scratch,
                                           into=(rec, self.total, bs))
                    if merged:
                        rsub[np.ix_(bs, kids.reshape(-1))] = (caught[:, :, None] * share).reshape(len(bs), -1)
                    else:
                        rsub[bs] = caught
                    self.exit_flux[bs] += ex
                    _scatter_into(self.unshot, cols.reshape(nb, -1), r.reshape((-1,) + shape), alb_k, self.held)
        fr, fo = self.received.reshape(nb, -1), rec.reshape(nb, -1)
        split_map(lambda s: np.add(fr[:, s], fo[:, s], out=fr[:, s]), fr.shape[1])
        return rsub

    def sun_emission(self, bs):
        """The sun's first scattering into bins ``bs`` per voxel (float32, in ``scratch``)."""
        e = self.scratch.empty("emission", (len(bs),) + self.shape)
        fe, q, r = e.reshape(len(bs), -1), (self.o.albedo * self.q[bs])[:, None], self.r_sun.reshape(1, -1)
        split_map(lambda s: np.multiply(q, r[:, s], out=fe[:, s]), fe.shape[1])
        return e

    def peaked_orders(self):
        """The sun's first scattering and the next peaked orders, each shot per sub-direction
        weighted as the order before filled its bins."""
        o, nb = self.o, self.o.nb
        self.peaked = np.zeros((o.peaked_orders, nb) + self.shape, np.float32)
        rsub = self.shoot_peaked(self.sun_emission, self.sun_dirs, self.wq, lambda gi: self.sun_profile,
                                 o.real_orders > 0, o.albedo * self.q * self.injected, o.merge_tol_first,
                                 self.peaked[0])
        self.pweights = [self.wq]
        for k in range(1, o.peaked_orders):
            rsub = self.peaked_order(k, rsub)

    def peaked_order(self, k, rsub):
        """Peaked order ``k`` >= 1: what order ``k - 1`` left unshot, shot on sub-direction weights
        of each bin from ``rsub``, order ``k - 1``'s catch per sub-direction; returns order ``k``'s."""
        o = self.o
        m_ss = phase.sub_sub_phase_matrix(o.g if k <= o.real_orders else self.g_s, o.first_sub, per_face=o.per_face)
        wk = np.einsum("ibja,ja->ib", m_ss, rsub)
        wk = np.where(wk.sum(1, keepdims=True) > 0, wk / np.maximum(wk.sum(1, keepdims=True), 1e-300),
                      1.0 / wk.shape[1])
        # (the order before's unshot light is shot now; the buffer of the one before that holds this one's)
        nxt, self.unshot = self.unshot, _zero(self.spare if self.spare is not None else np.empty_like(self.unshot))
        prof = [self.unshot_profile(gi, _bin_sum(nxt, bs)) for gi, (_, bs) in enumerate(self.groups)]
        if self.umom is not None:
            self.umom[:] = 0.0
        rsub = self.shoot_peaked(lambda bs: nxt[_as_slice(bs)], self.fdirs, wk, prof.__getitem__,
                                 k < o.real_orders, _bin_powers(nxt),
                                 o.merge_tol if k == 1 else o.merge_tol_later, self.peaked[k])
        self.pweights.append(wk)
        self.spare = nxt
        return rsub

    # ------------------------------------------------------------------ the sky

    def sky(self):
        """The sky: binned beams entering through the boundary (upstream face and sides), a
        uniform sky travelling downward, or per bin (sky_radiance (nb,): any direction)."""
        o, h, sky_radiance = self.o, self.h, self.o.sky_radiance
        uniform = np.ndim(sky_radiance) == 0
        if not np.any(np.asarray(sky_radiance) > 0):
            return
        dirs, wabs = self.dirs, self.wabs
        for axis, bs in self.groups:
            cc = 2 - axis
            area = np.prod([h[k] for k in range(3) if k != cc])
            if uniform:
                down = dirs[bs][..., 2] < 0
                sky_in = sky_radiance * wabs[bs] * np.abs(dirs[bs][..., cc]) * area * down
            else:
                sky_in = sky_radiance[bs][:, None] * wabs[bs] * np.abs(dirs[bs][..., cc]) * area
            r, _, ex = _sweep(self.sig_s, h, dirs[bs], self.wsub[bs], None, sky_in, o.periodic, axis,
                              moments=self.moment_sets(self.M[:, bs], self.alb_s, True), scratch=self.scratch,
                              into=(None, self.total, bs))
            self.received[bs] += r.astype(np.float32)
            self.exit_flux[bs] += ex
            self.injected += float(r.sum())
            _scatter_into(self.unshot, self.M[:, bs], r, self.alb_s, self.held)

    # ------------------------------------------------------------------ shooting passes

    def new_caches(self, ns):
        """Caches per group when they fit in 1 GiB: per beam, on each layer's non-empty rectangle,
        the transmittances, with profiles the deposit centroids, and when profiles are not
        refreshed every pass their escapes and the kept light's two moments (float32)."""
        o = self.o
        keep = int(o.profile_every) > 1
        arrays = 1 + bool(o.source_profile) * (1 + 3 * keep)
        area = _layer_area(self.sigma)
        return [{} if arrays * o.nb * ns * area <= 1 << 28 else None for _ in self.groups]

    def warm_pass(self, prev):
        """The Jacobi pass of a warm start (:mod:`._warm`): this frame's unshot light plus the
        scattering of ``prev``'s binned light, swept once through the new medium (2x2
        sub-directions, as the early passes); what is caught goes to ``received``, and the unshot
        light becomes the scattering of the difference from ``prev``'s.  The moments of the
        guess's own light are not known: the profiles of what is shot now take them as centred."""
        o, nb = self.o, self.o.nb
        origin = (0, 0, 0) if self.box is None else tuple(b.start for b in self.box)
        g = _warm.guess(prev, origin, self.sigma)
        rec, pk = self.received.reshape(nb, -1), self.peaked.reshape(len(self.peaked), nb, -1)
        fg = g.reshape(nb, -1)
        for k in range(len(self.peaked)):  # this frame's sky (received less its peaked orders) is in g
            fg += pk[k]
        fg -= rec
        _scatter_into(self.unshot, self.M, g, self.alb_s, self.held)
        gm = _warm.moments(prev, origin, self.sigma, self.umom)
        if gm is not None:  # where the guess's light sits in its voxels (else: centred)
            self.umom += self.alb_s * gm
        prof = [self.unshot_profile(gi, _bin_sum(self.unshot, bs)) for gi, (_, bs) in enumerate(self.groups)]
        if self.umom is not None:
            self.umom[:] = 0.0
            self.mom_binned[:] = 0.0
        # (the difference goes to the peaked orders' spare buffer, and this one becomes the spare)
        diff = _zero(self.spare) if self.spare is not None else np.zeros_like(self.unshot)
        for gi, (axis, bs) in enumerate(self.groups):
            sl = _as_slice(bs)
            r, _, ex = _sweep(self.sig_s, self.h, self.dirs[bs], self.wsub[bs], self.unshot[sl],
                              np.zeros(self.wsub[bs].shape), o.periodic, axis, profile=prof[gi],
                              moments=self.moment_sets(self.M[:, bs], self.alb_s, True), scratch=self.scratch,
                              into=(None, self.total, bs))
            self.received[sl] += r
            self.exit_flux[bs] += ex
            r -= g[sl]
            _scatter_into(diff, self.M[:, bs], r, self.alb_s, self.held)
        if gm is not None:  # the difference's moments: the new catch's less the guess's
            self.umom -= self.alb_s * gm
        self.unshot, self.spare = diff, self.unshot
        self.warm = self.signed = True

    def start_passes(self, prev=None):
        """After the first step (and a warm start's Jacobi pass from ``prev``): the unshot power per
        voxel (all bins), kept up to date group by group instead of summing the bins again (the
        phase matrix's columns sum to 1: a group adds albedo times what it caught); summed afresh
        after each pass.  After a warm start (and over-relaxed passes) the unshot light is signed:
        its residual is its L1."""
        self.ref = max(self.injected, 1e-300)
        self.warm = self.signed = False
        self.omega = 1.0
        if _warm.compatible(prev, self.full_sigma.shape, self.o.nb):
            self.warm_pass(prev)
        self.power = _bin_sum(self.unshot, slice(None))
        self.residual = self.unshot_residual()
        self.history.append(self.residual)
        self.converged = self.residual <= self.o.tol
        # Isotropic scattering: where a beam was caught says nothing about the direction its light
        # leaves in, so all groups share one profile in the passes (per group, the Gauss-Seidel
        # order alone made them differ: semi-infinite g 0, voxel tau 2, R +1.3 % instead of +0.4 %).
        # (Moments kept per group and a profile of their sum: R +0.1 %, but thick slabs' T +1.4 to
        # +2.1 % instead of -0.5 to -0.7 %.)
        self.shared = self.umom is not None and self.g_s == 0.0
        if self.shared:
            self.umom = self.umom.sum(0, keepdims=True)
            self.mom_binned = self.mom_binned.sum(0, keepdims=True)
        # In the passes the binned light's moments are not summed beside the unshot light's (a second
        # float64 array every sweep would read and write): they are the unshot light's plus what the
        # shots take from them, which mom_binned holds from here on (moments_out adds the two)
        if self.mom_binned is not None:
            self.mom_binned -= self.umom
        self.beams = (self.dirs, self.wsub, self.M, self.new_caches(self.dirs.shape[1]))
        # (the tail's buffers: the peaked orders' spare unshot buffer and their catches per sub-direction,
        # their pages touched)
        self.tail = (_Tail(self.received, self.total, self.exit_flux, (self.spare, self.scratch.take("recv")))
                     if self.o.extrapolate else None)
        self.spare = None
        self.late = self.o.late_sub is None

    def go_late(self):
        """Once the unshot power has fallen to ``late_residual``: shoot on ``late_sub`` sub-directions."""
        o = self.o
        self.late = True
        _, d1, w1, _ = _groups(o.periodic, o.late_sub, o.per_face, bands=self.g_s != 0.0)
        self.beams = (d1, w1, phase.phase_matrix(self.g_s, sub=o.phase_sub, transport_sub=o.late_sub,
                                                 per_face=o.per_face), self.new_caches(d1.shape[1]))
        if self.tail is not None:
            self.tail.reset()

    def shoot_group(self, gi, axis, bs, refresh):
        """One group of bins shoots ``omega`` times its unshot light (one sweep; over-relaxed, the
        rest is its light less that, signed) and scatters what is caught."""
        o, umom, second, w = self.o, self.umom, self.second, self.omega
        dirs_p, wsub_p, M_p, caches_p = self.beams
        shot = _bin_sum(self.unshot, bs)
        prof = self.unshot_profile(0, self.power) if self.shared else self.unshot_profile(gi, shot)
        # the unshot moments: less what is shot (omega times this group's light: to mom_binned, see
        # start_passes), plus albedo times what is caught (added by the sweep)
        if self.shared:
            for k in range(1 + second):
                took = w * prof[1 + k] * shot
                umom[0, k] -= took
                self.mom_binned[0, k] += took
        elif umom is not None:
            fu, fb = umom[gi].reshape(-1), self.mom_binned[gi].reshape(-1)

            def take(s):
                fb[s] += w * fu[s]
                fu[s] *= 1.0 - w

            split_map(take, fu.size)
        sets = ((np.ones((1, len(bs))), umom, self.alb_s, None) if self.shared
                else self.moment_sets(M_p[:, bs], self.alb_s))
        keep = int(o.profile_every) > 1
        r, _, ex = _sweep(self.sig_s, self.h, dirs_p[bs], w * wsub_p[bs], self.unshot[_as_slice(bs)],
                          np.zeros(wsub_p[bs].shape), o.periodic, axis, caches_p[gi], profile=prof, moments=sets,
                          fresh=refresh if keep else None, scratch=self.scratch, into=(None, self.total, bs))
        self.exit_flux[bs] += ex
        _shot_group(bs, self.unshot, self.received, r, self.power, shot, self.alb_s, w,
                    None if self.tail is None else self.tail.inc)
        _scatter_into(self.unshot, M_p[:, bs], r, self.alb_s, self.held)

    def run_passes(self):
        """The shooting passes (Gauss-Seidel by groups of bins) until converged, the tail
        extrapolated, or ``max_passes``; yields :class:`.Progress` after each group."""
        o, groups = self.o, self.groups
        while not self.converged and self.passes < int(o.max_passes):
            self.passes += 1
            if not self.late and self.residual <= o.late_residual:
                self.go_late()
            if self.tail is not None:
                self.tail.begin()
            refresh = self.passes <= 8 or self.passes % int(o.profile_every) == 0
            for gi, (axis, bs) in enumerate(groups):
                self.shoot_group(gi, axis, bs, refresh)
                self.residual = float(self.power.sum()) / self.ref
                yield Progress(self.passes, gi + 1, len(groups), self.residual)
            self.power = _bin_sum(self.unshot, slice(None))
            self.residual = self.unshot_residual()
            self.history.append(self.residual)
            self.converged = self.residual <= o.tol
            if self.passes == 1 and o.overrelax and not self.shared:
                self.relax()
            if self.tail is not None:
                err = self.alb_s * self.tail.end() / self.ref  # (which adds the pass's catch to received)
                # (signed passes (a warm start's, over-relaxed ones) reach tol with their unshot light
                # undone, which would still add about residual / (1 - rho): their tail goes in too,
                # once it is known)
                if (not self.converged or self.signed) and (
                        err <= o.tol or (self.converged and self.tail.factor is not None)):
                    self.tail.apply()
                    _zero(self.unshot)
                    self.residual, self.converged = min(err, self.residual), True
                    yield Progress(self.passes, len(groups), len(groups), self.residual)
        self.tail = None

    def moments_out(self):
        """The binned light's scattering moments per unit albedo (float32), for the next frame."""
        if self.mom_binned is None:
            return None
        # (the unshot light's and what was shot, see start_passes; divided in float64 into the float32
        # array in voxel ranges: no whole float64 temporary, 69 MB at 128x128x96)
        out = np.empty(self.mom_binned.shape, np.float32)
        fo, fb, fu, alb = out.reshape(-1), self.mom_binned.reshape(-1), self.umom.reshape(-1), max(self.alb_s, 1e-30)
        split_map(lambda s: np.divide(fb[s] + fu[s], alb, out=fo[s], casting="unsafe"), fo.size)
        return out

    def relax(self):
        """After the first pass: over-relax the passes to come, ``omega`` from that pass's ratio
        ``rho`` of residuals as successive over-relaxation's optimum for a Gauss-Seidel ratio rho
        (Young 1954: 2 / (1 + sqrt(1 - rho))), at most ``OMEGA_MAX``."""
        h = self.history
        rho = h[-1] / h[-2] if len(h) >= 2 and h[-2] > 0 else 0.0
        if 0.0 < rho < 1.0:
            self.omega = min(2.0 / (1.0 + np.sqrt(1.0 - rho)), OMEGA_MAX)
            self.signed = self.omega > 1.0

    def unshot_residual(self):
        """The unshot power over the entered power: its sum, or where it is signed (a warm start,
        over-relaxed passes) its L1."""
        if not self.signed:
            return float(self.power.sum()) / self.ref
        u = self.unshot.reshape(-1)
        return float(sum(split_map(lambda s: np.abs(u[s]).sum(dtype=np.float64), u.size))) / self.ref

    def solution(self):
        o = self.o
        return Solution(
            sigma=self.full_sigma.astype(np.float32), size=self.full_size, albedo=float(o.albedo), g=float(o.g),
            sun_dir=tuple(float(v) for v in o.sun), sun_irradiance=float(o.sun_irradiance),
            sky_radiance=o.sky_radiance, received=self.received, total=self.total,
            received_sun=self.r_sun.astype(np.float32), received_peaked=self.peaked,
            peaked_weights=np.stack(self.pweights).astype(np.float32), unshot=self.unshot, exit_flux=self.exit_flux,
            sun_exit=self.sun_exit, injected=self.injected, passes=self.passes, residual=self.residual,
            converged=bool(self.converged), history=self.history, sub=int(o.sub), periodic=o.periodic,
            albedo_binned=float(self.alb_s), g_binned=float(self.g_s), delta_f=float(self.f),
            real_orders=o.real_orders, origin=(0, 0, 0) if self.box is None else tuple(b.start for b in self.box),
            warm=self.warm, moments_binned=self.moments_out())


def solve_steps(sigma, size, *, albedo=0.99, g=0.8, sun_dir=(0.0, 0.0, 1.0), sun_irradiance=1.0,
                sky_radiance=0.0, tol=1e-3, max_passes=100, sub=2, periodic=(False, False, False),
                delta_m=True, phase_sub=6, first_sub=None, source_profile=True, second_moments=None,
                peaked_orders=None, real_orders=1, profile_every=1, extrapolate=True, merge_tol=MERGE_TOL,
                late_sub=1, late_residual=0.1, merge_tol_first=MERGE_TOL_FIRST, merge_tol_later=MERGE_TOL_LATER,
                bins_per_face=phase.N_PER_FACE, warm=None, overrelax=True, total=False):
    """The shooting solve as a generator: yields :class:`.Progress` after each group of bins,
    returns the :class:`.Solution` (``StopIteration.value``; :func:`solve` unwraps it).

    The measurements behind the defaults are in this module's notes (:mod:`._solve`).

    Parameters
    ----------
    sigma : (nz, ny, nx) extinction per unit length (>= 0, finite).
    size : (Lx, Ly, Lz) box size.
    albedo : single-scattering albedo in [0, 1].
    g : Henyey-Greenstein asymmetry in (-1, 1).
    sun_dir : direction toward the sun.
    sun_irradiance : sun power per unit area perpendicular to its rays.
    sky_radiance : the sky: a number, the constant radiance of light travelling downward
        (a uniform upper hemisphere), or an array (6 n^2,) (``n = bins_per_face``): the
        radiance of light travelling in each bin of :mod:`.phase` (arriving from minus its
        direction), any direction, e.g. :func:`.sky.panorama_radiance` of a rendered world
        (same ``bins_per_face``).  Either enters through the box's boundary and is received
        like scattered light (binned, not sharp like the sun).
    tol : stop when unshot power <= tol * entered power, or (``extrapolate``) when the
        bound on the extrapolated tail's error (albedo times the L1 error of ``received``,
        :class:`._passes._Tail`) is <= tol * entered power.
    max_passes : stop after this many passes even if not converged (see ``Solution.report``).
    extrapolate : after each pass, extrapolate the geometric tail of the passes still to
        come and stop once that is as sure as ``tol``; the unshot power is then counted as
        shot (``Solution.unshot`` zero, ``residual`` the estimated error).
    sub : sub-directions per bin side in the sweeps (flux spread over the bin).
    periodic : (x, y, z) periodic axes (slabs); at least one axis must not be.
    delta_m : transport the binned flux in the delta-M scaled medium (Wiscombe 1977):
        the fraction ``f = g^4`` (g > 0) of scattering inside the forward peak counts as
        unscattered, ``sigma* = sigma (1 - albedo f)``, ``albedo* = albedo (1-f)/(1-albedo f)``,
        ``g* = (g - f)/(1 - f)``; the smooth remainder suits 96 bins.  The sun's first
        scattering toward a viewer stays exact (unscaled medium, full HG).
    phase_sub : sub-squares per bin side for the phase matrix integrals.
    profile_every : after pass 8, recompute the escape fractions of the unshot light's
        voxel profiles only every this many passes (cached between; the moments are
        tracked on every pass).
    peaked_orders : how many scattering orders of sunlight are shot per sub-direction
        (weighted inside each bin as the previous order filled it) before the rest is
        binned; at least 1.  None (default): 4, or 1 for isotropic scattering.
    real_orders : how many of the peaked flights of scattered sunlight travel in the
        real medium and are scattered on with the full HG(g) (at most ``peaked_orders``);
        delta-M applies after them.
    source_profile : sources inside a voxel follow where the light was caught (an
        exponential profile, one per sweep group of bins; exact for the sun's first
        scattering) instead of being spread evenly, so optically thick voxels (tau ~ 1-2)
        keep their accuracy.  False gives the even spread (for comparisons).
    second_moments : also track the caught light's second moments, so a profile gets a
        P2 term where its light sits away from the voxel's faces (light scattered more than
        once in a thick voxel) or toward both.  None (default): where the thickest voxel's
        optical depth (delta-M scaled) reaches ``SECOND_MOMENTS_TAU`` (0.5) and scattering
        is not isotropic.
    first_sub : sub-directions per bin side (a divisor of 48) carrying the sun's first
        scattering (weighted by the exact phase function within each bin, each along its
        sub-square's phase-weighted mean direction, :func:`.phase.direct_directions`) and the
        next peaked orders (weighted by the previous one's interceptions scattered per
        sub-direction, along the sub-squares' centres).  None (default): 8 for a sun less
        than 30 deg above (or below) the x-y plane (``LOW_SUN``), else 4.
    merge_tol : in the second peaked order, the weakest bins holding at most this share of
        its power together are swept on ``sub x sub`` merged sub-directions (quarters of
        the ``first_sub`` ones, :func:`._passes._merge_quarters`); 0 sweeps all bins on all
        sub-directions.
    merge_tol_first : the same for the first peaked order, whose weak bins are the
        back-scatter a sunlit face shows (0.01).
    merge_tol_later : ``merge_tol`` of the third and later peaked orders, whose flux has
        spread over its bins: 1 (default) sweeps all their bins on merged quarters.
    late_sub, late_residual : once the unshot power has fallen to ``late_residual`` of the
        entered power, the passes shoot on ``late_sub x late_sub`` sub-directions per bin
        instead of ``sub x sub`` (None: never).
    bins_per_face : direction bins per cube-face side, an even integer from 2 to 8
        (:func:`.phase.bins`): ``6 n^2`` bins, 4 (default) the paper's 96.
    overrelax : after the first pass, shoot ``omega`` times each group's unshot light (the rest
        stays, signed): successive over-relaxation with Young's optimum for the first pass's
        ratio of residuals, at most ``OMEGA_MAX`` (1.4); not for isotropic scattering.  False:
        Gauss-Seidel throughout.
    warm : a :class:`.Solution` of the previous frame (same grid and bins; albedo, g, sun and
        density may differ) to start from (:mod:`._warm`): the passes then shoot only the
        difference the new density makes and end where a cold solve ends (to ``tol``).  Ignored
        when the grids differ (``Solution.warm`` says which).
    total : also sum the paper's total flux, the power passing through each voxel per bin
        (``Solution.total``; None without).  The views read ``received``; the sum costs the
        sweeps about a tenth of their time and the solve an array like ``received``.

    References
    ----------
    Max & Crawfis, "Cloud rendering"; Max 1994; Cohen et al. 1988; Wiscombe 1977;
    Nakajima & Tanaka, JQSRT 40 (1988) 51-69 (exact single scattering with delta-M);
    Young, Trans. AMS 76 (1954) 92-111 (over-relaxation).
    """
    kw = dict(albedo=albedo, g=g, sun_dir=sun_dir, sun_irradiance=sun_irradiance, sky_radiance=sky_radiance,
              tol=tol, max_passes=max_passes, sub=sub, periodic=periodic, delta_m=delta_m, phase_sub=phase_sub,
              first_sub=first_sub, source_profile=source_profile, second_moments=second_moments,
              peaked_orders=peaked_orders, real_orders=real_orders, profile_every=profile_every,
              extrapolate=extrapolate, merge_tol=merge_tol, late_sub=late_sub, late_residual=late_residual,
              merge_tol_first=merge_tol_first, merge_tol_later=merge_tol_later, bins_per_face=bins_per_face,
              overrelax=overrelax, total=bool(total))
    s = _Solve(sigma, size, kw)
    s.sun_beam()
    s.first_flight_bins()
    s.profile_moments()
    s.peaked_orders()
    s.sky()
    s.start_passes(warm)
    yield Progress(0, len(s.groups), len(s.groups), s.residual)
    yield from s.run_passes()
    return s.solution()


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
