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

from ..flow.advect import WindField, steps_to_keep
from ..errors import DataError
from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, globe_radius, height_from_radius


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
    keep_hours : float
        Hours of converted wind steps kept (every RK4 sweep visits the whole
        release window, so fewer than it would re-read every step each sweep).
    """

    def __init__(self, dataset, radius=1.0, exaggeration=DEFAULT_EXAGGERATION, nan="error", keep_hours=48):
        self.wind = WindField(dataset, nan=nan, read_ahead=False, cache_steps=steps_to_keep(dataset.grid, keep_hours))
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
        out = np.zeros_like(p)
        # Every point has its own time: read the winds at the hourly steps bracketing each
        # point (one call per step, no blended grid per distinct time) and blend linearly.
        hours = np.asarray(self.wind.hours, dtype=np.float64)
        for hour in (t.min(), t.max()):
            self.wind.check_time(hour)
        i0 = np.clip(np.searchsorted(hours, t, side="right") - 1, 0, max(len(hours) - 2, 0))
        w1 = np.clip((t - hours[i0]) / (hours[np.minimum(i0 + 1, len(hours) - 1)] - hours[i0] if len(hours) > 1 else 1.0), 0.0, 1.0)
        for i in np.unique(i0):
            sel = i0 == i
            for step, w in ((i, 1.0 - w1[sel]), (min(i + 1, len(hours) - 1), w1[sel])):
                v, sdot = self.wind.velocity(float(hours[step]), unit[sel], s[sel])
                rate = sdot * np.interp(s[sel], np.arange(len(self._dr_ds)), self._dr_ds)
                out[sel] += w[:, None] * (v * r[sel, None] + rate[:, None] * unit[sel])
        return out
