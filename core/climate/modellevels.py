"""Hybrid model levels: pressures from the ``a``/``b`` coefficients and heights by the hypsometric equation.

ECMWF's IFS (and NCEP's GFS) define half levels ``p_{k+1/2} = a_{k+1/2} + b_{k+1/2} p_s``
and full levels as their mean, ``p_k = (p_{k-1/2} + p_{k+1/2}) / 2``.  Heights
come from integrating the hypsometric equation upward from the surface with
the virtual temperature ``T_v = T (1 + (1/ε - 1) q)``:

* half levels: ``z_{k-1/2} = z_{k+1/2} + R_d T_v,k ln(p_{k+1/2} / p_{k-1/2}) / g``;
* full levels: ``z_k = z_{k+1/2} + α_k R_d T_v,k / g`` with
  ``α_k = 1 - p_{k-1/2} / (p_{k+1/2} - p_{k-1/2}) ln(p_{k+1/2} / p_{k-1/2})``
  (``α = ln 2`` in the top layer, whose upper half level is at zero pressure).

Arrays run from the top level down, as the coefficients in GRIB's ``pv`` do.

References
----------
.. [1] ECMWF, IFS Documentation Cy47r3, Part III: Dynamics and numerical procedures, section 2.2
   (eqs. 2.11, 2.20-2.23: half/full-level pressure and geopotential).
.. [2] ECMWF, ``compute_geopotential_on_ml.py`` (the same integration, on GRIB model levels).
"""

import numpy as np

from .humidity import EPSILON, G0, R_DRY


def half_levels(pv):
    """``(a, b, from_top)``: half-level coefficients (``a`` in Pa) from a GRIB ``pv`` array (``a`` values then
    ``b`` values) ordered from the top down, and whether the file lists (and numbers) them from the top
    (ECMWF: model level 1 is the highest) rather than from the surface (NCEP: level 1 is the lowest)."""
    pv = np.asarray(pv, dtype=np.float64).ravel()
    n = pv.size // 2
    a, b = pv[:n], pv[n:]
    if b[0] > b[-1]:  # listed from the surface up (b = 1 at the surface): turn to top-down
        return a[::-1], b[::-1], False
    return a, b, True


def pressure_half(a, b, ps):
    """Half-level pressures ``(n + 1, ...)`` (Pa) for surface pressure ``ps`` (Pa, any shape)."""
    ps = np.asarray(ps, dtype=np.float64)
    return a.reshape((-1,) + (1,) * ps.ndim) + b.reshape((-1,) + (1,) * ps.ndim) * ps[None]


def pressure_full(p_half):
    """Full-level pressures: the mean of the two half levels around each."""
    return 0.5 * (p_half[:-1] + p_half[1:])


def hypsometric_heights(p_half, t, q=None, z_surface=0.0):
    """Full-level heights (m, ``(n, ...)``, top down) from half-level pressures, temperature and specific humidity.

    Parameters
    ----------
    p_half : (n + 1, ...) array
        Half-level pressures (Pa), top down; the last is the surface pressure.
    t : (n, ...) array
        Temperature (K) on the full levels.
    q : (n, ...) array, optional
        Specific humidity (kg/kg); dry air when omitted.
    z_surface : array_like
        Height of the surface (m).
    """
    p = np.asarray(p_half, dtype=np.float64)
    tv = np.asarray(t, dtype=np.float64)
    if q is not None:
        tv = tv * (1.0 + (1.0 / EPSILON - 1.0) * np.asarray(q, dtype=np.float64))
    n = tv.shape[0]
    z_half = np.broadcast_to(np.asarray(z_surface, dtype=np.float64), tv.shape[1:]).copy()
    z_full = np.empty(tv.shape)
    for k in range(n - 1, -1, -1):
        upper, lower = p[k], p[k + 1]
        if np.all(upper <= 0.0):  # the model top: alpha = ln 2
            alpha = np.full(lower.shape, np.log(2.0))
            dlog = None
        else:
            dlog = np.log(lower / upper)
            alpha = 1.0 - upper / (lower - upper) * dlog
        z_full[k] = z_half + alpha * R_DRY * tv[k] / G0
        if dlog is not None:
            z_half = z_half + R_DRY * tv[k] * dlog / G0
    return z_full


__all__ = ["half_levels", "hypsometric_heights", "pressure_full", "pressure_half"]
