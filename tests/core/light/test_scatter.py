"""The 96-bin shooting solve: slabs against adding-doubling, hard cases, views."""

import numpy as np
import pytest
from kernel_paths import BOTH, EVERY

from nephele.core.errors import DataError
from nephele.core.light import scatter, scatter_task

# Homogeneous slab, normal incidence, no refractive boundary: total R and T
# (T includes the unscattered exp(-tau)) from adding-doubling (facts.md;
# independent Monte Carlo agrees within 0.0015).
AD = [
    # tau, g, albedo, R, T
    (1.0, 0.0, 1.0, 0.34130, 0.65864),
    (1.0, 0.0, 0.99, 0.33289, 0.65095),
    (4.0, 0.8, 1.0, 0.25444, 0.74406),
    (4.0, 0.8, 0.99, 0.23131, 0.70164),
    (16.0, 0.8, 1.0, 0.63252, 0.36486),
    (16.0, 0.8, 0.99, 0.48166, 0.23837),
    (1.0, 0.8, 1.0, 0.06000, 0.93926),
    (4.0, 0.0, 1.0, 0.69075, 0.30894),
]
# Measured (nz=32): worst |R - R_AD| is about +0.004 at tau = 4, g = 0.8 (+0.0070
# before issue 18's exact first flight; +0.0114 before the sun's first two scatterings
# were shot per sub-direction).  Relative checks over voxel depth: test_scatter_voxel_depth.py.


def slab(tau, g, albedo, nz=32, **kw):
    sol = scatter.solve(np.full((nz, 1, 1), tau), (1.0, 1.0, 1.0), albedo=albedo, g=g, sun_dir=(0, 0, 1),
                        tol=1e-5, max_passes=2000, periodic=(True, True, False), **kw)
    return sol, scatter.slab_reflectance(sol)


@pytest.mark.slow
@pytest.mark.parametrize("tau,g,albedo,r_ref,t_ref", AD)
@pytest.mark.parametrize("kernels", BOTH, indirect=True)
def test_slab_against_adding_doubling(tau, g, albedo, r_ref, t_ref, kernels):
    sol, (r, t) = slab(tau, g, albedo)
    assert sol.converged
    assert abs(r - r_ref) <= 0.01 and abs(t - t_ref) <= 0.01, (r, t)


# the thick slab on the NumPy twins (13 s) in the full tier; the thin one on both paths in the quick one
@pytest.mark.parametrize("tau,g,kernels", [(1.0, 0.0, "native"), (1.0, 0.0, "numpy"), (16.0, 0.8, "native"),
                                           pytest.param(16.0, 0.8, "numpy", marks=pytest.mark.slow)],
                         indirect=["kernels"])
def test_slab_conserves_energy_at_albedo_one(tau, g, kernels):
    sol, (r, t) = slab(tau, g, 1.0)
    assert r + t == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("kernels", EVERY, indirect=True)
def test_slab_transmission_of_pure_absorber(kernels):
    sol, (r, t) = slab(2.0, 0.5, 0.0)
    assert r == 0.0 and t == pytest.approx(np.exp(-2.0), rel=1e-6)  # float32 beams


def small_cloud(shape=(8, 10, 10), value=5.0):
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    return np.where(x * x + y * y + z * z < 0.7, value, 0.0)


def test_empty_density():
    sol = scatter.solve(np.zeros((6, 7, 8)), (1, 1, 1), sun_dir=(0.3, 0.2, 1.0))
    assert sol.converged and sol.injected == 0.0 and sol.passes == 0
    cam = scatter.orbit_camera(0.3, (1, 1, 1), width=16, height=12)
    src = scatter.view_source(sol, cam.position)
    img = scatter.render(sol.sigma, src, sol.size, cam)
    assert np.all(src == 0) and np.all(img == 0)


@pytest.mark.parametrize("kernels", EVERY, indirect=True)
def test_very_thick_voxels_no_overflow(kernels):
    sig = small_cloud(value=1e8)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        sol = scatter.solve(sig, (1, 1, 1), sun_dir=(0.2, -0.1, 1.0), albedo=0.9, max_passes=8, total=True)
    for a in (sol.received, sol.total, sol.received_sun, sol.unshot):
        assert np.all(np.isfinite(a))
    # a wall: all entering power is intercepted in the first lit voxels
    assert sol.received_sun.sum() == pytest.approx(sol.injected)
    cam = scatter.orbit_camera(0.5, (1, 1, 1), width=16, height=12)
    img = scatter.render(sig, scatter.view_source(sol, cam.position), (1, 1, 1), cam)
    assert np.all(np.isfinite(img)) and img.max() > 0


def test_albedo_one_stops_at_pass_limit_with_report():
    sol = scatter.solve(small_cloud(value=60.0), (1, 1, 1), albedo=1.0, sun_dir=(0, 0, 1), tol=1e-9, max_passes=3)
    assert not sol.converged and sol.passes == 3
    assert "not converged" in sol.report and "3 passes" in sol.report
    assert len(sol.history) == 4 and sol.history[-1] < sol.history[0]


def test_albedo_one_converges():
    sol = scatter.solve(small_cloud(value=5.0), (1, 1, 1), albedo=1.0, sun_dir=(0, 0, 1), tol=1e-3)
    assert sol.converged and sol.residual <= 1e-3


@pytest.mark.parametrize("sun", [(0, 0, 1), (1, 0, 0), (1, 1, 1), (1, 0, 1), (0.5, 0.5, np.sqrt(0.5))])
def test_sun_along_axis_or_bin_boundary(sun):
    # axis, cube corner, cube edge and an inner bin boundary of the direction cube
    sig = small_cloud()
    sol = scatter.solve(sig, (1, 1, 1), sun_dir=sun, albedo=0.99, g=0.8, tol=1e-3)
    assert sol.converged and np.all(np.isfinite(sol.received))
    # the sun's power is intercepted or passes the far face; nothing is created
    n = np.asarray(sun, float) / np.linalg.norm(sun)
    incident = np.abs(n) @ np.array([1.0, 1.0, 1.0])  # unit irradiance on the unit cube's faces
    assert sol.received_sun.min() >= 0 and 0 < sol.injected <= incident * (1 + 1e-6)


def test_symmetric_cloud_gives_symmetric_light():
    sig = small_cloud(shape=(8, 10, 10))
    sol = scatter.solve(sig, (1, 1, 1), sun_dir=(0, 0, 1), albedo=0.99, g=0.8, tol=1e-4)
    tot = sol.received.sum(0)
    np.testing.assert_allclose(tot, tot[:, :, ::-1], rtol=1e-4, atol=1e-9 * tot.max())
    np.testing.assert_allclose(tot, tot[:, ::-1, :], rtol=1e-4, atol=1e-9 * tot.max())


@pytest.mark.parametrize("g", [0.99, -0.99])
def test_g_near_plus_minus_one(g):
    sol = scatter.solve(small_cloud(), (1, 1, 1), sun_dir=(0.2, 0.1, 1), albedo=0.99, g=g, tol=1e-3, max_passes=200)
    assert sol.converged and np.all(np.isfinite(sol.received))


def test_bad_input():
    with pytest.raises(DataError):
        scatter.solve(np.full((3, 3, 3), np.nan), (1, 1, 1))
    with pytest.raises(DataError):
        scatter.solve(-np.ones((3, 3, 3)), (1, 1, 1))
    with pytest.raises(DataError):
        scatter.solve(np.ones((3, 3, 3)), (1, 1, 1), albedo=1.5)
    with pytest.raises(DataError):
        scatter.solve(np.ones((3, 3, 3)), (1, 1, 1), g=1.0)
    with pytest.raises(DataError):
        scatter.solve(np.ones((3, 3, 3)), (1, 1, 1), sun_dir=(0, 0, 0))
    with pytest.raises(DataError):
        scatter.solve(np.ones((3, 3, 3)), (1, 0, 1))
    with pytest.raises(DataError, match="late_sub"):
        scatter.solve(np.ones((3, 3, 3)), (1, 1, 1), late_sub=0)


def test_progress_steps():
    steps = []
    sol = scatter.solve(small_cloud(), (1, 1, 1), progress=steps.append, tol=1e-2)
    assert steps[0].pass_index == 0 and steps[-1].pass_index == sol.passes
    assert steps[-1].residual == pytest.approx(sol.residual)


def test_render_homogeneous_emission_box():
    # analytic: L = S / sigma * (1 - exp(-sigma * chord)) through a uniform box
    n = 12
    sig = np.full((n, n, n), 3.0)
    src = np.full((n, n, n), 2.0)
    cam = scatter.Camera.look_at((0.5, 0.5, 5.0), (0.5, 0.5, 0.5), up=(0.0, 1.0, 0.0), fov=2.0, width=4, height=4)
    # trilinear fields fall to zero over half a voxel beyond the box on each side
    img = scatter.render(sig, src, (1, 1, 1), cam, step=0.05)
    h = 1.0 / n
    # ramp: value * (0.5 - s/h) for s in (-h/2, h/2), integrated exactly
    ramp_tau = 3.0 * h / 2  # optical depth of each half-voxel ramp
    chord_tau = 3.0 * (1.0 - h)
    tau_total = chord_tau + 2 * ramp_tau
    expect = 2.0 / 3.0 * (1 - np.exp(-tau_total))
    np.testing.assert_allclose(img, expect, rtol=2e-3)


@pytest.mark.parametrize("kernels", EVERY, indirect=True)
def test_total_on_request_changes_nothing_else(kernels, tmp_path):
    # Summing the total flux (solve(total=True)) feeds nothing back: every other array has the same bits,
    # cold and warm-started, and a solution without it saves and loads as one.
    kw = dict(albedo=0.99, g=0.8, sun_dir=(0.3, -0.2, 1.0), tol=1e-3)
    sig = small_cloud(value=30.0)
    with_total, without = (scatter.solve(sig, (1, 1, 0.8), total=t, **kw) for t in (True, False))
    moved = np.roll(sig, 1, axis=2)
    warm = [scatter.solve(moved, (1, 1, 0.8), warm=w, total=w is with_total, **kw) for w in (with_total, without)]
    assert without.total is None and warm[1].total is None and warm[0].warm and warm[1].warm
    for a, b in ((with_total, without), warm):
        assert a.total.shape == a.received.shape and a.total.max() > 0 and np.all(np.isfinite(a.total))
        assert a.history == b.history
        for k in ("received", "received_sun", "received_peaked", "unshot", "exit_flux", "moments_binned"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    for sol in (with_total, without):
        back = scatter.load_solution(scatter.save_solution(sol, tmp_path / "s.npz"))
        assert (back.total is None) == (sol.total is None)
        np.testing.assert_array_equal(back.received, sol.received)
        if sol.total is not None:
            np.testing.assert_array_equal(back.total, sol.total)


def test_save_load_roundtrip(tmp_path):
    sol = scatter.solve(small_cloud(), (1, 1, 0.8), sun_dir=(0.1, 0.2, 1), tol=1e-2)
    p = scatter.save_solution(sol, tmp_path / "s.npz")
    back = scatter.load_solution(p)
    assert back.report == sol.report and back.size == sol.size
    np.testing.assert_array_equal(back.received, sol.received)
    cam = scatter.orbit_camera(1.0, (1, 1, 0.8), width=8, height=6)
    np.testing.assert_array_equal(scatter.view_source(back, cam.position), scatter.view_source(sol, cam.position))
    (tmp_path / "bad.npz").write_bytes(b"nope")
    with pytest.raises(DataError):
        scatter.load_solution(tmp_path / "bad.npz")


def test_scatter_task_matches_solve_and_is_planned(tmp_path):
    from nephele.core.pipeline import tasks
    from nephele.core.volume import cloud_density as cd

    cloud = cd.CloudParams(shape=(6, 8, 8), size=(1.0, 1.0, 0.75), seed=3)
    params = scatter_task.task_params(cloud, 30.0, albedo=0.9, g=0.8, sun_dir=[0.3, 0.1, 1.0], tol=1e-2)
    arrays = tasks.run_cached("scatter", params, tmp_path)
    again = tasks.run_cached("scatter", params, tmp_path)  # from the cache
    sol = scatter.solve(30.0 * cd.cloud_density(cloud), cloud.size, albedo=0.9, g=0.8, sun_dir=(0.3, 0.1, 1.0),
                        tol=1e-2)
    for a in (arrays, again):
        back = scatter.solution_from_arrays(a)
        assert back.report == sol.report
        np.testing.assert_array_equal(back.received, sol.received)
    assert tasks.plan({"kind": "scatter", "solve_task": params}, 7) == [("scatter", params)]
    assert tasks.plan({"kind": "scatter"}, 7) == []
    with pytest.raises(DataError):
        scatter_task.task_params(cloud, 30.0, colour="red")
