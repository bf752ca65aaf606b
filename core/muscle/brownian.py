"""Brownian dynamics of the cross-bridges: heads hinged to the thick filaments, driven through the cycle.

Units: nanometres, microseconds, piconewtons (so energies are pN nm; kT at
300 K is 4.142 pN nm and water's viscosity 1 mPa s is 1e-3 pN us / nm^2).

* **Brownian impulses** (overdamped Langevin, Euler-Maruyama): a body of
  translational drag ``g`` moves ``F / g dt + sqrt(2 kT / g dt) xi`` per step
  and turns by the rotation vector ``tau / g_r dt + sqrt(2 kT / g_r dt) xi``
  (Stokes drags ``6 pi eta r`` and ``8 pi eta r^3``; a head is a chain of
  spheres turning about its hinge, ``sum 6 pi eta r s^2 + 8 pi eta r^3``).
* **Two hinges per head**: the lever turns about its hinge on the thick
  filament (spring :attr:`Params.hinge_stiffness`, drag of the whole head)
  and the motor domain about the elbow at the lever's end (spring
  :attr:`Params.elbow_stiffness`, drag of the motor domain's spheres about
  the elbow); the two springs are independent, so each hinge samples its own
  Boltzmann distribution (:func:`hinge_velocities`, :func:`turn_hinges`).
  Euler-Maruyama on a spring of stiffness ``k`` is stable only for
  ``k dt / g < 2`` and inflates the sampled variance by ``1 / (1 - k dt / 2g)``;
  :func:`check_step` refuses ``k dt / g > MAX_RELAXATION``.
* **Elastic collisions**: free hard spheres move, and pairs that would
  overlap exchange their pseudo-velocities ``dx / dt`` elastically at contact
  (Strating 1999), conserving momentum and kinetic energy.  Heads, which turn
  about their hinges, bounce the same way: a head whose move would overlap an
  actin filament, a thick-filament backbone or another head collides as a
  chain of hinged rigid links (:func:`hinged_collision`, the hinged case of
  :func:`rigid_collision`; pseudo angular velocities ``dw / dt``, inertias =
  the hinges' rotational drags, the hinges taking up the linear momentum,
  filaments immovable across their axes).
  The few moves a bounce cannot clear within a step are refused, so no two
  bodies ever overlap.
* **The cross-bridge cycle** (Lymn-Taylor) is a Markov chain over
  M.ATP (detached, lever down) -> M.ADP.Pi (hydrolysis and recovery stroke,
  lever up) -> A.M.ADP.Pi (weak binding) -> A.M.ADP (Pi release, power
  stroke) -> A.M (ADP release, rigor) -> M.ATP (ATP binding, detachment).
  Each step advances it with the exact transition matrix ``expm(Q dt)``, so
  its occupancies converge to ``Q``'s steady state for any step.  Binding
  needs a free actin site within :attr:`Params.capture` of the head's tip.
* **Animation forces** (the paper's "fake" forces): the state sets the
  lever hinge's rest pose (detached: lever up after the recovery stroke, down
  after detachment; weakly bound: the pose it bound in, so binding strains
  nothing; after Pi release: that pose swung by the power stroke,
  ``pre_stroke - post_stroke`` = 80 degrees, tip towards the M line at -z)
  and the elbow's (straight when detached, the bend it bound with when
  bound), and a bound tip is held to its actin site by a spring; the thin filaments
  slide under the reaction of those springs (contraction towards -z).
* **Time scale**: the Brownian motion runs at its real speed (one film frame
  is :attr:`Params.frame_time` = 0.1 us of it) while the chemistry runs
  :attr:`Params.speedup` = 2e4 times faster than in muscle (a cycle of about
  40 ms then takes about 20 frames), as the original film accelerated the
  cycle with animation forces.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (random
   Brownian impulse forces, elastic bounces, fake animation forces).
.. [2] N. Max, N. Hayashi and T. Wakabayashi, "Computer simulation and
   animation of muscle cross-bridge motion", J. Visualization and Computer
   Animation 1(1), 9-14 (1990).
.. [3] D. L. Ermak and J. A. McCammon, "Brownian dynamics with hydrodynamic
   interactions", J. Chem. Phys. 69, 1352 (1978).
.. [4] P. Strating, "Brownian dynamics simulation of a hard-sphere
   suspension", Phys. Rev. E 59, 2175 (1999) (elastic collisions of
   pseudo-velocities).
.. [5] R. W. Lymn and E. W. Taylor, "Mechanism of adenosine triphosphate
   hydrolysis by actomyosin", Biochemistry 10, 4617-4624 (1971).
.. [6] J. Howard, "Mechanics of Motor Proteins and the Cytoskeleton",
   Sinauer 2001, chapters 2, 13-14 (drag coefficients, myosin II rates).
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import DataError
from . import lattice as lat
from .molecules import LEVER_LENGTH

KT_300 = 4.142
"""Boltzmann's constant times 300 K, pN nm."""

WATER_VISCOSITY = 1e-3
"""1 mPa s in pN us / nm^2."""

MAX_RELAXATION = 0.2
"""Largest ``k dt / drag`` accepted (Euler-Maruyama variance error 11 %; unstable beyond 2)."""

# Cycle states.
M_ATP, M_ADP_PI, AM_ADP_PI, AM_ADP, AM = range(5)
STATE_NAMES = ("M.ATP", "M.ADP.Pi", "A.M.ADP.Pi", "A.M.ADP", "A.M")
BOUND = np.array([False, False, True, True, True])

RATES = {
    (M_ATP, M_ADP_PI): 100.0,  # hydrolysis + recovery stroke
    (M_ADP_PI, M_ATP): 10.0,  # its reversal (hydrolysis equilibrium constant about 10)
    (M_ADP_PI, AM_ADP_PI): 200.0,  # weak binding (when a site is in reach)
    (AM_ADP_PI, M_ADP_PI): 100.0,  # weak detachment
    (AM_ADP_PI, AM_ADP): 50.0,  # Pi release and power stroke (rate-limiting)
    (AM_ADP, AM): 500.0,  # ADP release
    (AM, M_ATP): 1000.0,  # ATP binding and detachment (about 2 mM ATP)
}
"""Rate constants in 1/s for fast skeletal myosin II, representative values after Howard (2001)."""


# --- drag, steps, rotations ---------------------------------------------------


def translational_drag(radius, viscosity=WATER_VISCOSITY):
    """Stokes drag ``6 pi eta r`` of a sphere, pN us / nm."""
    return 6 * np.pi * viscosity * np.asarray(radius, np.float64)


def rotational_drag(radius, viscosity=WATER_VISCOSITY):
    """Stokes rotational drag ``8 pi eta r^3`` of a sphere, pN nm us."""
    return 8 * np.pi * viscosity * np.asarray(radius, np.float64) ** 3


def check_step(dt, drag, stiffness=0.0, *, what="dt"):
    """Refuse a time step that is not positive and finite or too long for the stiffest spring.

    Raises
    ------
    DataError
        If ``dt`` is not a positive finite number or ``stiffness * dt / drag``
        exceeds :data:`MAX_RELAXATION`.
    """
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise DataError(f"must be a positive finite time step in microseconds, got {dt}", field=what)
    ratio = float(np.max(np.asarray(stiffness, np.float64) * dt / np.asarray(drag, np.float64)))
    if ratio > MAX_RELAXATION:
        limit = dt * MAX_RELAXATION / ratio
        raise DataError(f"time step {dt:g} us is too long for the springs: k dt / drag = {ratio:.3g} > "
                        f"{MAX_RELAXATION} (Euler-Maruyama biased or unstable); use dt <= {limit:.3g} us", field=what)
    return dt


def rotation_matrix(rotvec):
    """Rodrigues: rotation vectors (n, 3) -> matrices (n, 3, 3)."""
    w = np.asarray(rotvec, np.float64).reshape(-1, 3)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-8
    k = w / np.where(small, 1.0, th)[:, None]
    kx = np.zeros((len(w), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx = kx - kx.transpose(0, 2, 1)
    s = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))[:, None, None] * th[:, None, None]
    c = np.where(small, th**2 / 2, 1 - np.cos(th))[:, None, None]
    r = np.eye(3) + s * kx + c * kx @ kx
    # Second-order series for tiny angles (k is arbitrary there; use w directly).
    wx = np.zeros((len(w), 3, 3))
    wx[:, 0, 1], wx[:, 0, 2], wx[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    wx = wx - wx.transpose(0, 2, 1)
    return np.where(small[:, None, None], np.eye(3) + wx + wx @ wx / 2, r)


def rotation_vector(mats):
    """Inverse of :func:`rotation_matrix` for angles below pi: (n, 3, 3) -> (n, 3)."""
    m = np.asarray(mats, np.float64).reshape(-1, 3, 3)
    cos = np.clip((np.trace(m, axis1=1, axis2=2) - 1) / 2, -1, 1)
    th = np.arccos(cos)
    v = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1)
    sin = np.sin(th)
    scale = np.where(sin > 1e-8, th / (2 * np.where(sin > 1e-8, sin, 1.0)), 0.5)
    return v * scale[:, None]


def _kT(kT):
    kT = float(kT)
    if not (np.isfinite(kT) and kT >= 0):
        raise DataError(f"must be >= 0 pN nm, got {kT}", field="kT")
    return kT


def brownian_step(positions, rotations, dt, drag, rotational, rng, *, force=None, torque=None, kT=KT_300):
    """One Euler-Maruyama step of free rigid bodies (translation and rotation).

    Parameters
    ----------
    positions : (n, 3) array
    rotations : (n, 3, 3) array
        Body frames (columns are the body axes in the lab).
    dt : float
        Time step, us.
    drag, rotational : float or (n,) array
        Translational (pN us / nm) and rotational (pN nm us) drag.
    rng : numpy.random.Generator
    force, torque : (n, 3) arrays, optional
        Deterministic force (pN) and torque (pN nm) in the lab frame.
    kT : float
        Thermal energy, pN nm; 0 gives the deterministic (noise-free) step.

    Returns
    -------
    positions, rotations : the moved bodies.
    """
    x = np.asarray(positions, np.float64).reshape(-1, 3)
    r = np.asarray(rotations, np.float64).reshape(len(x), 3, 3)
    dt = check_step(dt, 1.0)
    kT = _kT(kT)
    g = np.broadcast_to(np.asarray(drag, np.float64), (len(x),))[:, None]
    gr = np.broadcast_to(np.asarray(rotational, np.float64), (len(x),))[:, None]
    dx = np.sqrt(2 * kT * dt / g) * rng.standard_normal(x.shape)
    dw = np.sqrt(2 * kT * dt / gr) * rng.standard_normal(x.shape)
    if force is not None:
        dx += np.asarray(force, np.float64) * dt / g
    if torque is not None:
        dw += np.asarray(torque, np.float64) * dt / gr
    return x + dx, rotation_matrix(dw) @ r


# --- free hard spheres with elastic collisions --------------------------------


def elastic_collision(v1, v2, m1, m2, normal):
    """Velocities after an elastic collision along unit ``normal`` (rows): momentum and energy conserved.

    Only the components along the normal change; they are exchanged as in a
    one-dimensional elastic collision of masses ``m1`` and ``m2``.
    """
    v1, v2, n = (np.asarray(a, np.float64) for a in (v1, v2, normal))
    m1 = np.asarray(m1, np.float64)[..., None]
    m2 = np.asarray(m2, np.float64)[..., None]
    u = np.sum((v1 - v2) * n, axis=-1, keepdims=True)
    j = 2 * u / (m1 + m2)
    return v1 - j * m2 * n, v2 + j * m1 * n


def rigid_collision(v1, w1, v2, w2, inv_m1, inv_i1, inv_m2, inv_i2, r1, r2, normal):
    """Elastic collision of two rigid bodies touching at one point (rows): momentum and energy conserved.

    Body 1 receives the impulse ``J n`` at arm ``r1`` (contact point minus its
    centre of mass, or minus its hinge), body 2 receives ``-J n`` at ``r2``;
    ``n`` points from body 2 to body 1.  With ``u = (v1 + w1 x r1 - v2 - w2 x
    r2) . n`` the approach speed at the contact, the elastic impulse reverses
    it: ``J = -2 u / (1/m1 + 1/m2 + |r1 x n|^2 / I1 + |r2 x n|^2 / I2)``, which
    conserves the kinetic energy ``sum (m |v|^2 + I |w|^2) / 2``, the momentum
    and the angular momentum about any point.  Inertias are isotropic scalars;
    an inverse mass of 0 is a body held at its hinge (a pivot takes up the
    momentum), an inverse mass and inertia of 0 an immovable obstacle.  Bodies
    already separating (``u >= 0``) are returned unchanged.

    Returns
    -------
    v1, w1, v2, w2 : the velocities and angular velocities after the collision.
    """
    v1, w1, v2, w2, r1, r2, n = (np.asarray(a, np.float64) for a in (v1, w1, v2, w2, r1, r2, normal))
    im1, ii1, im2, ii2 = (np.asarray(a, np.float64)[..., None] for a in (inv_m1, inv_i1, inv_m2, inv_i2))
    a1, a2 = np.cross(r1, n), np.cross(r2, n)
    u = np.sum((v1 - v2) * n, -1, keepdims=True) + np.sum(w1 * a1, -1, keepdims=True) - np.sum(w2 * a2, -1, keepdims=True)
    k = im1 + im2 + ii1 * np.sum(a1 * a1, -1, keepdims=True) + ii2 * np.sum(a2 * a2, -1, keepdims=True)
    j = np.where(u < 0, -2 * u / np.where(k > 0, k, 1.0), 0.0)
    return v1 + im1 * j * n, w1 + ii1 * j * a1, v2 - im2 * j * n, w2 - ii2 * j * a2


def hinged_collision(wa, wb, inv_ia, inv_ib, arms_a, arms_b, normal):
    """Elastic collision of two bodies made of hinged rigid links, touching at one point (rows).

    Each body moves by turning about ``k`` hinges with angular velocities
    ``w`` (m, k, 3) and scalar inertias ``1 / inv_i`` (m, k); ``arms`` (m, k,
    3) are the contact point minus each hinge (zero for a hinge whose turn
    does not move the touching link).  Body a receives ``J n`` and body b
    ``-J n``, ``n`` pointing from b to a; the elastic impulse reverses the
    approach speed ``u`` at the contact,
    ``J = -2 u / sum(inv_i |arm x n|^2)``, which conserves the kinetic energy
    ``sum I |w|^2 / 2`` (the hinges take up the momentum).  An immovable
    obstacle is a body b with ``inv_ib = 0``.  Separating bodies are returned
    unchanged.

    Returns
    -------
    wa, wb : the angular velocities after the collision.
    """
    wa, wb, arms_a, arms_b, n = (np.asarray(a, np.float64) for a in (wa, wb, arms_a, arms_b, normal))
    ia, ib = (np.asarray(a, np.float64)[..., None] for a in (inv_ia, inv_ib))
    a, b = np.cross(arms_a, n[:, None, :]), np.cross(arms_b, n[:, None, :])
    u = np.einsum("mkj,mkj->m", wa, a) - np.einsum("mkj,mkj->m", wb, b)
    k = np.einsum("mkj,mkj->m", ia * a, a) + np.einsum("mkj,mkj->m", ib * b, b)
    j = np.where(u < 0, -2 * u / np.where(k > 0, k, 1.0), 0.0)[:, None, None]
    return wa + ia * j * a, wb - ib * j * b


def hinge_velocities(R, Q, R_eq, Q_eq, k_lever, k_elbow, g_lever, g_elbow, dt, rng, kT=KT_300,
                     torque_lever=None, torque_elbow=None):
    """Euler-Maruyama pseudo angular velocities of a head's two hinges (lab frame).

    The lever's frame ``R`` turns about the hinge on the thick filament; the
    motor domain's frame relative to the lever, ``Q`` (lab frame ``R Q``),
    turns about the elbow (the converter).  The springs ``k_lever
    |rotvec(R R_eq^T)|^2 / 2`` and ``k_elbow |rotvec(Q Q_eq^T)|^2 / 2`` are
    independent (turning the lever carries the motor domain along and leaves
    ``Q`` alone), so with the diagonal drags ``g_lever`` (the whole head about
    its hinge) and ``g_elbow`` (the motor domain about the elbow) each
    hinge's rotation vector samples variance ``kT / k`` per component.

    Returns
    -------
    w_lever, w_elbow : (n, 3) arrays, rad / us; turn with :func:`turn_hinges`.
    """
    t1 = -k_lever * rotation_vector(R @ np.swapaxes(R_eq, -1, -2))
    t2 = -k_elbow * np.einsum("nij,nj->ni", R, rotation_vector(Q @ np.swapaxes(Q_eq, -1, -2)))
    if torque_lever is not None:
        t1 = t1 + torque_lever
    if torque_elbow is not None:
        t2 = t2 + torque_elbow
    n = len(t1)
    w1 = t1 / g_lever + np.sqrt(2 * kT / (g_lever * dt)) * rng.standard_normal((n, 3))
    w2 = t2 / g_elbow + np.sqrt(2 * kT / (g_elbow * dt)) * rng.standard_normal((n, 3))
    return w1, w2


def turn_hinges(R, Q, w_lever, w_elbow, dt):
    """Turn the levers by ``w_lever dt`` (carrying their motor domains) and the motor domains by ``w_elbow dt``."""
    a = rotation_matrix(w_lever * dt)
    R1 = a @ R
    M1 = rotation_matrix(w_elbow * dt) @ (a @ (R @ Q))
    return R1, np.swapaxes(R1, -1, -2) @ M1


def _contact_time(d0, dv, dist):
    """Smallest t in [0, 1] with |d0 + t dv| = dist (rows), or 1 where they never touch."""
    a = np.sum(dv * dv, axis=1)
    b = 2 * np.sum(d0 * dv, axis=1)
    c = np.sum(d0 * d0, axis=1) - dist**2
    disc = np.maximum(b * b - 4 * a * c, 0.0)
    t = (-b - np.sqrt(disc)) / np.where(a > 0, 2 * a, 1.0)
    return np.clip(np.where(a > 0, t, 1.0), 0.0, 1.0)


def _overlaps(x, radii, box):
    from scipy.spatial import cKDTree

    if len(x) < 2:
        return np.zeros((0, 2), np.int64)
    tree = cKDTree(np.mod(x, box), boxsize=box)
    pairs = tree.query_pairs(2 * float(radii.max()), output_type="ndarray")
    if len(pairs) == 0:
        return pairs.reshape(0, 2)
    d = x[pairs[:, 1]] - x[pairs[:, 0]]
    d -= np.round(d / box) * box
    keep = np.linalg.norm(d, axis=1) < radii[pairs[:, 0]] + radii[pairs[:, 1]]
    return pairs[keep]


def sphere_step(positions, radii, dt, drag, rng, *, box, masses=None, kT=KT_300, force=None, passes=20):
    """Brownian step of free hard spheres in a periodic box, resolving contacts by elastic collisions.

    Each sphere's Brownian displacement is a pseudo-velocity ``v = dx / dt``;
    pairs that would overlap collide elastically at their contact time
    (:func:`elastic_collision`, masses default to the drags) and finish the
    step with the new velocities.  After ``passes`` rounds, bodies still in an
    overlap stay where they were (the old positions overlap nothing).

    Returns
    -------
    (n, 3) new positions (not wrapped).
    """
    x0 = np.asarray(positions, np.float64).reshape(-1, 3)
    rad = np.broadcast_to(np.asarray(radii, np.float64), (len(x0),))
    box = np.asarray(box, np.float64)
    dt = check_step(dt, 1.0)
    kT = _kT(kT)
    g = np.broadcast_to(np.asarray(drag, np.float64), (len(x0),))
    m = g if masses is None else np.broadcast_to(np.asarray(masses, np.float64), (len(x0),))
    v = np.sqrt(2 * kT / (g * dt))[:, None] * rng.standard_normal(x0.shape)
    if force is not None:
        v += np.asarray(force, np.float64) / g[:, None]
    start, t0 = x0.copy(), np.zeros(len(x0))
    x = x0 + v * dt
    for _ in range(passes):
        pairs = _overlaps(x, rad, box)
        if len(pairs) == 0:
            return x
        # One collision per sphere per pass: the earliest of its pairs.
        i, j = pairs[:, 0], pairs[:, 1]
        # Separation extrapolated back to the step's start along each one's current segment.
        d0 = (start[j] - v[j] * t0[j, None] * dt) - (start[i] - v[i] * t0[i, None] * dt)
        d0 -= np.round(d0 / box) * box
        tc = _contact_time(d0, (v[j] - v[i]) * dt, rad[i] + rad[j])
        order = np.argsort(tc, kind="stable")
        used = np.zeros(len(x0), bool)
        for k in order:
            a, b = i[k], j[k]
            if used[a] or used[b] or tc[k] < max(t0[a], t0[b]):
                continue
            used[a] = used[b] = True
            t = tc[k]
            pa = start[a] + v[a] * (t - t0[a]) * dt
            pb = start[b] + v[b] * (t - t0[b]) * dt
            n = pb - pa
            n -= np.round(n / box) * box
            n /= max(np.linalg.norm(n), 1e-12)
            va, vb = elastic_collision(v[a], v[b], m[a], m[b], n)
            v[a], v[b] = va, vb
            start[a], start[b], t0[a], t0[b] = pa, pb, t, t
        x = start + v * ((1 - t0) * dt)[:, None]
    # Still overlapping after all passes: those bodies keep their old positions.
    while True:
        pairs = _overlaps(x, rad, box)
        if len(pairs) == 0:
            return x
        stuck = np.unique(pairs)
        x[stuck] = x0[stuck]


# --- the cross-bridge cycle ------------------------------------------------------


def cycle_generator(rates=None):
    """Generator matrix ``Q`` (5, 5) in 1/s of the cycle (rows sum to zero)."""
    rates = RATES if rates is None else rates
    q = np.zeros((5, 5))
    for (a, b), k in rates.items():
        if not (np.isfinite(k) and k >= 0):
            raise DataError(f"rate {STATE_NAMES[a]} -> {STATE_NAMES[b]} must be >= 0 1/s, got {k}", field="rates")
        q[a, b] = k
    q[np.diag_indices(5)] = -q.sum(axis=1)
    return q


def steady_state(q):
    """Stationary occupancies ``p`` with ``p Q = 0``, ``sum p = 1``."""
    q = np.asarray(q, np.float64)
    a = np.vstack([q.T, np.ones(len(q))])
    b = np.zeros(len(q) + 1)
    b[-1] = 1
    return np.linalg.lstsq(a, b, rcond=None)[0]


def transition_matrix(q, dt):
    """Exact one-step transition probabilities ``expm(Q dt)`` (dt in seconds)."""
    from scipy.linalg import expm

    p = expm(np.asarray(q, np.float64) * float(dt))
    p = np.clip(p, 0, None)
    return p / p.sum(axis=1, keepdims=True)


def cycle_step(states, p, rng, p_blocked=None, blocked=None):
    """Advance every head's state one step with transition matrix ``p``.

    Heads with ``blocked`` True (no actin site in reach) use ``p_blocked`` instead.
    """
    s = np.asarray(states)
    cum = np.cumsum(p, axis=1)
    cum[:, -1] = 1.0  # no rounding gap above the last state
    cum = cum[s]
    if blocked is not None and p_blocked is not None:
        cb = np.cumsum(p_blocked, axis=1)
        cb[:, -1] = 1.0
        cum = np.where(blocked[:, None], cb[s], cum)
    u = rng.random(len(s))[:, None]
    return (u >= cum).sum(axis=1)


# --- hinged heads in the lattice ---------------------------------------------------


HEAD_SPHERES = np.array([3.0, 8.5, 14.0])
"""Distances of a head's collision spheres from its hinge along the straight head (S1 is 16.5 nm long)."""

ELBOW = LEVER_LENGTH
"""Distance of the elbow (the converter, where the motor domain turns on the lever) from the hinge, nm."""

MOTOR_SPHERE = HEAD_SPHERES >= ELBOW
"""Which collision spheres belong to the motor domain (they turn about the elbow too)."""

HEAD_SPHERE_RADIUS = 2.5
MAX_BOUND_PER_FILAMENT = 20
"""Bound heads per thin filament assumed by the sliding time-step check."""
TIP_REACH = HEAD_SPHERES[-1]


@dataclass(frozen=True)
class Params:
    """Simulation settings (nm, us, pN).

    Attributes
    ----------
    dt : float
        Brownian time step, us.
    frame_time : float
        Brownian time per film frame, us.
    speedup : float
        Factor by which the chemistry runs faster than in muscle.
    kT, viscosity : float
    hinge_stiffness : float
        Angular spring of the hinge, pN nm / rad^2 (20 kT: about 13 degrees rms).
    elbow_stiffness : float
        Angular spring between lever and motor domain, pN nm / rad^2 (5 kT: about 26 degrees rms; stiffer
        needs a shorter ``dt``, as the motor domain's own drag about the elbow is small).
    bind_stiffness : float
        Spring holding a bound tip to its site, pN / nm.
    capture : float
        A detached, primed head binds a free site within this distance of its tip, nm.
    pre_stroke, post_stroke : float
        Hinge rest tilt towards +z (away from the M line) before and after the power stroke, radians.
    filament_drag : float
        Drag of a thin filament sliding along its axis, pN us / nm (slender body, 1 um long, in water).
    load : float
        Force opposing each thin filament's sliding, pN.
    rates : dict
        Cycle rate constants, 1/s (see :data:`RATES`).
    """

    dt: float = 0.01
    frame_time: float = 0.1
    speedup: float = 2e4
    kT: float = KT_300
    viscosity: float = WATER_VISCOSITY
    hinge_stiffness: float = 20 * KT_300
    elbow_stiffness: float = 5 * KT_300
    bind_stiffness: float = 0.5
    capture: float = 4.0
    pre_stroke: float = np.deg2rad(50.0)
    post_stroke: float = np.deg2rad(-30.0)
    filament_drag: float = 2 * np.pi * WATER_VISCOSITY * 1000.0 / (np.log(1000.0 / 9.0) - 0.2)
    load: float = 0.0
    rates: dict = field(default_factory=lambda: dict(RATES))

    @property
    def head_drag(self):
        """Rotational drag of a head about its hinge (its spheres, Stokes), pN nm us."""
        r = HEAD_SPHERE_RADIUS
        return float(np.sum(translational_drag(r, self.viscosity) * HEAD_SPHERES**2) + 3 * rotational_drag(r, self.viscosity))

    @property
    def elbow_drag(self):
        """Rotational drag of a motor domain about the elbow (its spheres, Stokes), pN nm us."""
        r, s = HEAD_SPHERE_RADIUS, HEAD_SPHERES[MOTOR_SPHERE] - ELBOW
        return float(np.sum(translational_drag(r, self.viscosity) * s**2) + len(s) * rotational_drag(r, self.viscosity))

    @property
    def steps_per_frame(self):
        return max(1, int(round(self.frame_time / self.dt)))


@dataclass
class Frame:
    """The state of the cell at one film frame."""

    rotations: np.ndarray  # (n, 3, 3) lever frames (column 0: along the lever, from hinge to elbow)
    states: np.ndarray  # (n,) cycle state
    sites: np.ndarray  # (n,) bound actin subunit or -1
    slide: np.ndarray  # (6,) thin filament displacement, nm
    time: float  # Brownian time, us
    motor: np.ndarray  # (n, 3, 3) motor domain frames in the lab (column 0: from the elbow to the tip)


def _tilt_frames(heads, tilt):
    """Head frames: x along the head (its rest direction tilted by ``tilt`` towards +z), z near the fibre axis."""
    x0 = heads.rest
    ez = np.array([0.0, 0.0, 1.0])
    t = np.broadcast_to(np.asarray(tilt, np.float64), (len(x0),))
    x = np.cos(t)[:, None] * x0 + np.sin(t)[:, None] * ez
    y = np.cross(ez, x0)
    y /= np.linalg.norm(y, axis=1)[:, None]
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=2)


class CrossBridges:
    """Myosin heads of one unit cell through Brownian motion and the cross-bridge cycle.

    Parameters
    ----------
    lattice : Lattice
    params : Params
    seed : int
        Seeds every random number (same seed, same film).
    """

    def __init__(self, lattice, params=None, seed=0):
        self.lattice = lattice
        self.p = params or Params()
        p = self.p
        self.kT = _kT(p.kT)
        self.drag, self.elbow_drag = p.head_drag, p.elbow_drag
        check_step(p.dt, self.drag, p.hinge_stiffness + p.bind_stiffness * TIP_REACH**2)
        check_step(p.dt, self.elbow_drag, p.elbow_stiffness + p.bind_stiffness * (TIP_REACH - ELBOW) ** 2)
        check_step(p.dt, p.filament_drag, p.bind_stiffness * MAX_BOUND_PER_FILAMENT, what="dt (filament sliding)")
        self.rng = np.random.default_rng(seed)
        self.heads = lat.myosin_heads(lattice)
        n = len(self.heads)
        self._pairs = self._sphere_pairs()
        q = cycle_generator(p.rates)
        chem_dt = p.dt * 1e-6 * p.speedup
        self.P = transition_matrix(q, chem_dt)
        qb = q.copy()
        qb[M_ADP_PI, AM_ADP_PI] = 0
        qb[np.diag_indices(5)] = 0
        qb[np.diag_indices(5)] = -qb.sum(axis=1)
        self.P_blocked = transition_matrix(qb, chem_dt)
        self.slide = np.zeros(6)
        self.time = 0.0
        self.collisions = self.rejected = 0  # of the last step: bounces resolved, moves refused
        # Filament axes in the orthorhombic box (both copies of the cell): xy distances need only box rounding.
        self._axes = [(lattice.to_box(np.column_stack([xy, np.zeros(len(xy))]))[:, :2], rad)
                      for xy, rad in ((lattice.thin_xy, lat.THIN_RADIUS), (lattice.thick_xy, lat.THICK_RADIUS))]
        # Start primed and detached (lever up): that pose clears the thin filaments.
        self.states = np.full(n, M_ADP_PI)
        self.sites = np.full(n, -1)
        self.Q = np.tile(np.eye(3), (n, 1, 1))  # straight heads
        self.Q_bind = self.Q.copy()
        self.R = self._place(_tilt_frames(self.heads, self._rest_tilt(self.states)))
        self.R_bind = self.R.copy()
        # The power stroke turns the head about ez x rest, swinging its tip towards -z (the M line).
        axis = np.cross([0.0, 0.0, 1.0], self.heads.rest)
        self._stroke_axis = axis / np.linalg.norm(axis, axis=1)[:, None]

    # geometry --------------------------------------------------------------------

    def _rest_tilt(self, states):
        return np.where(np.isin(states, (M_ADP_PI, AM_ADP_PI)), self.p.pre_stroke, self.p.post_stroke)

    def spheres(self, R=None, Q=None):
        """(n, 3, 3) collision sphere centres of every head (lever frames ``R``, motor domains ``Q`` on them)."""
        R = self.R if R is None else R
        Q = self.Q if Q is None else Q
        lever, motor = R[:, None, :, 0], (R @ Q)[:, None, :, 0]
        s = HEAD_SPHERES[None, :, None]
        along = np.where(MOTOR_SPHERE[None, :, None], ELBOW * lever + (s - ELBOW) * motor, s * lever)
        return self.heads.pivots[:, None, :] + along

    def tips(self, R=None, Q=None):
        """(n, 3) centres of the heads' tip spheres (the actin-binding end of the motor domain)."""
        return self.spheres(R, Q)[:, -1]

    def site_positions(self, slide=None):
        """(m, 3) binding sites: one per actin subunit, where a bound tip sphere's centre sits."""
        sub = lat.actin_subunits(self.lattice, self.slide if slide is None else slide)
        r = lat.THIN_RADIUS + HEAD_SPHERE_RADIUS + 0.05
        return sub.origins + r * sub.rotations[:, :, 0], sub.filament

    def overlaps(self, R=None, Q=None):
        """Per head: does any of its spheres overlap a thin filament, a thick backbone or another head?

        The tip sphere of a bound head is exempt from the thin filaments (its
        spring holds it at its site); the first spheres of a molecule's two
        heads share the hinge and may touch.
        """
        head, other = self._contacts(R, Q, R, Q)[:2]
        bad = np.zeros(len(self.heads), bool)
        bad[head] = True
        bad[other[other >= 0]] = True
        return bad

    def _contacts(self, R, Q, R0, Q0):
        """Overlaps of the heads in frames ``R, Q``, as collisions to resolve from frames ``R0, Q0``.

        Returns one row per overlapping head sphere and filament, or pair of
        head spheres: arrays ``head``, ``other`` (the other head, or -1 for a
        filament), ``arm``, ``other_arm`` ((m, 2, 3): sphere centre minus the
        hinge and minus the elbow, zero for a lever sphere, in ``R0, Q0``),
        ``normal`` (unit, from the other body towards the head, in ``R0, Q0``)
        and ``depth`` (nm).
        """
        R0 = self.R if R0 is None else R0
        c, c0 = self.spheres(R, Q), self.spheres(R0, Q0)
        n = len(c)
        flat, flat0 = c.reshape(-1, 3), c0.reshape(-1, 3)
        lt = self.lattice
        box = lt.box[:2]
        xy, xy0 = lt.wrap(flat)[:, None, :2], lt.wrap(flat0)[:, None, :2]
        out = []
        for k, (axes, rad) in enumerate(self._axes):
            d = xy - axes[None]
            d -= np.round(d / box) * box
            r2 = np.einsum("nak,nak->na", d, d)
            hit = r2 < (rad + HEAD_SPHERE_RADIUS - 1e-9) ** 2
            if k == 0:  # a bound head's tip rests on its actin: it may press into the thin filament
                hit.reshape(n, 3, -1)[:, -1] &= (self.sites < 0)[:, None]
            s, a = np.nonzero(hit)
            d0 = xy0[s, 0] - axes[a]
            d0 -= np.round(d0 / box) * box
            out.append((s, np.full(len(s), -1), np.column_stack([d0, np.zeros(len(s))]),
                        rad + HEAD_SPHERE_RADIUS - np.sqrt(r2[s, a])))
        i, j, shift = self._pairs
        d = flat[i] - flat[j] + shift
        dist = np.sqrt(np.einsum("nk,nk->n", d, d))
        hit = dist < 2 * HEAD_SPHERE_RADIUS - 1e-9
        out.append((i[hit], j[hit], flat0[i[hit]] - flat0[j[hit]] + shift[hit], 2 * HEAD_SPHERE_RADIUS - dist[hit]))
        s = np.concatenate([o[0] for o in out])
        o = np.concatenate([o[1] for o in out])
        nrm = np.concatenate([o[2] for o in out]).reshape(-1, 3)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-12)[:, None]
        pivots = self.heads.pivots
        elbows = pivots + ELBOW * R0[:, :, 0]

        def arms(sphere, h):
            c = flat0[sphere]
            return np.stack([c - pivots[h], np.where(MOTOR_SPHERE[sphere % 3, None], c - elbows[h], 0.0)], axis=1)

        head, other = s // 3, np.where(o >= 0, o // 3, -1)
        other_arm = np.where((o >= 0)[:, None, None], arms(np.maximum(o, 0), np.maximum(other, 0)), 0.0)
        return head, other, arms(s, head), other_arm, nrm, np.concatenate([o[3] for o in out])

    def _sphere_pairs(self):
        """Head sphere pairs that can ever touch, with the period that brings them together.

        Hinges are fixed, so sphere ``a`` of one head and ``b`` of another can
        touch only if their hinges (in that periodic image) are closer than
        ``s_a + s_b + 2 r``.  Returns flat sphere indices ``i``, ``j`` and the
        (m, 3) period vectors to add to ``c_i - c_j``.
        """
        from scipy.spatial import cKDTree

        lt, piv = self.lattice, self.heads.pivots
        n = len(piv)
        reach = 2 * (HEAD_SPHERES[-1] + HEAD_SPHERE_RADIUS)
        if 2 * reach >= lt.box.min():
            raise DataError(f"the cell ({lt.box.min():.3g} nm across) is too small for heads {reach / 2:.3g} nm long",
                            field="d10")
        both = lt.to_box(piv)
        pq = cKDTree(both, boxsize=lt.box).query_pairs(reach, output_type="ndarray")
        hi, hj = pq[:, 0] % n, pq[:, 1] % n
        d = both[pq[:, 0]] - both[pq[:, 1]]
        d -= np.round(d / lt.box) * lt.box
        t = d - (piv[hi] - piv[hj])
        swap = hi > hj
        hi, hj = np.where(swap, hj, hi), np.where(swap, hi, hj)
        t = np.where(swap[:, None], -t, t)
        keep = hi != hj
        hi, hj, t = hi[keep], hj[keep], t[keep]
        _, first = np.unique(np.column_stack([hi, hj, np.round(t / 1e-3)]), axis=0, return_index=True)
        hi, hj, t = hi[first], hj[first], t[first]
        a, b = (x.reshape(-1) for x in np.meshgrid(np.arange(3), np.arange(3), indexing="ij"))
        hi, hj, t = np.repeat(hi, 9), np.repeat(hj, 9), np.repeat(t, 9, axis=0)
        a, b = np.tile(a, len(first)), np.tile(b, len(first))
        gap = np.linalg.norm(piv[hi] - piv[hj] + t, axis=1)
        sib = (self.heads.molecule[hi] == self.heads.molecule[hj]) & (a == 0) & (b == 0)
        keep = (gap < HEAD_SPHERES[a] + HEAD_SPHERES[b] + 2 * HEAD_SPHERE_RADIUS) & ~sib
        return 3 * hi[keep] + a[keep], 3 * hj[keep] + b[keep], t[keep]

    def _bounce(self, w_lever, w_elbow, passes=4):
        """Elastic collisions of the hinged heads: reflect the pseudo angular velocities of colliding heads.

        ``w_lever``, ``w_elbow`` (n, 3) are each head's rotation vectors of its
        two hinges for this step divided by ``dt`` (Strating's pseudo-velocity).  Each pass finds the heads whose
        trial frames overlap, takes each head's deepest contact, and applies
        :func:`hinged_collision` with the contact normal of the current frames
        (inertias: the hinges' drags; the hinges take up the momentum;
        filaments are immovable across their axes).  Returns the new pseudo
        angular velocities and the number of bounces (approaching contacts).

        Momentum is not a state variable of overdamped Brownian dynamics; as
        in Strating's hard-sphere method, each body's displacement over the
        step divided by ``dt`` stands for its velocity and its drag for its
        mass, so the collision is the inertial rigid-body collision of those
        pseudo-velocities.  The bounce is applied to the whole step (the
        contact normal is taken in the start frames), an error of order one
        step in where the bounce happens; moves still overlapping after the
        passes are refused by the caller.
        """
        dt, inv_i = self.p.dt, np.array([1.0 / self.drag, 1.0 / self.elbow_drag])
        w = np.stack([w_lever, w_elbow], axis=1)
        hits = 0
        for _ in range(passes):
            head, other, arm, oarm, nrm, depth = self._contacts(*turn_hinges(self.R, self.Q, w[:, 0], w[:, 1], dt),
                                                                self.R, self.Q)
            if not len(head):
                break
            # One collision per head per pass, the deepest first.
            used = np.zeros(len(w) + 1, bool)
            pick = []
            for k in np.argsort(-depth, kind="stable").tolist():
                a, b = head[k], other[k]
                if not (used[a] or used[b]):
                    used[a] = used[b] = True
                    used[-1] = False  # index -1: a filament, which takes any number of collisions
                    pick.append(k)
            k = np.array(pick, np.int64)
            a, b = head[k], other[k]
            wall = b < 0
            wa, wb = hinged_collision(w[a], np.where(wall[:, None, None], 0.0, w[b]), np.broadcast_to(inv_i, (len(k), 2)),
                                      np.where(wall[:, None], 0.0, inv_i), arm[k], oarm[k], nrm[k])
            hits += int(np.any(wa != w[a], axis=(1, 2)).sum())
            w[a] = wa
            w[b[~wall]] = wb[~wall]
        return w[:, 0], w[:, 1], hits

    def _place(self, R):
        """Start frames free of overlaps: tilt overlapping heads further until they are free."""
        R = R.copy()
        bad = self.overlaps(R)
        for tries in range(1, 60):
            if not bad.any():
                return R
            idx = np.flatnonzero(bad)
            w = self.rng.normal(0, 0.15 * tries, (len(idx), 3))
            R[idx] = rotation_matrix(w) @ R[idx]
            bad = self.overlaps(R)
        raise DataError("cannot place the myosin heads without overlaps; the lattice is too tight", field="d10")

    # dynamics ---------------------------------------------------------------------

    def _free_site(self, tips, k=6):
        """Nearest free binding site within ``capture`` of each tip, or -1."""
        from scipy.spatial import cKDTree

        sites, _ = self.site_positions()
        m = len(sites)
        tree = cKDTree(self.lattice.to_box(sites), boxsize=self.lattice.box)
        d, idx = tree.query(self.lattice.wrap(tips), k=k, distance_upper_bound=self.p.capture)
        taken = np.zeros(m + 1, bool)
        taken[self.sites[self.sites >= 0]] = True
        taken[m] = True  # "no neighbour" comes back as index 2m
        site = np.where(idx >= 2 * m, m, idx % m)
        ok = ~taken[site]
        first = np.where(ok.any(axis=1), ok.argmax(axis=1), -1)
        return np.where(first >= 0, site[np.arange(len(tips)), np.maximum(first, 0)], -1)

    def _rest_frames(self):
        """Hinge rest frames: detached heads at the global pre/post-stroke tilts; a weakly bound head at the
        pose it bound in (binding strains nothing); after Pi release that pose swung by the power stroke."""
        R_eq = _tilt_frames(self.heads, self._rest_tilt(self.states))
        weak = self.states == AM_ADP_PI
        R_eq[weak] = self.R_bind[weak]
        strong = BOUND[self.states] & ~weak
        if strong.any():
            stroke = (self.p.pre_stroke - self.p.post_stroke) * self._stroke_axis[strong]
            R_eq[strong] = rotation_matrix(stroke) @ self.R_bind[strong]
        # The elbow rests straight, or, bound, at the bend it bound with.
        Q_eq = np.where(BOUND[self.states][:, None, None], self.Q_bind, np.eye(3))
        return R_eq, Q_eq

    def _tip_in_actin(self, idx):
        """(len(idx),) whether each head's tip sphere overlaps a thin filament, and the outward directions."""
        box = self.lattice.box[:2]
        thin = self._axes[0][0]
        tip = self.lattice.wrap(self.tips()[idx])[:, :2]
        d = tip[:, None] - thin[None]
        d -= np.round(d / box) * box
        r2 = np.einsum("nak,nak->na", d, d)
        k = np.argmin(r2, axis=1)
        inside = r2[np.arange(len(idx)), k] < (lat.THIN_RADIUS + HEAD_SPHERE_RADIUS) ** 2
        return inside, np.column_stack([d[np.arange(len(idx)), k], np.zeros(len(idx))])

    def _push_out(self, idx, step=0.05, tries=30):
        """Turn released heads whose tips pressed into the actin out of it about their hinges (the bounce).

        Returns the heads that could not be freed without an overlap; they are put back as they were.
        """
        R0 = self.R[idx].copy()
        todo = idx
        for _ in range(tries):
            inside, out = self._tip_in_actin(todo)
            todo, out = todo[inside], out[inside]
            if not len(todo):
                break
            u = self.tips()[todo] - self.heads.pivots[todo]
            w = np.cross(u, out)
            w *= step / np.maximum(np.linalg.norm(w, axis=1), 1e-12)[:, None]
            self.R[todo] = rotation_matrix(w) @ self.R[todo]
        stuck = idx[self.overlaps()[idx]]
        self.R[stuck] = R0[np.isin(idx, stuck)]
        return stuck

    def _binding_torques(self):
        """Torques of the binding springs about the hinges and elbows, and their pull on each thin filament."""
        n = len(self.heads)
        t1, t2, pull = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(6)
        bound = self.sites >= 0
        if bound.any():
            sites, fil = self.site_positions()
            tip = self.tips()[bound]
            d = self.lattice.min_image(sites[self.sites[bound]] - tip)
            f = self.p.bind_stiffness * d  # on the tip; the reaction pulls the filament
            t1[bound] = np.cross(tip - self.heads.pivots[bound], f)
            t2[bound] = np.cross(tip - (self.heads.pivots[bound] + ELBOW * self.R[bound, :, 0]), f)
            np.add.at(pull, fil[self.sites[bound]], -f[:, 2])
        return t1, t2, pull

    def step(self):
        """One Brownian step: cycle transitions, hinge and binding torques, collisions, sliding."""
        p, rng = self.p, self.rng
        n = len(self.heads)
        # Chemistry: binding needs a free site in reach of the tip (only primed, detached heads look).
        nearest = np.full(n, -1)
        look = np.flatnonzero(self.states == M_ADP_PI)
        if len(look):
            nearest[look] = self._free_site(self.tips()[look])
        reach = nearest >= 0
        new = cycle_step(self.states, self.P, rng, self.P_blocked, ~reach)
        # expm(Q dt) may chain steps (M.ATP -> M.ADP.Pi -> A.M.ADP.Pi): any head newly bound needs a site.
        binding = BOUND[new] & ~BOUND[self.states]
        new[binding & ~reach] = M_ADP_PI
        idx = np.flatnonzero(binding & reach)
        # Two heads reaching for one site: the first keeps it, the other stays detached.
        _, first = np.unique(nearest[idx], return_index=True)
        lose = np.setdiff1d(idx, idx[first])
        new[lose] = M_ADP_PI
        self.sites[idx[first]] = nearest[idx[first]]
        self.R_bind[idx[first]] = self.R[idx[first]]
        self.Q_bind[idx[first]] = self.Q[idx[first]]
        released = np.flatnonzero((self.sites >= 0) & ~BOUND[new])
        old_sites, old_states = self.sites[released], self.states[released]
        self.sites[~BOUND[new]] = -1
        self.states = new
        if len(released):
            stuck = self._push_out(released)
            # A tip that cannot get out of the actin without hitting something stays bound this step.
            keep = np.isin(released, stuck)
            self.sites[released[keep]] = old_sites[keep]
            self.states[released[keep]] = old_states[keep]
        # Mechanics.
        t1, t2, pull = self._binding_torques()
        w1, w2 = hinge_velocities(self.R, self.Q, *self._rest_frames(), p.hinge_stiffness, p.elbow_stiffness, self.drag,
                                  self.elbow_drag, p.dt, rng, self.kT, t1, t2)
        w1, w2, self.collisions = self._bounce(w1, w2)
        R, Q = turn_hinges(self.R, self.Q, w1, w2, p.dt)
        moved = np.ones(n, bool)
        while True:  # moves the bounces could not clear are refused; the old frames overlap nothing
            bad = self.overlaps(R, Q) & moved
            if not bad.any():
                break
            R[bad], Q[bad] = self.R[bad], self.Q[bad]
            moved[bad] = False
        self.rejected = int(n - moved.sum())
        self.R, self.Q = R, Q
        noise = np.sqrt(2 * self.kT * p.dt / p.filament_drag) * rng.standard_normal(6)
        self.slide = self.slide + (pull - p.load) * p.dt / p.filament_drag + noise
        self.time += p.dt

    def frame(self):
        return Frame(self.R.copy(), self.states.copy(), self.sites.copy(), self.slide.copy(), self.time, self.R @ self.Q)

    def run(self, frames):
        """Simulate ``frames`` film frames; returns the list of :class:`Frame` (the first is the start)."""
        frames = int(frames)
        if frames < 0:
            raise DataError(f"must be >= 0, got {frames}", field="frames")
        out = [self.frame()]
        for _ in range(frames - 1):
            for _ in range(self.p.steps_per_frame):
                self.step()
            out.append(self.frame())
        return out[:frames] if frames else []


def with_params(**kw):
    """:class:`Params` with some fields changed (for the CLI and the add-on)."""
    return replace(Params(), **kw)
