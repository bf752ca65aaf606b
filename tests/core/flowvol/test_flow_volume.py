"""Flow volumes against closed forms, a DOP853 reference and the project's climate winds."""

import numpy as np
import pytest
from mesh_checks import check_mesh
from scipy.integrate import solve_ivp

from nephele.core.errors import DataError
from nephele.core.flow.flows import FlowDataset, SolidBodyRotation, sample_grid
from nephele.core.flowvol import ClimateVelocity, flow_volume


def polygon_area(radius, sides):
    return 0.5 * sides * radius**2 * np.sin(2 * np.pi / sides)


def polygon_flux(fv, v, n=60):
    """Flux of a steady ``v`` through the generator polygon: centroid rule on n^2 equal sub-triangles of each
    fan triangle."""
    c, g = fv.generator[0], fv.generator[1:]
    outer = g[1::2]  # rings=2: the outer ring's points (the polygon's corners and edge points)
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    up = i + j < n
    down = i + j < n - 1
    a = np.concatenate([(i[up] + 1 / 3) / n, (i[down] + 2 / 3) / n])
    b = np.concatenate([(j[up] + 1 / 3) / n, (j[down] + 2 / 3) / n])
    flux = 0.0
    for k in range(len(outer)):
        p, q = outer[k] - c, outer[(k + 1) % len(outer)] - c
        pts = c + a[:, None] * p + b[:, None] * q
        flux += 0.5 * np.linalg.norm(np.cross(p, q)) * np.mean(v(pts, 0.0) @ fv.normal)
    return flux


def uniform(p, t):
    return np.tile([0.3, -0.2, 2.0], (len(p), 1))


def shear(p, t):
    return np.stack([0 * p[:, 0], 0 * p[:, 0], 1 + p[:, 0]], axis=1)


def abc(p, t, A=np.sqrt(3), B=np.sqrt(2), C=1.0):
    x, y, z = p.T
    return np.stack([A * np.sin(z) + C * np.cos(y), B * np.sin(x) + A * np.cos(z), C * np.sin(y) + B * np.cos(x)],
                    axis=1)


@pytest.mark.parametrize("sides,duration", [(3, 1.0), (32, 2.5)])
def test_uniform_flow_gives_area_times_speed_times_duration(sides, duration):
    fv = flow_volume(uniform, [1.0, 2.0, 3.0], 0.7, duration, sides=sides)
    speed = np.linalg.norm([0.3, -0.2, 2.0])
    assert fv.volume == pytest.approx(polygon_area(0.7, sides) * speed * duration, rel=1e-12)
    assert np.allclose(fv.normal, np.array([0.3, -0.2, 2.0]) / speed)
    vol = check_mesh(fv)
    assert np.all(vol > 0)
    assert fv.age.min() == 0 and fv.age.max() == pytest.approx(duration)


def test_shear_gives_polygon_area_times_duration():
    fv = flow_volume(shear, [0, 0, 0], 0.5, 2.0, normal=[0, 0, 1], sides=7, rings=3)
    assert fv.volume == pytest.approx(polygon_area(0.5, 7) * 2.0, rel=1e-12)
    check_mesh(fv)


def test_solid_body_rotation_matches_pappus():
    # v = z x p about the z axis; the generator at x = 1 faces +y; the axis lies in its plane.
    def rot(p, t):
        return np.stack([-p[:, 1], p[:, 0], 0 * p[:, 0]], axis=1)
    fv = flow_volume(rot, [1, 0, 0], 0.25, 2.0, sides=16, tol=0.01)
    assert np.allclose(fv.normal, [0, 1, 0])
    exact = polygon_area(0.25, 16) * 2.0 * 1.0
    assert fv.volume == pytest.approx(exact, rel=2e-3)
    check_mesh(fv)


def test_divergence_free_abc_flow_conserves_volume():
    fv = flow_volume(abc, [0.5, 0.3, 0.2], 0.3, 1.0, sides=16, tol=0.02, steps=16)
    flux = polygon_flux(fv, abc)
    assert fv.complete
    assert fv.volume == pytest.approx(flux * 1.0, rel=1e-3)
    check_mesh(fv)


def test_front_matches_dop853_reference_on_abc():
    fv = flow_volume(abc, [0.5, 0.3, 0.2], 0.3, 1.5, sides=12, steps=32)
    first = np.isclose(fv.release, 0.0)
    start = fv.generator
    ref = solve_ivp(lambda t, y: abc(y.reshape(-1, 3), t).ravel(), (0, 1.5), start.ravel(), method="DOP853", rtol=1e-12,
                    atol=1e-12).y[:, -1].reshape(-1, 3)
    got = fv.vertices[first]
    assert np.max(np.linalg.norm(got - ref, axis=1)) < 1e-6


def test_refinement_reintegrates_from_the_generator_on_a_diverging_flow():
    # v = (x, y, 1): exact flow map (x e^a, y e^a, z + a) for age a; the front spreads e^2 = 7.4 times.
    def div(p, t):
        return np.stack([p[:, 0], p[:, 1], np.ones(len(p))], axis=1)
    fv = flow_volume(div, [0, 0, 0], 0.2, 2.0, sides=8, tol=0.1, steps=64)
    assert len(fv.generator) > 1 + 2 * 8  # columns were inserted
    a = fv.age[:, None]
    g = fv.vertices.copy()
    start = np.stack([g[:, 0] * np.exp(-a[:, 0]), g[:, 1] * np.exp(-a[:, 0]), g[:, 2] - a[:, 0]], axis=1)
    # Every vertex came from a point on the generator polygon in z = 0 (not from a chord of the front).
    assert np.max(np.abs(start[:, 2])) < 1e-9
    r = 0.2 * np.cos(np.pi / 8) / np.cos((np.arctan2(start[:, 1], start[:, 0]) % (np.pi / 4)) - np.pi / 8)
    rad = np.hypot(start[:, 0], start[:, 1])
    on_rings = np.min(np.abs(rad[:, None] - np.array([0, 0.5, 1.0])[None] * r[:, None]), axis=1)
    assert np.max(on_rings) < 1e-7
    # Air of age a fills a slab of area A e^(2a) and unit thickness per unit age: V = A (e^(2T) - 1) / 2.
    assert fv.volume == pytest.approx(polygon_area(0.2, 8) * (np.exp(4.0) - 1) / 2, rel=2e-3)


def test_stagnation_point_at_the_centre():
    def para(p, t):
        return np.stack([0 * p[:, 0], 0 * p[:, 0], p[:, 0] ** 2 + p[:, 1] ** 2], axis=1)
    with pytest.raises(DataError, match="calm air"):
        flow_volume(para, [0, 0, 0], 1.0, 1.0)
    fv = flow_volume(para, [0, 0, 0], 1.0, 1.0, normal=[0, 0, 1], sides=24, rings=8, tol=0.05)
    # Flux of r^2 through the regular 24-gon, exact: sum over fan triangles of (|p|^2+|q|^2+p.q)/6 * area.
    ang = 2 * np.pi * np.arange(25) / 24
    p, q = np.stack([np.cos(ang[:-1]), np.sin(ang[:-1])], 1), np.stack([np.cos(ang[1:]), np.sin(ang[1:])], 1)
    tri = 0.5 * np.abs(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0])
    flux = np.sum(tri * (1 + 1 + np.sum(p * q, axis=1)) / 6)
    # Linear tets over the convex r^2 overestimate by O(ring spacing^2): 2.1 % with 4 rings, under 1 % with 8.
    assert fv.volume == pytest.approx(flux, rel=1e-2)
    check_mesh(fv)


def test_zero_wind_and_zero_duration_give_no_smoke():
    def calm(p, t):
        return np.zeros_like(p)
    fv = flow_volume(calm, [0, 0, 0], 1.0, 5.0, normal=[1, 0, 0])
    assert len(fv.tets) == 0 and fv.volume == 0.0 and len(fv.surface.faces) == 0
    fv = flow_volume(uniform, [0, 0, 0], 1.0, 0.0)
    assert len(fv.tets) == 0 and fv.volume == 0.0
    assert len(fv.generator) == 1 + 2 * 32


def test_nan_wind_and_bad_input_raise_data_error():
    def holes(p, t):
        v = uniform(p, t)
        v[p[:, 2] > 1.0] = np.nan
        return v

    with pytest.raises(DataError, match="NaN"):
        flow_volume(holes, [0, 0, 0], 0.5, 2.0)
    with pytest.raises(DataError, match="radius"):
        flow_volume(uniform, [0, 0, 0], -1.0, 2.0)
    with pytest.raises(DataError, match="duration"):
        flow_volume(uniform, [0, 0, 0], 1.0, np.nan)


@pytest.fixture(scope="module")
def rotation_globe():
    # Solid-body rotation tilted to pass near the poles, sampled on a coarse grid (hourly).
    flow = SolidBodyRotation(alpha=np.pi / 2 - 0.05)
    return flow, FlowDataset(flow, hours=25, grid=sample_grid(ni=64, nj=32))


@pytest.mark.parametrize("lonlat", [(0.0, 20.0), (180.0, 88.0)], ids=["seam", "pole"])
def test_climate_winds_solid_body_rotation_across_seam_and_pole(rotation_globe, lonlat):
    flow, ds = rotation_globe
    vel = ClimateVelocity(ds)
    c = vel.point(*lonlat, 5000.0)
    fv = flow_volume(vel, c, 0.02, 12.0, sides=12, rings=1, steps=12)
    axis = np.array([-np.sin(flow.alpha), 0.0, np.cos(flow.alpha)])
    d = np.linalg.norm(c - (c @ axis) * axis)
    angle = 2 * np.pi * 12.0 / flow.period_hours
    # Pappus: the rotation axis lies in the generator plane; grid interpolation error is the tolerance.
    assert fv.volume == pytest.approx(polygon_area(0.02, 12) * angle * d, rel=2e-2)
    check_mesh(fv)
    # Air released at t0 has turned by the rotation angle about the axis.
    from nephele.core.flow.flows import rotate

    first = np.isclose(fv.release, 0.0)
    assert np.max(np.linalg.norm(fv.vertices[first] - rotate(fv.generator, axis, angle), axis=1)) < 2e-3


def test_climate_generator_outside_the_data_time_raises(rotation_globe):
    _, ds = rotation_globe
    vel = ClimateVelocity(ds)
    with pytest.raises(DataError, match="outside"):
        flow_volume(vel, vel.point(0, 0, 5000.0), 0.02, 30.0, sides=6)


def test_converging_flow_merges_front_points_and_keeps_the_volume():
    # v = (-x, 0, 1): exact flow map (x e^-a, y, z + a); air of age a fills area A e^-a per unit
    # height, so V = A (1 - e^-T).  The front narrows to a segment: its points merge.
    def conv(p, t):
        return np.stack([-p[:, 0], 0 * p[:, 0], np.ones(len(p))], axis=1)
    T, exact = 6.0, polygon_area(1.0, 32) * (1 - np.exp(-6.0))
    kept = flow_volume(conv, [0, 0, 0], 1.0, T, normal=[0, 0, 1], sides=32, tol=0.1, steps=64, merge=0.5)
    full = flow_volume(conv, [0, 0, 0], 1.0, T, normal=[0, 0, 1], sides=32, tol=0.1, steps=64, merge=0.0)
    for fv in (kept, full):
        assert fv.volume == pytest.approx(exact, rel=2e-3)
        check_mesh(fv)
    layers = np.unique(kept.release)
    used = np.zeros(len(kept.vertices), dtype=bool)
    used[kept.tets.ravel()] = True
    per_layer = np.bincount(np.searchsorted(layers, kept.release[used]), minlength=len(layers))
    lattice = len(full.generator)
    old = (T - layers) > 3.0
    assert np.all(per_layer[old] <= 0.8 * lattice)  # measured 99 of 129
    assert per_layer[-1] == lattice  # the newest layer is the whole generator
    assert used.sum() < 0.9 * len(kept.vertices)
    # Kept neighbours on the outer ring of every old layer are still within tol.
    for k in np.nonzero(old)[0]:
        pts = kept.vertices[used & np.isclose(kept.release, layers[k])]
        r = np.hypot(pts[:, 0] * np.exp(T - layers[k]), pts[:, 1])  # undo the x compression
        ring = pts[np.isclose(r, r.max(), rtol=0.2)]
        ring = ring[np.argsort(np.arctan2(ring[:, 1], ring[:, 0] * np.exp(T - layers[k])))]
        assert np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).max() < 0.1


def test_merging_leaves_uniform_and_diverging_fronts_alone():
    fv = flow_volume(uniform, [1.0, 2.0, 3.0], 0.7, 2.5, sides=32, merge=0.9)
    assert len(np.unique(fv.tets)) == len(fv.vertices)
    def div(p, t):
        return np.stack([p[:, 0], p[:, 1], np.ones(len(p))], axis=1)
    fv = flow_volume(div, [0, 0, 0], 0.2, 2.0, sides=8, tol=0.1, steps=64, merge=0.9)
    assert len(np.unique(fv.tets)) == len(fv.vertices)


def test_climate_stacked_steps_equal_step_by_step_reads(rotation_globe):
    # One gather from the stacked steps and one read per step give the same winds.
    _, ds = rotation_globe
    stacked, per_step = ClimateVelocity(ds), ClimateVelocity(ds, stack_mb=0)
    rng = np.random.default_rng(3)
    p = np.array([stacked.point(lo, la, h) for lo, la, h in zip(rng.uniform(-180, 180, 200), rng.uniform(-89, 89, 200),
                                                                rng.uniform(0, 9000, 200))])
    t = rng.uniform(0, 24, 200)
    t[:10] = np.round(t[:10])  # exactly on a step
    a, b = stacked(p, t), per_step(p, t)
    assert stacked._stack is not None and per_step._stack is None
    assert np.allclose(a, b, rtol=1e-6, atol=1e-9 * np.abs(b).max())
