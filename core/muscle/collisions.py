"""Hard bodies that bounce: free spheres and heads hinged to the thick filaments, colliding elastically.

Free hard spheres move, and pairs that would overlap exchange their
pseudo-velocities ``dx / dt`` elastically at contact (Strating 1999),
conserving momentum and kinetic energy.  Heads, which turn about their
hinges, bounce the same way, as chains of hinged rigid links
(:func:`hinged_collision`, the hinged case of :func:`rigid_collision`).  The
few moves a bounce cannot clear within a step are refused, so no two bodies
ever overlap.

References
----------
.. [1] P. Strating, "Brownian dynamics simulation of a hard-sphere
   suspension", Phys. Rev. E 59, 2175 (1999).
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization" (elastic bounces).
"""

import numpy as np

from .dynamics import KT_300, _kT, check_step, rotation_matrix, rotation_vector


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
    u = (
        np.sum((v1 - v2) * n, -1, keepdims=True)
        + np.sum(w1 * a1, -1, keepdims=True)
        - np.sum(w2 * a2, -1, keepdims=True)
    )
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
