"""Closed-form map projections on the sphere (Snyder 1987) for the tests' regional grids.

Independent of the readers' own inverses (``nephele.core.climate.projections``): the tests build 2-D
latitude/longitude grids with these and check what the code does on them.
"""

import numpy as np

EARTH = 6_371_000.0


def lcc_inverse(x, y, lat1=30.0, lat2=60.0, lat0=45.0, lon0=-100.0, radius=EARTH):
    """Lambert conformal conic, eqs. 15-1..15-5, 14-4, 15-10, 15-11: projection metres -> lon in [-180, 180), lat."""
    p1, p2, p0 = np.deg2rad([lat1, lat2, lat0])
    t = lambda p: np.tan(np.pi / 4 + p / 2)  # noqa: E731
    n = np.log(np.cos(p1) / np.cos(p2)) / np.log(t(p2) / t(p1))
    F = np.cos(p1) * t(p1) ** n / n
    rho0 = radius * F / t(p0) ** n
    rho = np.sign(n) * np.hypot(x, rho0 - y)
    lat = 2 * np.arctan((radius * F / rho) ** (1 / n)) - np.pi / 2
    lon = lon0 + np.rad2deg(np.arctan2(x, rho0 - y) / n)
    return (lon + 180.0) % 360.0 - 180.0, np.rad2deg(lat)


def polar_inverse(x, y, radius=EARTH):
    """North polar stereographic, true scale at the pole, eqs. 20-18, 21-15, 20-16: projection metres -> lon, lat."""
    c = 2 * np.arctan(np.hypot(x, y) / (2 * radius))
    return np.rad2deg(np.arctan2(x, -y)), 90.0 - np.rad2deg(c)
