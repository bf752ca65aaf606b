"""Brownian dynamics of rigid bodies in water: Stokes drags, overdamped Langevin steps, rotations.

Units: nanometres, microseconds, piconewtons (so energies are pN nm; kT at
300 K is 4.142 pN nm and water's viscosity 1 mPa s is 1e-3 pN us / nm^2).
A body of translational drag ``g`` moves ``F / g dt + sqrt(2 kT / g dt) xi``
per step (Euler-Maruyama) and turns by the rotation vector
``tau / g_r dt + sqrt(2 kT / g_r dt) xi``; a spring of stiffness ``k`` is
stable only for ``k dt / g < 2`` (:func:`check_step`).  The model these serve
is described in :mod:`.brownian`.

References
----------
.. [1] D. L. Ermak and J. A. McCammon, "Brownian dynamics with hydrodynamic
   interactions", J. Chem. Phys. 69, 1352 (1978).
"""

import numpy as np

from ..errors import DataError

KT_300 = 4.142
"""Boltzmann's constant times 300 K, pN nm."""

WATER_VISCOSITY = 1e-3
"""1 mPa s in pN us / nm^2."""

MAX_RELAXATION = 0.2
"""Largest ``k dt / drag`` accepted (Euler-Maruyama variance error 11 %; unstable beyond 2)."""


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

def _cross_matrix(v):
    """(n, 3) -> (n, 3, 3): the matrices [v]x with [v]x u = v x u."""
    m = np.zeros((len(v), 3, 3))
    m[:, 0, 1], m[:, 0, 2], m[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    return m - m.transpose(0, 2, 1)

def _outer_minus_norm(v):
    """[v]x [v]x = v v^T - |v|^2 I, written out (twice as fast as the stacked matmul, within 5e-16)."""
    m = v[:, :, None] * v[:, None, :]
    m[:, (0, 1, 2), (0, 1, 2)] -= np.einsum("ni,ni->n", v, v)[:, None]
    return m

def rotation_matrix(rotvec):
    """Rodrigues: rotation vectors (n, 3) -> matrices (n, 3, 3)."""
    w = np.asarray(rotvec, np.float64).reshape(-1, 3)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-8
    k = w / np.where(small, 1.0, th)[:, None]
    s = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))[:, None, None] * th[:, None, None]
    c = np.where(small, th**2 / 2, 1 - np.cos(th))[:, None, None]
    r = np.eye(3) + s * _cross_matrix(k) + c * _outer_minus_norm(k)
    # Second-order series for tiny angles (k is arbitrary there; use w directly).
    return np.where(small[:, None, None], np.eye(3) + _cross_matrix(w) + _outer_minus_norm(w) / 2, r)

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
