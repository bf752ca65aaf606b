"""Analytic test winds with exact trajectories, analytic and sampled on a grid.

Two standard test cases of transport on the sphere:

* Nair & Lauritzen (2010) case 4, a non-divergent deformational flow with a
  translation, reversing in time: every point returns to its start at ``t = T``;
* Williamson et al. (1992) case 1, solid-body rotation about an axis tilted by
  ``alpha`` from the pole: the position at time ``t`` is a single rotation of the
  start (``alpha = pi/2 - 0.05`` carries points almost over the poles).

Each flow gives ``(u, v)`` in m/s at longitudes/latitudes (degrees) and a time
in hours.  :class:`FlowDataset` samples a flow hourly on a longitude–latitude
grid (default 320×160, the paper's resolution) as a lazy
:class:`~nephele.core.climate.dataset.Dataset`, so tests and benchmarks can separate
the integrator's error (analytic wind) from the data interpolation error
(the same wind read from the grid).

References
----------
.. [1] R. D. Nair and P. H. Lauritzen, "A class of deformational flow test cases
   for linear transport problems on the sphere", J. Comput. Phys. 229 (2010)
   8868-8887.
.. [2] D. L. Williamson, J. B. Drake, J. J. Hack, R. Jakob and P. N. Swarztrauber,
   "A standard test set for numerical approximations to the shallow water
   equations in spherical geometry", J. Comput. Phys. 102 (1992) 211-224.
.. [3] N. Max and R. Crawfis, "Visualizing wind velocities by advecting cloud
   textures", Proc. Visualization '92, 179-184.
"""

from dataclasses import dataclass

import numpy as np

from ..climate.dataset import Dataset, Variable, hourly
from ..climate.grid import EARTH_RADIUS, GlobeGrid
from ..errors import DataError

DAY_HOURS = 24.0


@dataclass(frozen=True)
class DeformationalFlow:
    """Nair & Lauritzen (2010) case 4: deformation plus a zonal translation.

    ``u = k sin²λ' sin2θ cos(πt/T) + (2πR/T) cosθ``,
    ``v = k sin2λ' cosθ cos(πt/T)``, ``λ' = λ - 2πt/T``, ``k = 10R/T``.

    Parameters
    ----------
    period_hours : float
        ``T``; the flow reverses at ``T/2`` and every point is back home at ``T``.
    radius : float
        Planet radius ``R`` in metres (winds in m/s scale with it).
    """

    period_hours: float = 12 * DAY_HOURS
    radius: float = EARTH_RADIUS

    def wind(self, lon, lat, hours):
        """``(u, v)`` in m/s at ``lon``, ``lat`` (degrees) and time ``hours``."""
        T = self.period_hours * 3600.0
        t = np.asarray(hours, dtype=np.float64) * 3600.0
        lam = np.deg2rad(np.asarray(lon, dtype=np.float64)) - 2 * np.pi * t / T
        th = np.deg2rad(np.asarray(lat, dtype=np.float64))
        k = 10.0 * self.radius / T
        c = np.cos(np.pi * t / T)
        u = k * np.sin(lam) ** 2 * np.sin(2 * th) * c + 2 * np.pi * self.radius / T * np.cos(th)
        v = k * np.sin(2 * lam) * np.cos(th) * c
        return u, v

    def exact_start(self, xyz, hours):
        """Exact start positions are known only at ``t = 0`` and ``t = T`` (the identity)."""
        h = float(hours)
        if not (abs(h) < 1e-12 or abs(h - self.period_hours) < 1e-9):
            raise ValueError("the deformational flow has a closed-form answer only at t = 0 and t = T")
        return np.array(xyz, dtype=np.float64)


@dataclass(frozen=True)
class SolidBodyRotation:
    """Williamson et al. (1992) case 1: rigid rotation tilted by ``alpha`` (radians).

    ``u = u0 (cosθ cosα + sinθ cosλ sinα)``, ``v = -u0 sinλ sinα``; the rotation
    axis is ``(-sin α, 0, cos α)`` and ``u0 = 2πR / (12 days)``, ``R`` = ``radius`` (m).
    """

    alpha: float = 0.0
    period_hours: float = 12 * DAY_HOURS
    radius: float = EARTH_RADIUS

    @property
    def u0(self):
        return 2 * np.pi * self.radius / (self.period_hours * 3600.0)

    def wind(self, lon, lat, hours):
        """``(u, v)`` in m/s (steady; ``hours`` only broadcasts)."""
        lam = np.deg2rad(np.asarray(lon, dtype=np.float64))
        th = np.deg2rad(np.asarray(lat, dtype=np.float64))
        a = self.alpha
        u = self.u0 * (np.cos(th) * np.cos(a) + np.sin(th) * np.cos(lam) * np.sin(a))
        v = -self.u0 * np.sin(lam) * np.sin(a)
        zero = np.zeros(np.shape(hours))
        return u + zero, v + zero

    def exact_start(self, xyz, hours):
        """Where the points ``xyz`` (unit vectors, (..., 3)) were at ``t = 0``."""
        axis = np.array([-np.sin(self.alpha), 0.0, np.cos(self.alpha)])
        angle = -2 * np.pi * float(hours) / self.period_hours
        return rotate(xyz, axis, angle)


def rotate(xyz, axis, angle):
    """Rodrigues rotation of points ``xyz`` (..., 3) about unit ``axis`` by ``angle`` radians."""
    xyz = np.asarray(xyz, dtype=np.float64)
    k = np.asarray(axis, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    return xyz * c + np.cross(k, xyz) * s + np.outer(xyz.reshape(-1, 3) @ k, k).reshape(xyz.shape) * (1 - c)


def tangent_velocity(lon, lat, u, v):
    """Cartesian velocity (..., 3), same units as ``u``, ``v``, of east/north winds at lon/lat (degrees)."""
    lam = np.deg2rad(np.asarray(lon, dtype=np.float64))
    th = np.deg2rad(np.asarray(lat, dtype=np.float64))
    sl, cl, st, ct = np.sin(lam), np.cos(lam), np.sin(th), np.cos(th)
    return np.stack([-sl * u - st * cl * v, cl * u - st * sl * v, ct * v], axis=-1)


def sample_grid(ni=320, nj=160, heights=(0.0, 10_000.0)):
    """The paper's 320×160 longitude–latitude grid (cell-centred latitudes, no pole rows)."""
    lon = np.arange(ni) * 360.0 / ni
    lat = -90.0 + (np.arange(nj) + 0.5) * 180.0 / nj
    h = np.asarray(heights, dtype=np.float64)[:, None, None] + np.zeros((len(heights), nj, ni))
    return GlobeGrid(lon, lat, h)


class FlowDataset(Dataset):
    """An analytic flow sampled hourly on a grid: fields ``u``, ``v``, ``w`` (zero).

    Steps are computed when read (a 289-step 320×160 dataset would otherwise
    hold ~350 MB), so this behaves exactly like a file of hourly winds.

    Parameters
    ----------
    flow : DeformationalFlow or SolidBodyRotation
    hours : int
        Number of hourly steps (default: the flow's period plus one).
    grid : GlobeGrid, optional
        Default :func:`sample_grid`.
    """

    def __init__(self, flow, hours=None, grid=None):
        self.flow = flow
        grid = grid or sample_grid()
        n = int(round(flow.period_hours)) + 1 if hours is None else int(hours)
        if n < 2:
            raise DataError("needs at least 2 hourly steps", path=f"<{type(flow).__name__}>", field="time")
        super().__init__(grid, hourly("2000-01-01", n),
                         [Variable("u", "m/s"), Variable("v", "m/s"), Variable("w", "m/s")],
                         f"<{type(flow).__name__}>", cache_steps=12)
        self.earth_radius = float(getattr(flow, "radius", EARTH_RADIUS))
        self._lon = np.broadcast_to(grid.lon[None, None, :], grid.shape)
        self._lat = np.broadcast_to(grid.lat[None, :, None], grid.shape)

    def _read(self, name, t):
        if name == "w":
            return np.zeros(self.grid.shape, dtype=np.float32)
        u, v = self.flow.wind(self._lon, self._lat, float(self.hours[t]))
        return u if name == "u" else v


__all__ = ["DeformationalFlow", "FlowDataset", "SolidBodyRotation", "rotate", "sample_grid", "tangent_velocity"]
