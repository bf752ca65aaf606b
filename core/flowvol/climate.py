"""The globe's winds as a velocity of scene points, for flow volumes over the globe.

A scene point ``p`` is a unit vector times the globe radius of its height
(:func:`~nephele.core.climate.grid.globe_radius`, exaggeration-aware).  Its level
coordinate comes from the grid's mean level heights; the project's
:class:`~nephele.core.flow.advect.WindField` interpolates the winds (trilinear in
level/row/column index, linear in time, rows mirrored across the poles and
periodic longitudes, so generators may straddle the seam or a pole).  On a
curvilinear (2-D longitude/latitude) grid the wind field locates points in the
grid's columns.  On a regional grid (curvilinear, or longitudes that do not
close the circle) the velocity is NaN outside the region (``bounded``):
:func:`~nephele.core.flowvol.volume.flow_volume` stops air that leaves the region at its exit point and
drops the tetrahedra that reach it. Time is in hours; velocities in scene units per hour.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 5).
"""

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, globe_radius, height_from_radius
from ..errors import DataError
from ..flow.advect import WindField, steps_to_keep


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
    stack_mb : float
        The steps a call needs are stacked once (kept between calls) so every
        point is interpolated in one gather, when they take at most this many
        MB; otherwise each step is read on its own.
    """

    def __init__(self, dataset, radius=1.0, exaggeration=DEFAULT_EXAGGERATION, nan="error", keep_hours=48,
                 stack_mb=256):
        self.wind = WindField(dataset, nan=nan, read_ahead=False, cache_steps=steps_to_keep(dataset.grid, keep_hours))
        self.bounded = self.wind.index.bounded  # NaN outside a regional grid (flow_volume stops air there)
        self.radius, self.exaggeration = float(radius), float(exaggeration)
        self.stack_bytes, self._stack = stack_mb * 2**20, None
        h = np.asarray(dataset.grid.height, dtype=np.float64).reshape(self.wind.nk, -1).mean(axis=1)
        self.level_height = h
        self._levels = np.arange(len(h), dtype=np.float64)
        self._hours = np.asarray(self.wind.hours, dtype=np.float64)
        # Scene units per level along the radius (vertical speed from the level rate).
        self._dr_ds = np.gradient(h) * self.radius * self.exaggeration / EARTH_RADIUS if len(h) > 1 else np.zeros(1)

    def _stacked(self, lo, hi):
        """Wind steps ``lo..hi`` (padded, converted) stacked along the level axis, kept between calls; None if
        too big."""
        if self._stack is not None and self._stack[0] <= lo and hi <= self._stack[1]:
            a, _, f = self._stack
            nk = self.wind.nk
            return f[(lo - a) * nk:(hi - a + 1) * nk]
        first = self.wind._step(lo)  # the wind field's converted, padded step (cached there too)
        if first.nbytes * (hi - lo + 1) > self.stack_bytes:
            return None
        f = np.concatenate([first] + [self.wind._step(i) for i in range(lo + 1, hi + 1)], axis=0)
        self._stack = (lo, hi, f)
        return f

    def level(self, points):
        """Fractional level index of scene points (clamped to the grid's levels)."""
        return self._level(np.linalg.norm(points, axis=1))

    def _level(self, r):
        hgt = height_from_radius(r, self.radius, self.exaggeration)
        return (np.interp(hgt, self.level_height, np.arange(len(self.level_height))) if len(self.level_height) > 1
                else np.zeros(len(r)))

    def point(self, lon, lat, height):
        """Scene point of a longitude, latitude (degrees) and height (m)."""
        lam, phi = np.deg2rad(lon), np.deg2rad(lat)
        r = globe_radius(height, self.radius, self.exaggeration)
        return r * np.array([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])

    def __call__(self, points, hours):
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        t = np.broadcast_to(np.asarray(hours, dtype=np.float64), (len(p),))
        r = np.sqrt(np.einsum("ij,ij->i", p, p))
        if not r.all():
            raise DataError("a flow-volume point is at the globe's centre", path=self.wind.dataset.source,
                            field="position")
        unit = p / r[:, None]
        s = self._level(r)
        # Every point has its own time: read the winds at the hourly steps bracketing each
        # point (one call per step, no blended grid per distinct time) and blend linearly.
        hours = self._hours
        t_lo, t_hi = t.min(), t.max()
        self.wind.check_time(t_lo)
        self.wind.check_time(t_hi)
        i0 = np.searchsorted(hours, t, side="right") - 1
        np.clip(i0, 0, max(len(hours) - 2, 0), out=i0)
        w1 = np.clip((t - hours[i0])
                     / (hours[np.minimum(i0 + 1, len(hours) - 1)] - hours[i0] if len(hours) > 1 else 1.0), 0.0, 1.0)
        lo, hi = int(i0[0] if t_lo == t_hi else i0.min()), min(int(i0.max()) + 1, len(hours) - 1)
        stack = self._stacked(lo, hi)
        fr = self.wind.index.fractional(unit, s) if stack is not None or self.bounded else None
        out = (self._stacked_velocity(stack, fr, unit, r, s, i0, w1, lo) if stack is not None
               else self._per_step(p, unit, r, s, i0, w1))
        if self.bounded:
            out[np.isnan(fr[2])] = np.nan
        return out

    def _stacked_velocity(self, stack, fr, unit, r, s, i0, w1, lo):
        """Every point's two bracketing steps in one gather from the steps stacked along the level axis."""
        hours = self._hours
        fk, fj, fi = fr
        nk = self.wind.nk
        upper = np.minimum(i0 + 1, len(hours) - 1)
        both = self.wind.index.trilinear(stack, np.concatenate([(i0 - lo) * nk + fk, (upper - lo) * nk + fk]),
                                         np.concatenate([fj, fj]), np.concatenate([fi, fi])).astype(np.float64)
        n = len(unit)
        f = (1.0 - w1)[:, None] * both[:n] + w1[:, None] * both[n:]
        v = f[:, :3] - np.einsum("ij,ij->i", f[:, :3], unit)[:, None] * unit
        rate = f[:, 3] * np.interp(s, self._levels, self._dr_ds)
        return v * r[:, None] + rate[:, None] * unit

    def _per_step(self, p, unit, r, s, i0, w1):
        """Too many steps to stack: one wind read per hourly step for every point that needs it."""
        hours = self._hours
        out = np.zeros_like(p)
        steps = np.concatenate([i0, np.minimum(i0 + 1, len(hours) - 1)])
        weights = np.concatenate([1.0 - w1, w1])
        owner = np.concatenate([np.arange(len(p)), np.arange(len(p))])
        for step in np.unique(steps):
            use = (steps == step) & (weights > 0)
            sel, w = owner[use], weights[use]
            if len(sel) == 0:
                continue
            v, sdot = self.wind.velocity(float(hours[step]), unit[sel], s[sel])
            rate = sdot * np.interp(s[sel], np.arange(len(self._dr_ds)), self._dr_ds)
            np.add.at(out, sel, w[:, None] * (v * r[sel, None] + rate[:, None] * unit[sel]))
        return out
