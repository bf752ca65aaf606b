"""Trajectories through a wind: Euler, midpoint (RK2) and classical Runge-Kutta (RK4) steps on the sphere.

Integrating in 3-D Cartesian coordinates and renormalising every stage keeps
the poles regular; vertical motion is clamped at the bottom and top levels.
The step is the smaller of ``dt_max`` and a CFL bound from the fastest wind of
the interval.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 4).
"""

import numpy as np

from ._grid_index import _normalise

METHODS = ("euler", "rk2", "rk4")


def trace(wind, xyz, s, t_from, t_to, *, method="rk4", dt_max=1.0, cfl=1.0, vertices=None):
    """Integrate points from time ``t_from`` to ``t_to`` (hours; backwards when ``t_to < t_from``).

    Parameters
    ----------
    wind : WindField or AnalyticWind
    xyz : (n, 3) array
        Unit vectors (normalised here).
    s : (n,) array
        Level coordinates, clamped to ``0..nk-1``.
    method : {"euler", "rk2", "rk4"}
    dt_max : float
        Largest step in hours.
    cfl : float
        Largest displacement per step, in grid spacings (horizontal) or levels.
    vertices : (n,) int array, optional
        Flat grid indices of the points when they are the grid's vertices (and
        ``wind`` a :class:`WindField`): the first stage reads the wind at the
        vertices instead of interpolating it there.

    Returns
    -------
    xyz, s : arrays like the inputs, at ``t_to``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not dt_max > 0 or not cfl > 0:
        raise ValueError("dt_max and cfl must be positive")
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(s, dtype=np.float64).reshape(-1)
    if len(s) != len(xyz):
        raise ValueError(f"xyz has {len(xyz)} points but s has {len(s)}")
    wind.check_time(t_from)
    wind.check_time(t_to)
    xyz = _normalise(xyz)
    top = wind.nk - 1
    s = np.clip(s, 0.0, top)
    span = t_to - t_from
    if span == 0 or len(xyz) == 0:
        return xyz, s
    sp, vr = wind.max_speed(t_from, t_to)
    dt = dt_max
    if sp > 0:
        dt = min(dt, cfl * wind.min_spacing / sp)
    if vr > 0:
        dt = min(dt, cfl / vr)
    n = int(np.ceil(abs(span) / dt - 1e-9))
    h = span / n
    t = t_from
    first = (
        wind.vertex_velocity(t, vertices, xyz) if vertices is not None and hasattr(wind, "vertex_velocity") else None
    )
    for _ in range(n):
        xyz, s = _step(wind, method, t, h, xyz, s, top, first)
        t += h
        first = None
    return xyz, s


def _step(wind, method, t, h, x, s, top, first=None):
    def stage(xb, sb, k, dk, a):
        return _normalise(xb + a * k), np.clip(sb + a * dk, 0.0, top)

    k1, d1 = wind.velocity(t, x, s) if first is None else first
    if method == "euler":
        return stage(x, s, k1, d1, h)
    if method == "rk2":
        x2, s2 = stage(x, s, k1, d1, h / 2)
        k2, d2 = wind.velocity(t + h / 2, x2, s2)
        return stage(x, s, k2, d2, h)
    x2, s2 = stage(x, s, k1, d1, h / 2)
    k2, d2 = wind.velocity(t + h / 2, x2, s2)
    x3, s3 = stage(x, s, k2, d2, h / 2)
    k3, d3 = wind.velocity(t + h / 2, x3, s3)
    x4, s4 = stage(x, s, k3, d3, h)
    k4, d4 = wind.velocity(t + h, x4, s4)
    return stage(x, s, k1 + 2 * k2 + 2 * k3 + k4, d1 + 2 * d2 + 2 * d3 + d4, h / 6)


__all__ = ["METHODS", "trace"]
