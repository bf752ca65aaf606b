"""Brownian dynamics against closed forms: Stokes-Einstein diffusion, Boltzmann variances, the cycle's
steady state (eigenvector of the rate matrix), elastic-collision conservation laws, hard-core runs."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.muscle import brownian as br
from nephele.core.muscle import lattice as lat

KT = br.KT_300


def test_stokes_einstein_translation():
    # MSD = 2 d D t with D = kT / (6 pi eta r); 30,000 bodies make the 3-D estimate good to 0.5 % (1 sigma).
    rng = np.random.default_rng(0)
    n, r, dt, steps = 30000, 2.5, 0.01, 20
    g = br.translational_drag(r)
    assert g == pytest.approx(6 * np.pi * 1e-3 * 2.5)
    x = np.zeros((n, 3))
    rot = np.broadcast_to(np.eye(3), (n, 3, 3))
    for _ in range(steps):
        x, rot = br.brownian_step(x, rot, dt, g, br.rotational_drag(r), rng)
    D = KT / g
    msd = np.mean(np.sum(x * x, axis=1))
    assert msd / (2 * 3 * D * dt * steps) == pytest.approx(1, abs=0.02)
    # Each axis alone: 2 D t.
    assert np.mean(x[:, 0] ** 2) / (2 * D * dt * steps) == pytest.approx(1, abs=0.02)


def test_stokes_einstein_rotation():
    # A body axis decorrelates as <u(t) . u(0)> = exp(-2 D_r t), D_r = kT / (8 pi eta r^3).
    rng = np.random.default_rng(1)
    n, r = 30000, 3.0
    gr = br.rotational_drag(r)
    Dr = KT / gr
    t_total = 0.25 / Dr
    steps = 40
    dt = t_total / steps
    x = np.zeros((n, 3))
    rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for _ in range(steps):
        x, rot = br.brownian_step(x, rot, dt, br.translational_drag(r), gr, rng)
    corr = np.mean(np.einsum("nii->n", rot)) / 3  # mean of u_k(t) . u_k(0) over the three body axes
    assert corr == pytest.approx(np.exp(-2 * Dr * t_total), rel=0.02)


def test_harmonic_well_variance_is_kT_over_k():
    rng = np.random.default_rng(2)
    n, k, g = 5000, 2.0, 0.05
    dt = 0.01 * g / k  # k dt / g = 0.01: Euler-Maruyama inflates the variance by 0.5 %
    x = np.zeros((n, 3))
    rot = np.broadcast_to(np.eye(3), (n, 3, 3))
    samples = []
    for step in range(1600):
        x, rot = br.brownian_step(x, rot, dt, g, 1.0, rng, force=-k * x)
        if step >= 500 and step % 100 == 0:
            samples.append(x.copy())
    var = np.var(np.concatenate(samples))
    assert var / (KT / k) == pytest.approx(1, abs=0.02)


def test_head_on_hinge_spring_samples_boltzmann():
    # The hinge spring's torque -k * rotvec(R R_eq^T) about a head's rotational drag: each rotation-vector
    # component has variance kT / k (k = 100 kT: the curvature of SO(3) changes it by < 0.2 %).
    rng = np.random.default_rng(3)
    drag = br.Params().head_drag
    k = 100 * KT
    dt = 0.01 * drag / k
    n = 6000
    req = br.rotation_matrix(rng.normal(0, 1, (n, 3)))
    rot = req.copy()
    x = np.zeros((n, 3))
    samples = []
    for step in range(1400):
        tau = -k * br.rotation_vector(rot @ req.transpose(0, 2, 1))
        x, rot = br.brownian_step(x, rot, dt, 1.0, drag, rng, torque=tau)
        if step >= 400 and step % 100 == 0:
            samples.append(br.rotation_vector(rot @ req.transpose(0, 2, 1)))
    var = np.var(np.concatenate(samples))
    assert var / (KT / k) == pytest.approx(1, abs=0.02)


def test_rotation_vector_round_trip():
    rng = np.random.default_rng(4)
    w = rng.normal(0, 1, (500, 3))
    w *= (np.minimum(np.linalg.norm(w, axis=1), 3.0) / np.linalg.norm(w, axis=1))[:, None]
    m = br.rotation_matrix(w)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", m, m), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(br.rotation_vector(m), w, atol=1e-8)
    tiny = br.rotation_matrix(np.array([[1e-10, 0, 0], [0, 0, 0]]))
    np.testing.assert_allclose(tiny[1], np.eye(3))


def test_cycle_steady_state_matches_the_rate_matrix():
    q = br.cycle_generator()
    # Independent truth: the left eigenvector of Q for eigenvalue 0.
    vals, vecs = np.linalg.eig(q.T)
    pi = np.real(vecs[:, np.argmin(np.abs(vals))])
    pi /= pi.sum()
    np.testing.assert_allclose(br.steady_state(q), pi, atol=1e-12)
    # Simulated occupancies (20,000 heads, 1 ms steps, far longer than the 40 ms cycle).
    rng = np.random.default_rng(5)
    p = br.transition_matrix(q, 1e-3)
    s = np.zeros(20000, np.int64)
    counts = np.zeros(5)
    for step in range(300):
        s = br.cycle_step(s, p, rng)
        if step >= 100 and step % 10 == 0:
            counts += np.bincount(s, minlength=5)
    occ = counts / counts.sum()
    big = pi > 0.05
    np.testing.assert_allclose(occ[big] / pi[big], 1, atol=0.02)
    np.testing.assert_allclose(occ, pi, atol=0.003)


def test_two_state_closed_form_and_blocked_binding():
    np.testing.assert_allclose(br.steady_state([[-3.0, 3.0], [1.0, -1.0]]), [0.25, 0.75], atol=1e-12)
    # A blocked transition matrix is used only where blocked is True.
    p = br.transition_matrix(br.cycle_generator(), 1.0)
    stay = np.eye(5)
    rng = np.random.default_rng(6)
    s = np.full(1000, br.M_ADP_PI)
    out = br.cycle_step(s, p, rng, stay, np.ones(1000, bool))
    assert np.all(out == br.M_ADP_PI)
    assert br.cycle_step(np.zeros(0, np.int64), p, rng).shape == (0,)


def test_elastic_collision_conserves_momentum_and_energy():
    rng = np.random.default_rng(7)
    v1, v2 = rng.normal(size=(100, 3)), rng.normal(size=(100, 3))
    m1, m2 = rng.uniform(0.5, 3, 100), rng.uniform(0.5, 3, 100)
    n = rng.normal(size=(100, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    a, b = br.elastic_collision(v1, v2, m1, m2, n)
    np.testing.assert_allclose(m1[:, None] * a + m2[:, None] * b, m1[:, None] * v1 + m2[:, None] * v2, atol=1e-12)
    e0 = m1 * np.sum(v1**2, 1) + m2 * np.sum(v2**2, 1)
    e1 = m1 * np.sum(a**2, 1) + m2 * np.sum(b**2, 1)
    np.testing.assert_allclose(e1, e0, rtol=1e-12)
    # Equal masses head-on: the velocities are exchanged; tangential parts are untouched.
    a, b = br.elastic_collision([1.0, 0.5, 0], [-2.0, 0, 0], 1.0, 1.0, [1.0, 0, 0])
    np.testing.assert_allclose(a, [-2.0, 0.5, 0])
    np.testing.assert_allclose(b, [1.0, 0, 0])


def test_spheres_collide_across_the_periodic_seam():
    # Zero temperature, pushed towards each other across x = 0: they must bounce, not pass through.
    box = np.array([20.0, 20.0, 20.0])
    x = np.array([[1.5, 10, 10], [18.5, 10, 10]])
    f = np.array([[-100.0, 0, 0], [100.0, 0, 0]])
    rng = np.random.default_rng(8)
    y = br.sphere_step(x, 1.0, 0.01, 1.0, rng, box=box, kT=0.0, force=f)
    d = y[0] - y[1]
    d -= np.round(d / box) * box
    assert np.linalg.norm(d) >= 2.0 - 1e-9
    # Momentum (equal masses) is conserved through the bounce: the centre of mass has not moved.
    np.testing.assert_allclose((y[0, 0] + (y[1, 0] - 20)) / 2, (x[0, 0] + (x[1, 0] - 20)) / 2, atol=1e-9)


def test_dense_spheres_never_overlap():
    rng = np.random.default_rng(9)
    box = np.array([30.0, 30.0, 30.0])
    g = np.stack(np.meshgrid(*[np.arange(6) * 5.0 + 2.5] * 3, indexing="ij"), -1).reshape(-1, 3)  # 216 spheres
    x, r = g.copy(), 2.0  # volume fraction 0.27
    for _ in range(200):
        x = br.sphere_step(x, r, 0.05, br.translational_drag(r), rng, box=box)
        d = x[:, None] - x[None]
        d -= np.round(d / box) * box
        dist = np.linalg.norm(d, axis=2) + np.eye(len(x)) * 1e9
        assert dist.min() >= 2 * r - 1e-9
    # They did move (and some left the box: positions are unwrapped).
    assert np.sqrt(np.mean(np.sum((x - g) ** 2, 1))) > 2.0
    assert br.sphere_step(np.zeros((0, 3)), r, 0.05, 1.0, rng, box=box).shape == (0, 3)


def test_zero_temperature_is_deterministic():
    x = np.array([[1.0, 2.0, 3.0]])
    rot = np.eye(3)[None]
    a = br.brownian_step(x, rot, 0.1, 2.0, 1.0, np.random.default_rng(1), force=[[4.0, 0, 0]], kT=0.0)
    b = br.brownian_step(x, rot, 0.1, 2.0, 1.0, np.random.default_rng(2), force=[[4.0, 0, 0]], kT=0.0)
    np.testing.assert_allclose(a[0], [[1.2, 2.0, 3.0]])
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], rot)
    e = br.brownian_step(np.zeros((0, 3)), np.zeros((0, 3, 3)), 0.1, 1.0, 1.0, np.random.default_rng(0))
    assert e[0].shape == (0, 3)


@pytest.mark.parametrize("dt", [10.0, 0.0, -1.0, np.nan, np.inf])
def test_bad_time_steps_rejected(dt):
    with pytest.raises(DataError, match="dt"):
        br.CrossBridges(lat.unit_cell(), br.Params(dt=dt))


def test_huge_step_message_names_the_limit():
    with pytest.raises(DataError, match=r"too long .* use dt <="):
        br.check_step(1.0, 1.0, 5.0)
    with pytest.raises(DataError, match="kT"):
        br.brownian_step(np.zeros((1, 3)), np.eye(3)[None], 0.1, 1.0, 1.0, np.random.default_rng(0), kT=-1)


@pytest.fixture(scope="module")
def run():
    sim = br.CrossBridges(lat.unit_cell(), seed=11)
    record = []
    for _ in range(150):
        sim.step()
        record.append((sim.overlaps().any(), sim.R.copy(), sim.states.copy(), sim.sites.copy(), sim.slide.copy(),
                       sim.collisions, sim.rejected))
    return sim, record


def test_cross_bridges_never_overlap_and_bind(run):
    sim, record = run
    assert not any(r[0] for r in record)
    states = np.array([r[2] for r in record])
    sites = np.array([r[3] for r in record])
    assert np.all((sites >= 0) == br.BOUND[states])
    assert br.BOUND[states].any(axis=1)[-50:].all()  # heads do bind
    # A site holds at most one head.
    for s in sites[-10:]:
        b = s[s >= 0]
        assert len(b) == len(np.unique(b))
    # Bound tips stay near their sites (spring of 0.5 pN/nm: thermal spread ~ 3 nm).
    pos, _ = sim.site_positions()
    bound = sim.sites >= 0
    tip = sim.tips()[bound]
    gap = np.linalg.norm(sim.lattice.min_image(pos[sim.sites[bound]] - tip), axis=1)
    assert gap.max() < 4 * sim.p.capture


def test_same_seed_same_film(run):
    a = br.CrossBridges(lat.unit_cell(), seed=11)
    for _ in range(20):
        a.step()
    sim, record = run
    np.testing.assert_array_equal(a.R, record[19][1])
    np.testing.assert_array_equal(a.states, record[19][2])
    b = br.CrossBridges(lat.unit_cell(), seed=12)
    for _ in range(20):
        b.step()
    assert not np.array_equal(a.R, b.R)


def test_filaments_wrap_periodically():
    cell = lat.unit_cell()
    sim = br.CrossBridges(cell, seed=0)
    sim.slide = np.full(6, 3 * cell.length + 5.0)
    pos, _ = sim.site_positions()
    sim.slide = np.full(6, 5.0)
    pos2, _ = sim.site_positions()
    np.testing.assert_allclose(pos, pos2, atol=1e-9)
    assert np.all((pos[:, 2] >= 0) & (pos[:, 2] < cell.length))


def test_frames_are_recorded():
    sim = br.CrossBridges(lat.unit_cell(), br.Params(frame_time=0.02), seed=3)
    frames = sim.run(3)
    assert len(frames) == 3 and frames[0].time == 0
    assert frames[2].time == pytest.approx(0.04)
    assert sim.run(0) == []


def _one_bound_head(state):
    """Zero temperature, no cycle transitions: one head bound to the site nearest its tip, in ``state``."""
    sim = br.CrossBridges(lat.unit_cell(), br.Params(kT=0.0, rates={}), seed=0)
    pos, fil = sim.site_positions()
    tips = sim.heads.pivots + br.TIP_REACH * sim.R[:, :, 0]
    d = np.linalg.norm(sim.lattice.min_image(tips[:, None] - pos[None]), axis=2)
    i = int(np.argmin(d.min(axis=1)))
    site = int(np.argmin(d[i]))
    sim.states[:] = br.M_ADP_PI
    sim.states[i], sim.sites[i], sim.R_bind[i] = state, site, sim.R[i]
    for _ in range(300):
        sim.step()
    return sim.slide, fil[site]


def test_power_stroke_slides_the_filament_towards_the_m_line():
    weak, f = _one_bound_head(br.AM_ADP_PI)
    strong, f2 = _one_bound_head(br.AM_ADP)
    assert f == f2
    # Only the bound head's filament moves, and the stroke moves it further towards -z than weak binding does.
    others = np.arange(6) != f
    np.testing.assert_array_equal(strong[others], 0.0)
    assert strong[f] - weak[f] < -1.0


def test_rigid_collision_conserves_momentum_angular_momentum_and_energy():
    # Free rigid bodies touching at a point: momentum, angular momentum about the origin and energy conserved,
    # the approach speed at the contact reversed (closed form of the elastic impulse).
    rng = np.random.default_rng(21)
    n = 200
    x1, x2 = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    xc = (x1 + x2) / 2 + 0.3 * rng.normal(size=(n, 3))  # contact point, off both centres
    v1, v2, w1, w2 = (rng.normal(size=(n, 3)) for _ in range(4))
    m1, m2, i1, i2 = (rng.uniform(0.5, 3, n) for _ in range(4))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    r1, r2 = xc - x1, xc - x2
    a, wa, b, wb = br.rigid_collision(v1, w1, v2, w2, 1 / m1, 1 / i1, 1 / m2, 1 / i2, r1, r2, nrm)

    def speed(v1, w1, v2, w2):
        return np.sum((v1 + np.cross(w1, r1) - v2 - np.cross(w2, r2)) * nrm, 1)

    u0, u1 = speed(v1, w1, v2, w2), speed(a, wa, b, wb)
    np.testing.assert_allclose(u1, np.where(u0 < 0, -u0, u0), atol=1e-12)
    assert (u0 < 0).sum() > 50 and np.all(u1 >= -1e-12)
    np.testing.assert_allclose(m1[:, None] * a + m2[:, None] * b, m1[:, None] * v1 + m2[:, None] * v2, atol=1e-12)

    def ang(v1, w1, v2, w2):
        return (m1[:, None] * np.cross(x1, v1) + i1[:, None] * w1 + m2[:, None] * np.cross(x2, v2)
                + i2[:, None] * w2)

    np.testing.assert_allclose(ang(a, wa, b, wb), ang(v1, w1, v2, w2), atol=1e-12)

    def energy(v1, w1, v2, w2):
        return (m1 * np.sum(v1**2, 1) + i1 * np.sum(w1**2, 1) + m2 * np.sum(v2**2, 1) + i2 * np.sum(w2**2, 1)) / 2

    np.testing.assert_allclose(energy(a, wa, b, wb), energy(v1, w1, v2, w2), rtol=1e-12)
    # Hinged bodies (inverse mass 0: the hinge takes the momentum) and a body against an immovable wall:
    # energy conserved, approach reversed, linear velocities untouched.
    z = np.zeros((n, 3))
    _, wa, _, wb = br.rigid_collision(z, w1, z, w2, 0.0, 1 / i1, 0.0, 1 / i2, r1, r2, nrm)
    np.testing.assert_allclose(energy(z, wa, z, wb), energy(z, w1, z, w2), rtol=1e-12)
    np.testing.assert_allclose(speed(z, wa, z, wb), np.abs(speed(z, w1, z, w2)), atol=1e-12)
    _, wa, _, wb = br.rigid_collision(z, w1, z, z, 0.0, 1 / i1, 0.0, 0.0, r1, r2, nrm)
    np.testing.assert_array_equal(wb, 0)
    np.testing.assert_allclose(np.sum(wa**2, 1), np.sum(w1**2, 1), rtol=1e-12)
    # A head swinging straight into a wall: its angular velocity is reversed.
    _, wa, _, _ = br.rigid_collision([0, 0, 0.0], [0, 0, 2.0], [0, 0, 0.0], [0, 0, 0.0], 0.0, 1.0, 0.0, 0.0,
                                     [10.0, 0, 0], [0, 0, 0.0], [0, -1.0, 0])
    np.testing.assert_allclose(wa, [0, 0, -2.0])


def test_heads_bounce_rather_than_refuse(run):
    # Contacts are resolved by elastic bounces; refusing a move is the rare exception.
    sim, record = run
    bounces, refused = sum(r[5] for r in record), sum(r[6] for r in record)
    assert bounces > 1000
    assert refused < 0.02 * bounces


# The full tier's case samples 6000 heads over 1400 steps (27 s on 2 cores, AMD EPYC): 10 samples a
# relaxation time (100 steps) apart after 4 of them, the variance's own error about 0.4 %, so within 2 %;
# the quick tier's 3000 heads over 700 steps (4 samples after 3 relaxation times, which leave 0.25 % of
# the variance to come) about 0.8 %, so within 3 % (measured, seed 31: 0.997 and 1.007).
@pytest.mark.parametrize("n, steps, burn, tol", [pytest.param(6000, 1400, 400, 0.02, marks=pytest.mark.slow),
                                                 (3000, 700, 300, 0.03)])
def test_lever_and_elbow_hinges_each_sample_boltzmann(n, steps, burn, tol):
    # Two hinges per head: the lever about the thick filament (k1) and the motor domain about the elbow (k2).
    # Each rotation vector's components have variance kT / k (springs of 300 kT and the same relaxation time
    # g / k for both, k dt / g = 0.01: Euler-Maruyama +0.5 %, SO(3) curvature well below 1 %).
    rng = np.random.default_rng(31)
    p = br.Params()
    g1, g2 = p.head_drag, p.elbow_drag
    k1 = 300 * KT
    k2 = k1 * g2 / g1
    dt = 0.01 * g1 / k1
    r_eq = br.rotation_matrix(rng.normal(0, 1, (n, 3)))
    q_eq = br.rotation_matrix(rng.normal(0, 0.5, (n, 3)))
    R, Q = r_eq.copy(), q_eq.copy()
    s1, s2 = [], []
    for step in range(steps):
        w1, w2 = br.hinge_velocities(R, Q, r_eq, q_eq, k1, k2, g1, g2, dt, rng, KT)
        R, Q = br.turn_hinges(R, Q, w1, w2, dt)
        if step >= burn and step % 100 == 0:
            s1.append(br.rotation_vector(R @ r_eq.transpose(0, 2, 1)))
            s2.append(br.rotation_vector(Q @ q_eq.transpose(0, 2, 1)))
    v1, v2 = np.var(np.concatenate(s1)), np.var(np.concatenate(s2))
    assert v1 / (KT / k1) == pytest.approx(1, abs=tol)
    assert v2 / (KT / k2) == pytest.approx(1, abs=tol)
    # Turning only the lever carries the motor domain along: its frame relative to the lever is unchanged.
    R2, Q2 = br.turn_hinges(R[:5], Q[:5], rng.normal(size=(5, 3)), np.zeros((5, 3)), 0.1)
    np.testing.assert_allclose(Q2, Q[:5], atol=1e-12)


def test_hinged_collision_conserves_energy_and_reverses_the_approach():
    rng = np.random.default_rng(33)
    m = 300
    wa, wb = rng.normal(size=(m, 2, 3)), rng.normal(size=(m, 2, 3))
    ia, ib = rng.uniform(0.2, 2, (m, 2)), rng.uniform(0.2, 2, (m, 2))
    arms_a, arms_b = rng.normal(size=(m, 2, 3)) * 5, rng.normal(size=(m, 2, 3)) * 5
    arms_a[::3, 1] = 0  # contacts on a lever sphere: the elbow's turn does not move them
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]

    def speed(wa, wb):
        return (np.einsum("mkj,mkj->m", wa, np.cross(arms_a, n[:, None])) -
                np.einsum("mkj,mkj->m", wb, np.cross(arms_b, n[:, None])))

    def energy(wa, wb):
        return (np.einsum("mk,mkj,mkj->m", 1 / ia, wa, wa) + np.einsum("mk,mkj,mkj->m", 1 / ib, wb, wb)) / 2

    a, b = br.hinged_collision(wa, wb, ia, ib, arms_a, arms_b, n)
    u0 = speed(wa, wb)
    assert (u0 < 0).sum() > 100
    np.testing.assert_allclose(speed(a, b), np.abs(u0), atol=1e-10)
    np.testing.assert_allclose(energy(a, b), energy(wa, wb), rtol=1e-12)
    np.testing.assert_array_equal(a[::3, 1], wa[::3, 1])
    # One hinge each: the same as two rigid bodies held at their hinges.
    z = np.zeros((m, 3))
    a1, b1 = br.hinged_collision(wa[:, :1], wb[:, :1], ia[:, :1], ib[:, :1], arms_a[:, :1], arms_b[:, :1], n)
    _, wa2, _, wb2 = br.rigid_collision(z, wa[:, 0], z, wb[:, 0], 0.0, ia[:, 0], 0.0, ib[:, 0], arms_a[:, 0],
                                        arms_b[:, 0], n)
    np.testing.assert_allclose(a1[:, 0], wa2, atol=1e-12)
    np.testing.assert_allclose(b1[:, 0], wb2, atol=1e-12)


def test_heads_bend_at_the_elbow(run):
    sim, record = run
    f = sim.frame()
    np.testing.assert_allclose(f.motor, sim.R @ sim.Q, atol=1e-12)
    bend = np.linalg.norm(br.rotation_vector(sim.Q), axis=1)
    assert 0.05 < np.median(bend) < 1.5
    # The tip sits at the end of the motor domain, from the elbow.
    elbow = sim.heads.pivots + br.ELBOW * sim.R[:, :, 0]
    np.testing.assert_allclose(sim.tips(), elbow + (br.TIP_REACH - br.ELBOW) * f.motor[:, :, 0], atol=1e-12)
