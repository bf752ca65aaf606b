"""The globe's winds as a velocity of scene points, for flow volumes over the globe.

A scene point ``p`` is a unit vector times the globe radius of its height
(:func:`~nephele.core.grid.globe_radius`, exaggeration-aware).  Its level
coordinate comes from the grid's mean level heights; the project's
:class:`~nephele.core.advect.WindField` interpolates the winds (trilinear in
level/row/column index, linear in time, rows mirrored across the poles and
periodic longitudes, so generators may straddle the seam or a pole).  Time is
in hours; velocities in scene units per hour.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 5).
"""

import numpy as np

from ..advect import WindField
from ..errors import DataError
from ..grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, globe_radius, height_from_radius


class ClimateVelocity:
    """``velocity(points (n, 3), hours (n,)) -> (n, 3)`` from a climate dataset's winds.

    Parameters
    ----------
    dataset : Dataset
        With ``u``, ``v`` (and optionally ``w``) in m/s.
    radius, exaggeration : float
        The globe's scene radius and vertical exaggeration.
    nan : {"error", "zero"}
        Missing winds raise :class:`DataError` or count as calm air.
    """

    def __init__(self, dataset, radius=1.0, exaggeration=DEFAULT_EXAGGERATION, nan="error"):
        self.wind = WindField(dataset, nan=nan, read_ahead=False)
        self.radius, self.exaggeration = float(radius), float(exaggeration)
        h = np.asarray(dataset.grid.height, dtype=np.float64).reshape(self.wind.nk, -1).mean(axis=1)
        self.level_height = h
        # Scene units per level along the radius (vertical speed from the level rate).
        self._dr_ds = np.gradient(h) * self.radius * self.exaggeration / EARTH_RADIUS if len(h) > 1 else np.zeros(1)

    def level(self, points):
        """Fractional level index of scene points (clamped to the grid's levels)."""
        r = np.linalg.norm(points, axis=1)
        hgt = height_from_radius(r, self.radius, self.exaggeration)
        return np.interp(hgt, self.level_height, np.arange(len(self.level_height))) if len(self.level_height) > 1 else np.zeros(len(r))

    def point(self, lon, lat, height):
        """Scene point of a longitude, latitude (degrees) and height (m)."""
        lam, phi = np.deg2rad(lon), np.deg2rad(lat)
        r = globe_radius(height, self.radius, self.exaggeration)
        return r * np.array([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])

    def __call__(self, points, hours):
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        t = np.broadcast_to(np.asarray(hours, dtype=np.float64), (len(p),))
        r = np.linalg.norm(p, axis=1)
        if np.any(r == 0):
            raise DataError("a flow-volume point is at the globe's centre", path=self.wind.dataset.source, field="position")
        unit = p / r[:, None]
        s = self.level(p)
        out = np.empty_like(p)
        # The wind field takes one time per call: group the points by time (one per layer and stage).
        times, inverse = np.unique(t, return_inverse=True)
        for i, hour in enumerate(times):
            self.wind.check_time(hour)
            sel = inverse.reshape(-1) == i
            v, sdot = self.wind.velocity(float(hour), unit[sel], s[sel])
            out[sel] = v * r[sel, None] + (sdot * np.interp(s[sel], np.arange(len(self._dr_ds)), self._dr_ds))[:, None] * unit[sel]
        return out
