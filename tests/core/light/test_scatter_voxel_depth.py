"""Issue 18: the solve's accuracy must not depend on the voxels' optical thickness.

Independent truth (``radiative_truth.py``, not in core): single scattering of a slab in
closed form, Chandrasekhar's H-function for a semi-infinite isotropic medium
(iterated from its integral equation) and a small adding-doubling for
Henyey-Greenstein slabs at any sun angle.  Voxel optical thickness 0.25 to 2 and suns
from overhead down to 15 degrees.
"""

import numpy as np
import pytest
from kernel_paths import BOTH
from radiative_truth import adding_doubling, gauss01, h_function, single_scattering_r

from nephele.core.light import scatter


def slab(tau, layers, omega, g, mu0, **kw):
    s = np.sqrt(max(0.0, 1 - mu0 * mu0))
    sol = scatter.solve(np.full((layers, 1, 1), float(tau)), (1.0, 1.0, 1.0), albedo=omega, g=g,
                        sun_dir=(s, 0.0, mu0), tol=1e-6, max_passes=5000, periodic=(True, True, False), **kw)
    assert sol.converged
    return scatter.slab_reflectance(sol)


MU15 = float(np.sin(np.radians(15.0)))


def test_independent_truths_agree():
    # the adding-doubling here against the H-function and facts.md
    h = h_function(0.9)
    for mu0 in (1.0, 0.5, MU15):
        assert adding_doubling(64.0, 0.9, mu0)[0] == pytest.approx(1 - h(mu0) * np.sqrt(0.1), abs=2e-6)
    r, t = adding_doubling(1.0, 1.0, 1.0)
    assert r == pytest.approx(0.34130, abs=5e-5) and t == pytest.approx(0.65864, abs=5e-5)
    # single scattering closed form against the adding-doubling at small albedo
    assert single_scattering_r(1e-4, 0.0, 2.0, 0.5) == pytest.approx(adding_doubling(2.0, 1e-4, 0.5)[0], rel=1e-4)
    # Henyey-Greenstein g = 0.8: the closed form again, energy conserved at albedo 1,
    # converged in the quadrature, and facts.md's values (which lose 0.1-0.3 % of the
    # energy: R + T = 0.9985 at tau 4) within 0.4 %
    for mu0 in (1.0, 0.5, MU15):
        assert single_scattering_r(1e-4, 0.8, 2.0, mu0) == pytest.approx(
            adding_doubling(2.0, 1e-4, mu0, g=0.8)[0], rel=1e-3)
        r, t = adding_doubling(4.0, 1.0, mu0, g=0.8)
        assert r + t == pytest.approx(1.0, abs=1e-6)
        assert (r, t) == pytest.approx(adding_doubling(4.0, 1.0, mu0, g=0.8, n=64), rel=1e-5)
    for tau, omega, r_facts, t_facts in AD_G08:
        r, t = adding_doubling(tau, omega, 1.0, g=0.8)
        assert r == pytest.approx(r_facts, rel=4e-3) and t == pytest.approx(t_facts, rel=4e-3)


# Measured: before issue 18 (even spread in each voxel) -3.7% / -7.7% at voxel tau 0.5
# (mu0 1 / 0.5) and -33% / -49% at 2; now +0.20%, +0.26% and (sun 15 deg up, 8x8
# sub-directions) +0.09% at every voxel tau (2026-11-28).
@pytest.mark.parametrize("mu0", [1.0, 0.5, MU15])
@pytest.mark.parametrize("layers", [32, 16, 8, 4])  # voxel tau 0.25 .. 2 on tau = 8
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_single_scattering_independent_of_voxel_depth(mu0, layers, kernels):
    r, _ = slab(8.0, layers, 1e-3, 0.0, mu0)
    assert r == pytest.approx(single_scattering_r(1e-3, 0.0, 8.0, mu0), rel=5e-3)


# The sun's first scattering uses the full HG(0.8) (not the delta-M scaled one: that was
# +9% on the tau=1 slab).  What is left is angular: each bin's first flight travels on
# first_sub^2 sub-directions, each standing for its sub-square.  From the sub-squares'
# centres (before 2026-11-28) first_sub=4 was +0.5% overhead, +1.1% at mu0 0.5 and +2.3%
# at 15 deg (8: +0.6%); from their phase-weighted mean directions (phase.direct_directions,
# now) +0.23%, +0.44% and +0.96% (8, the low sun's default: +0.28%), the same on voxel tau
# 2 and 0.5.  Albedo 1e-4: at 1e-3 the solve's second order (shot as a peaked order for g
# 0.8) adds +0.11% that the closed form does not have.
@pytest.mark.parametrize("mu0,first_sub,rel", [(1.0, None, 0.005), (0.5, None, 0.005), (MU15, None, 0.005),
                                               (np.sin(np.radians(25.0)), None, 0.005), (MU15, 4, 0.011)])
@pytest.mark.parametrize("layers", [4, 16])
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_single_scattering_forward_peaked(mu0, first_sub, rel, layers, kernels):
    r, _ = slab(8.0, layers, 1e-4, 0.8, mu0, first_sub=first_sub)
    assert r == pytest.approx(single_scattering_r(1e-4, 0.8, 8.0, mu0), rel=rel)


# Measured: before -0.0028 .. -0.177 (worst mu0 = 0.26, voxel tau 2); now |rel| <= 0.3%
# (2026-11-28, one peaked order for isotropic scattering; with two, as before, up to +0.42%).
@pytest.mark.parametrize("mu0", [1.0, 0.5, MU15])
@pytest.mark.parametrize("layers", [64, 32, 16])  # voxel tau 0.5, 1, 2
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_semi_infinite_against_h_function(mu0, layers, kernels):
    omega = 0.9
    r, t = slab(32.0, layers, omega, 0.0, mu0)
    assert t < 1e-5
    assert r == pytest.approx(1 - h_function(omega)(mu0) * np.sqrt(1 - omega), rel=5e-3)


@pytest.mark.slow
@pytest.mark.parametrize("mu0", [1.0, 0.5])
@pytest.mark.parametrize("layers", [16, 32, 64, 128])  # voxel tau 2 .. 0.25
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_thick_isotropic_slab_against_adding_doubling(mu0, layers, kernels):
    r_ref, t_ref = adding_doubling(32.0, 0.99, mu0)
    r, t = slab(32.0, layers, 0.99, 0.0, mu0)
    assert r == pytest.approx(r_ref, rel=1e-2) and t == pytest.approx(t_ref, rel=1e-2)


# Measured (voxel tau 1): R +0.50%, T +0.10%; with sources spread evenly -4.8%, +18%.
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_uniform_sky_on_isotropic_slab(kernels):
    # sky radiance L from the upper hemisphere: incident pi L per unit area; the slab's
    # reflected and transmitted fractions are 2 int R(mu0) mu0 dmu0 (adding-doubling)
    tau, omega, layers = 4.0, 0.99, 4  # voxel tau 1
    mu, w = gauss01(12)
    ad = np.array([adding_doubling(tau, omega, m) for m in mu])
    r_ref, t_ref = 2 * np.sum(w * mu * ad[:, 0]), 2 * np.sum(w * mu * ad[:, 1])
    sol = scatter.solve(np.full((layers, 1, 1), tau), (1.0, 1.0, 1.0), albedo=omega, g=0.0, sun_irradiance=0.0,
                        sky_radiance=2.0, tol=1e-6, max_passes=5000, periodic=(True, True, False))
    up = scatter.phase.bins(1)[0][:, 2] > 0
    incident = np.pi * 2.0
    r, t = sol.exit_flux[up].sum() / incident, sol.exit_flux[~up].sum() / incident
    assert sol.converged
    assert r == pytest.approx(r_ref, rel=1e-2) and t == pytest.approx(t_ref, rel=1e-2), (r, r_ref, t, t_ref)


# Measured, radiance from above (render of view_source): before -9% / -26% (sun overhead)
# and -15% / -38% (mu0 0.5) at voxel tau 1 / 2; now -1.5% / -2.3% and -2.1% / -2.6%
# (the rest: the march interpolates voxel values trilinearly).
@pytest.mark.parametrize("mu0", [1.0, 0.5])
@pytest.mark.parametrize("layers", [16, 8, 4])  # voxel tau 0.5, 1, 2
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_rendered_single_scattering_from_above(mu0, layers, kernels):
    omega, tau = 1e-3, 8.0
    s = np.sqrt(1 - mu0 * mu0)
    sol = scatter.solve(np.full((layers, 3, 3), tau), (1.0, 1.0, 1.0), albedo=omega, g=0.0, sun_dir=(s, 0, mu0),
                        tol=1e-4, periodic=(True, True, False))
    cam = scatter.Camera.look_at((0.5, 0.5, 30.0), (0.5, 0.5, 0.0), up=(0, 1, 0), fov=0.1, width=2, height=2)
    img = scatter.render(sol.sigma, scatter.view_source(sol, cam.position), sol.size, cam, step=0.05)
    ref = omega * mu0 / (4 * np.pi * (1 + mu0)) * (1 - np.exp(-tau * (1 / mu0 + 1)))
    assert img.mean() == pytest.approx(ref, rel=0.03)


# facts.md adding-doubling (normal incidence) for g = 0.8: tau, omega, R, T.
AD_G08 = [(1.0, 1.0, 0.06000, 0.93926), (4.0, 1.0, 0.25444, 0.74406), (4.0, 0.99, 0.23131, 0.70164),
          (16.0, 0.99, 0.48166, 0.23837)]


# Target (issue 18): 1% relative (mu0 = sin of the sun's elevation).
# Truth: the adding-doubling here (facts.md's values are 0.1-0.3 % lower).  Measured
# (2026-11-28, voxel tau 2 and 0.5, the sun's first flight on its sub-squares' phase-weighted
# mean directions): overhead within 0.67 % (tau 4 albedo 0.99: R +0.64 to +0.67 %), mu0 0.5
# within 0.82 % (tau 1 R -0.82 / -0.78 %; tau 16 T -0.64 %), sun 15 degrees up within 0.89 %
# (tau 16 T -0.89 % on voxel tau 2, -0.73 % on 0.5; with 4x4 sub-directions instead of the low
# sun's 8x8, -1.11 / -0.95 %).  The tau 1 R at mu0 0.5 was -0.66 % from the sub-squares'
# centres: their once-scattered light came out 1.1 % too bright (test_single_scattering_forward_
# peaked), which hid part of a deficit of the delta-M scaled later orders (two or three peaked
# orders in the real medium instead of one: -0.48 / -0.28 %, but tau 16 T at 15 deg -0.98 /
# -1.00 %, so one stays).  Before the second moments,
# the slab profile groups and four peaked orders: 1.3 %, 1.43 % and 1.98 %; before that
# 1.8 %, 2.5 % and 2.6 % (tau 16 T): the bin matrix's
# mean cosine did not make up for the spread of the flux inside its bins (diffusion
# eigenvalue +0.6 %, test_phase.py) and one voxel profile was shared by all bins.  The rest
# is angular (96 bins) and grows as the sun goes down.
# A one-layer slab with the sun at 60 degrees was R -15% while a single periodic cell's
# sideways source profile was tracked (a sideways centroid means nothing there).
@pytest.mark.parametrize("mu0,rel", [(1.0, 0.007), (0.5, 0.0085), (MU15, 0.0095)])
@pytest.mark.parametrize("vtau", [2.0, 0.5])
@pytest.mark.parametrize("tau,omega", [(t, o) for t, o, _, _ in AD_G08])
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_forward_peaked_slab_against_adding_doubling(tau, omega, vtau, mu0, rel, kernels):
    r_ref, t_ref = adding_doubling(tau, omega, mu0, g=0.8)
    r, t = slab(tau, max(1, int(round(tau / vtau))), omega, 0.8, mu0)
    assert r == pytest.approx(r_ref, rel=rel) and t == pytest.approx(t_ref, rel=rel), (r / r_ref - 1, t / t_ref - 1)


# Cubic voxels (as in a 3-D cloud, unlike the flat voxels of the slabs above: there a
# layer's beams move far sideways) in thin layers, oblique sun.  Measured (2026-11-28):
# g = 0 within 0.31 %, g = 0.8 within 0.83 % (one layer of tau 1, sun 15 deg up: R -0.83 %, and
# -0.82 % at mu0 0.5; -0.80 % and -0.66 % before the sun's first flight took the sub-squares'
# mean directions, see test_forward_peaked_slab_against_adding_doubling; 0.98 % before the second moments,
# the slab profile groups, four peaked orders and 8x8 sub-directions for a low sun; 1.6 % before one voxel
# profile per sweep group and the diffusion-matched bin matrix); before the moments were kept along the
# sweep axis only, g = 0.8 was R -15 % / T +3.8 % (one layer of tau 1, sun at 60 degrees) and R -22 % / T
# +23 % (tau 2, sun at 15 degrees).
@pytest.mark.parametrize("g,rel", [(0.0, 0.0045), (0.8, 0.009)])
@pytest.mark.parametrize("mu0", [1.0, 0.5, MU15])
@pytest.mark.parametrize("tau,layers", [(1.0, 1), (2.0, 1), (2.0, 2), (4.0, 2)])
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_cubic_voxels_in_thin_layers(tau, layers, mu0, g, rel, kernels):
    s = np.sqrt(1 - mu0 * mu0)
    sol = scatter.solve(np.full((layers, 3, 3), tau), (3.0 / layers, 3.0 / layers, 1.0), albedo=1.0, g=g,
                        sun_dir=(s, 0.0, mu0), tol=1e-6, max_passes=5000, periodic=(True, True, False))
    assert sol.converged
    r, t = scatter.slab_reflectance(sol)
    r_ref, t_ref = adding_doubling(tau, 1.0, mu0, g=g)
    assert r == pytest.approx(r_ref, rel=rel) and t == pytest.approx(t_ref, rel=rel), (r / r_ref - 1, t / t_ref - 1)


# The NumPy twins' run of the cases above is in the slow tier; here one cheap case of each property
# on them in the quick tier (the compiled kernels run every case above).
@pytest.mark.parametrize("kernels", ["numpy"], indirect=True)
def test_numpy_twin_keeps_the_accuracy(kernels):
    r, _ = slab(8.0, 8, 1e-3, 0.0, 0.5)
    assert r == pytest.approx(single_scattering_r(1e-3, 0.0, 8.0, 0.5), rel=5e-3)
    r, _ = slab(8.0, 4, 1e-4, 0.8, 0.5)
    assert r == pytest.approx(single_scattering_r(1e-4, 0.8, 8.0, 0.5), rel=5e-3)
    r, t = slab(4.0, 2, 0.99, 0.8, 1.0)
    r_ref, t_ref = adding_doubling(4.0, 0.99, 1.0, g=0.8)
    assert r == pytest.approx(r_ref, rel=0.007) and t == pytest.approx(t_ref, rel=0.007)
    r, _ = slab(32.0, 16, 0.9, 0.0, 1.0)
    assert r == pytest.approx(1 - h_function(0.9)(1.0) * np.sqrt(0.1), rel=5e-3)
