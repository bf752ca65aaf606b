"""A deterministic synthetic climate whose clouds are carried exactly by its winds.

The embedded demo data of Nephele (no downloads): a 320×160×19
longitude × latitude × terrain-following grid, hourly for 10 days from
1987-01-01 (the paper's January run [1]_), with fields ``cloud``,
``temperature``, ``u``, ``v`` and ``w``.  Every step is computed on demand in
closed form; nothing is stored but a few recent steps.

How it works
------------
Each level ``k`` has its own horizontal *flow map* ``X_k(a, t)`` on the unit
sphere: the position at time ``t`` of the air parcel that was at ``a`` at
``t = 0`` (``X_k(a, 0) = a``).  It is a composition of invertible closed-form
maps,

``X_k(·, t) = V_N ∘ … ∘ V_1 ∘ Z``

* ``Z`` — zonal differential rotation about the polar axis by
  ``Θ_k(φ, t)``: westerly jets in mid-latitudes, easterlies in the tropics,
  with strengths that oscillate in time.  Latitude is unchanged by ``Z``, so
  ``Z⁻¹`` is the rotation by ``−Θ_k(φ, t)``.
* ``V_i`` — a vortex "twist": rotation about a fixed axis ``c_i`` by
  ``ψ_i = g_k Γ_i S((t − t_i)/L_i) P(ρ/ρ_i)`` where ``ρ = |p − c_i|`` is the
  chord distance from the centre (kept by the rotation, so ``V_i⁻¹`` is the
  rotation by ``−ψ_i``), ``P(s) = (1 − s²)³`` for ``s < 1`` (compact, C²),
  ``S`` the C² smootherstep from 0 to 1: each storm spins up over
  ``L_i`` = 1–3 days from its birth ``t_i`` and leaves its twist in place.

Both kinds of map are area-preserving, so the horizontal wind on every level
is non-divergent.  The fields follow from the map:

* ``cloud(x, t) = C0_k(X_k⁻¹(x, t))`` with ``C0_k`` a smooth initial
  pattern (storm-track bands, a deep ITCZ just south of the equator, low
  cloud, 3-D "plane-wave" noise for structure; values clipped to 0..1 and
  shaped in height by the level's nominal height);
* horizontal wind = ``∂X_k/∂t`` at ``a = X_k⁻¹(x, t)``, by a central
  difference over ``±δ`` (60 s), projected on east/north and scaled by the
  Earth radius (m/s; the shallow-atmosphere convention: angular speed ×
  ``EARTH_RADIUS`` at every height);
* level heights ``h_k(x) = η_k H + b_k T(x)`` over the relief ``T`` (the
  shipped 1° ETOPO60, sea floor clipped to 0), ``η_k`` from 0 to 1
  (finer near the ground), ``H`` = 20 km, ``b_k = (1 − η_k)³``: terrain
  following at the bottom, flat at the top, strictly increasing wherever
  ``T < H/3``; ``T`` is the relief averaged over each grid cell, and between
  grid nodes it is the bilinear interpolant of those values (so the level
  surfaces are exactly those of the grid);
* ``w`` = the vertical speed of the parcel that stays on its level surface,
  ``Dh_k/Dt = b_k (T(X(a, t+δ)) − T(X(a, t−δ))) / 2δ``;
* ``temperature`` = a January surface temperature by latitude, a 6.5 K/km
  lapse rate up to a latitude-dependent tropopause (isothermal above), plus a
  ±3 K anomaly that is advected like the clouds.

So a parcel moved by ``(u, v, w)`` keeps its level index and its cloudiness:
the clouds are carried exactly by the winds (up to the time-interpolation of
hourly steps and the spatial interpolation of the grid, as with any data).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (the 320×160×19 hourly 10-day climate run of Fig. 1 and its film).
.. [2] D. L. Williamson et al., "A standard test set for numerical
   approximations to the shallow water equations in spherical geometry",
   J. Comput. Phys. 102 (1992) — closed-form flows on the sphere.
"""

import numpy as np

from .dataset import Dataset, Variable
from .errors import DataError
from .grid import EARTH_RADIUS, GlobeGrid
from .relief import load_relief, sample_relief

TOP = 20_000.0
"""Height of the flat model top (metres)."""

DELTA = 1.0
"""Time step of the forward difference ``(X(a, t + δ) − x) / δ`` for the winds (seconds);
its truncation error is ``|acceleration| δ / 2`` < 1e-3 m/s."""

DAY = 86_400.0

SIZES = {
    "full": dict(ni=320, nj=160, nk=19, days=10),
    "small": dict(ni=64, nj=32, nk=8, days=2),
}
"""Preset sizes of :func:`demo_dataset`: the paper's grid and a fast one for tests."""


def _smootherstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def _gauss(x, centre, width):
    return np.exp(-(((x - centre) / width) ** 2))


_ZNODES = np.linspace(-1.0, 1.0, 8193)
"""Nodes in z = sin(latitude) of the zonal rotation tables (linear interpolation between them
defines Θ exactly for the forward and the inverse map alike)."""


# Zonal jets: (centre latitude, width, peak m/s at the jet level, relative oscillation,
# period in days, phase).  January: the northern jet is the stronger.
_JETS = (
    (38.0, 11.0, 38.0, 0.30, 4.0, 0.0),
    (-47.0, 11.0, 28.0, 0.30, 5.0, 1.7),
    (-2.0, 16.0, -9.0, 0.40, 3.0, 0.6),
    (72.0, 8.0, -6.0, 0.50, 6.0, 2.4),
    (-70.0, 8.0, -5.0, 0.50, 6.0, 4.0),
)


class SyntheticClimate(Dataset):
    """The synthetic demo climate (see the module docstring for the model).

    Parameters
    ----------
    ni, nj, nk : int
        Longitudes (evenly spaced from 0 °E), latitudes (cell centres, the
        poles themselves are not rows) and levels.
    days : float
        Length of the hourly time axis (``round(24 * days) + 1`` steps would
        include the end; the axis has ``round(24 * days)`` steps like the
        paper's 240).
    seed : int
        Seed of the storms and cloud patterns; equal seeds give identical data.
    start : str
        First time (ISO date).
    n_storms : int, optional
        Number of vortices; about 2.5 per day by default.
    relief : (lon, lat, elevation), optional
        Relief grid for the terrain (the shipped 1° ETOPO60 by default).
    cache_steps : int
        (field, step) arrays kept in memory.
    """

    def __init__(self, ni=320, nj=160, nk=19, days=10, seed=0, start="1987-01-01", n_storms=None, relief=None, cache_steps=8, source="demo"):
        for name, val, low in (("ni", ni, 3), ("nj", nj, 2), ("nk", nk, 2)):
            if int(val) != val or val < low:
                raise DataError(f"must be an integer >= {low}, got {val!r}", path=source, field=name)
        nt = int(round(24 * days))
        if nt < 1:
            raise DataError(f"needs at least one hour, got {days!r} days", path=source, field="days")
        self.seed = int(seed)
        lon = np.arange(ni) * (360.0 / ni)
        lat = -90.0 + (np.arange(nj) + 0.5) * (180.0 / nj)
        terrain = _cell_mean_terrain(load_relief() if relief is None else relief, lon, lat)
        if terrain.max() >= TOP / 3:
            raise DataError(f"terrain {terrain.max():.0f} m is too high for a {TOP:.0f} m model top", path=source, field="terrain")
        eta = (np.arange(nk) / (nk - 1)) ** 1.4
        self.eta = eta
        self.b = (1.0 - eta) ** 3
        self.nominal_height = eta * TOP
        height = self.nominal_height[:, None, None] + self.b[:, None, None] * terrain[None]
        grid = GlobeGrid(lon, lat, height, terrain).validate(source)
        self._terrain = (lon, lat, terrain)  # T(x): the grid's own terrain, bilinear between its nodes
        times = np.datetime64(start, "s") + np.arange(nt) * np.timedelta64(3600, "s")
        variables = [
            Variable("cloud", "1", "cloud fraction"),
            Variable("temperature", "K", "air temperature"),
            Variable("u", "m/s", "eastward wind"),
            Variable("v", "m/s", "northward wind"),
            Variable("w", "m/s", "upward wind"),
        ]
        super().__init__(grid, times, variables, source, cache_steps)
        self.vertical = f"hybrid height over the ETOPO60 relief, flat top at {TOP / 1000:g} km"
        z = self.nominal_height
        # How strongly each level feels the jets (peak near 11 km) and the storms (weaker aloft).
        self._jet_factor = 0.3 + 0.7 * _gauss(z, 11_000.0, 6_000.0)
        self._storm_factor = np.where(z < 9_000.0, 1.0, 0.35 + 0.65 * _gauss(z, 9_000.0, 6_000.0))
        rng = np.random.default_rng(self.seed)
        self._storms = self._make_storms(rng, days, n_storms)
        phi = np.rad2deg(np.arcsin(_ZNODES))
        self._jet_shapes = [peak / np.cos(np.deg2rad(lat0)) * _gauss(phi, lat0, width) / EARTH_RADIUS for lat0, width, peak, *_ in _JETS]
        self._frames = [self._theta_table(s[5]) for s in self._storms]
        self._noise = [self._make_waves(rng, 10, 5.0, 12.0), self._make_waves(rng, 14, 12.0, 26.0), self._make_waves(rng, 10, 4.0, 14.0)]
        # Grid points as unit vectors (float64) and east/north unit vectors, shape (nj, ni).
        lam, phi = np.deg2rad(lon)[None, :], np.deg2rad(lat)[:, None]
        cl, sl, cp, sp = np.cos(lam), np.sin(lam), np.cos(phi), np.sin(phi)
        self._unit = (cp * cl, cp * sl, sp * np.ones_like(cl))
        self._east = (-sl + 0 * phi, cl + 0 * phi)
        self._north = (-sp * cl, -sp * sl, cp + 0 * lam)
        self._departures = {}
        self._winds = {}
        self._flat = None

    # ----------------------------------------------------------------- parameters
    @staticmethod
    def _make_storms(rng, days, n):
        n = max(1, int(round(4 * days))) if n is None else int(n)
        storms = []
        for _ in range(n):
            tropical = rng.random() < 0.25
            hemi = -1.0 if rng.random() < (0.7 if tropical else 0.5) else 1.0  # tropical storms: mostly SH in January
            lat = hemi * (rng.uniform(8.0, 22.0) if tropical else rng.uniform(33.0, 65.0))
            lon = rng.uniform(0.0, 360.0)
            radius = np.deg2rad(rng.uniform(6.0, 10.0) if tropical else rng.uniform(9.0, 17.0))
            cyclone = tropical or rng.random() < 0.75
            strength = rng.uniform(2.5, 5.0) * (1.0 if cyclone else -0.5) * hemi  # cyclones turn counter-clockwise in the north
            birth = rng.uniform(0.0, max(days - 0.5, 0.0)) * DAY
            life = rng.uniform(1.0, 3.0) * DAY
            c = np.array([np.cos(np.deg2rad(lat)) * np.cos(np.deg2rad(lon)), np.cos(np.deg2rad(lat)) * np.sin(np.deg2rad(lon)), np.sin(np.deg2rad(lat))])
            zlim = (np.sin(np.deg2rad(lat) - radius), np.sin(min(np.deg2rad(lat) + radius, 0.5 * np.pi)))
            storms.append((c, 2.0 * np.sin(radius / 2.0), strength, birth, life, birth + 0.5 * life, zlim))
        storms.sort(key=lambda s: s[5])
        return storms

    @staticmethod
    def _make_waves(rng, n, kmin, kmax):
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        k = d * rng.uniform(kmin, kmax, size=(n, 1))
        return k, rng.uniform(0.0, 2 * np.pi, size=n), rng.uniform(0.5, 1.0, size=n)

    # --------------------------------------------------------------- flow map parts
    def _theta_table(self, t):
        """Zonal rotation angle per unit jet factor after ``t`` seconds, tabulated on ``_ZNODES``."""
        total = np.zeros_like(_ZNODES)
        for (lat0, width, peak, osc, period, phase), shape in zip(_JETS, self._jet_shapes):
            om = 2.0 * np.pi / (period * DAY)
            integral = t - osc / om * (np.cos(om * t + phase) - np.cos(phase))  # ∫0^t (1 + osc sin(om s + phase)) ds
            total += integral * shape
        return total

    @staticmethod
    def _lookup(table, z):
        """Linear interpolation of a table on the uniform nodes ``_ZNODES`` at ``z`` in [-1, 1]."""
        x = (np.clip(z, -1.0, 1.0) + 1.0) * (0.5 * (_ZNODES.size - 1))
        i = np.minimum(x.astype(np.intp), _ZNODES.size - 2)
        f = x - i
        return table[i] * (1.0 - f) + table[i + 1] * f

    @staticmethod
    def _rotate_z(x, y, ang):
        c, s = np.cos(ang), np.sin(ang)
        return c * x - s * y, s * x + c * y

    def _twists(self, p, t, jet, storm, inverse):
        """Apply the storms' twists ``Z_s⁻¹ V_i Z_s`` (or their inverses, in reverse order) to ``p`` in place."""
        x, y, z = p
        order = reversed(self._storms) if inverse else self._storms
        for (c, rho, strength, birth, life, _, (zlo, zhi)), table in zip(order, reversed(self._frames) if inverse else self._frames):
            grow = _smootherstep((t - birth) / life)
            if grow == 0.0:
                continue
            # Z_s keeps latitude: candidates by the cap's latitude range, then the exact chord test.
            cand = np.nonzero((z > zlo) & (z < zhi))[0]
            if cand.size == 0:
                continue
            cj = jet[cand]
            pz = z[cand]
            px, py = self._rotate_z(x[cand], y[cand], cj * self._lookup(table, pz))  # into the storm's frame
            cdot = c[0] * px + c[1] * py + c[2] * pz
            s2 = 2.0 * (1.0 - cdot) / (rho * rho)
            inside = s2 < 1.0
            cand, cj, px, py, pz, cdot, s2 = (v[inside] for v in (cand, cj, px, py, pz, cdot, s2))
            psi = (strength * grow) * storm[cand] * (1.0 - s2) ** 3
            if inverse:
                psi = -psi
            cs, sn = np.cos(psi), np.sin(psi)
            k = cdot * (1.0 - cs)
            qx = px * cs + (c[1] * pz - c[2] * py) * sn + c[0] * k
            qy = py * cs + (c[2] * px - c[0] * pz) * sn + c[1] * k
            qz = pz * cs + (c[0] * py - c[1] * px) * sn + c[2] * k
            x[cand], y[cand] = self._rotate_z(qx, qy, -cj * self._lookup(table, qz))  # back from the storm's frame
            z[cand] = qz
        return p

    def forward(self, a, t, jet, storm):
        """``X(a, t)``: where the parcels labelled by unit vectors ``a`` are at ``t`` seconds.

        ``a`` is a tuple of three flat float64 arrays; ``jet`` and ``storm`` are
        the level factors per point (see :meth:`level_factors`).
        """
        x, y, z = self._twists([np.array(v, dtype=np.float64) for v in a], t, jet, storm, inverse=False)
        x, y = self._rotate_z(x, y, jet * self._lookup(self._theta_table(t), z))
        return x, y, z

    def inverse(self, x, t, jet, storm):
        """``X⁻¹(x, t)``: the labels (positions at ``t = 0``) of the parcels at ``x`` at ``t`` seconds."""
        z = np.array(x[2], dtype=np.float64)
        px, py = self._rotate_z(np.asarray(x[0], dtype=np.float64), np.asarray(x[1], dtype=np.float64), -jet * self._lookup(self._theta_table(t), z))
        return tuple(self._twists([px, py, z], t, jet, storm, inverse=True))

    def level_factors(self, k):
        """Jet and storm strength factors for level indices ``k`` (array)."""
        k = np.asarray(k)
        return self._jet_factor[k], self._storm_factor[k]

    # -------------------------------------------------------------- initial fields
    def _waves(self, which, a):
        kvec, phase, amp = self._noise[which]
        x, y, z = (np.asarray(v, dtype=np.float32) for v in a)
        out = np.zeros(x.shape, dtype=np.float32)
        for (kx, ky, kz), ph, am in zip(kvec.astype(np.float32), phase.astype(np.float32), amp.astype(np.float32)):
            out += am * np.sin(kx * x + ky * y + kz * z + ph)
        return out * np.float32(1.0 / np.sqrt(0.5 * np.sum(amp**2)))  # unit variance

    def initial_cloud(self, a, k):
        """``C0_k(a)``: cloud fraction at ``t = 0`` at unit vectors ``a`` on levels ``k``."""
        z = self.nominal_height[np.asarray(k)].astype(np.float32)
        lat = np.rad2deg(np.arcsin(np.clip(np.asarray(a[2], dtype=np.float32), -1.0, 1.0)))
        n1, n2 = self._waves(0, a), self._waves(1, a)
        storm_track = _gauss(np.abs(lat), 50.0, 12.0) * (1.0 + 0.25 * (lat > 0))
        itcz = _gauss(lat, -4.0, 7.0)
        subtropics = _gauss(np.abs(lat), 24.0, 7.0)
        polar = _gauss(np.abs(lat), 75.0, 10.0)
        low = _gauss(z, 1_200.0, 1_500.0)
        mid = _gauss(z, 4_500.0, 3_500.0)
        deep = _gauss(z, 8_000.0, 6_000.0)
        top = 1.0 / (1.0 + np.exp((z - 15_000.0) / 800.0))
        wet = (
            0.55 * storm_track * (low + mid)
            + 0.7 * itcz * deep
            + 0.25 * polar * low
            + 0.18 * (low + 0.5 * mid)
            - 0.25 * subtropics * (mid + deep)
        )
        c = wet * (1.0 + 0.9 * n1 + 0.45 * n2) * top - 0.1
        return np.clip(c, 0.0, 1.0).astype(np.float32)

    def _anomaly(self, a):
        return 3.0 * self._waves(2, a)

    def background_temperature(self, lat, height):
        """January temperature (K) without the advected anomaly: by latitude and height."""
        s = np.sin(np.deg2rad(lat))
        surface = 299.0 - 40.0 * s * s - 12.0 * s
        tropopause = 16_000.0 - 8_000.0 * s * s
        return surface - 0.0065 * np.minimum(height, tropopause)

    # ------------------------------------------------------------------ per step
    def _flat_grid(self):
        """Grid points as flat unit-vector components and their level factors (computed once)."""
        if self._flat is None:
            nk, nj, ni = self.grid.shape
            x = tuple(np.broadcast_to(u, (nk, nj, ni)).ravel() for u in self._unit)
            self._flat = x, self.level_factors(np.repeat(np.arange(nk), nj * ni))
        return self._flat

    def departure(self, t):
        """Labels (unit vectors at ``t = 0``) of the grid points at step ``t``: three ``(nk, nj, ni)`` arrays."""
        t = int(t) % self.times.size
        if t not in self._departures:
            x, (jet, storm) = self._flat_grid()
            a = self.inverse(x, self.hours[t] * 3600.0, jet, storm)
            if len(self._departures) >= 2:
                self._departures.pop(next(iter(self._departures)))
            self._departures[t] = tuple(v.reshape(self.grid.shape) for v in a)
        return self._departures[t]

    def _wind(self, t):
        if t in self._winds:
            return self._winds[t]
        shape = self.grid.shape
        a = tuple(v.ravel() for v in self.departure(t))
        p0, (jet, storm) = self._flat_grid()
        p1 = self.forward(a, self.hours[t] * 3600.0 + DELTA, jet, storm)
        scale = EARTH_RADIUS / DELTA
        d = [((q1 - q0) * scale).reshape(shape) for q1, q0 in zip(p1, p0)]
        u = d[0] * self._east[0] + d[1] * self._east[1]
        v = d[0] * self._north[0] + d[1] * self._north[1] + d[2] * self._north[2]
        lon1, lat1 = _lonlat(p1)
        lon0, lat0 = _lonlat(p0)
        dterrain = sample_relief(lon1, lat1, self._terrain) - sample_relief(lon0, lat0, self._terrain)
        w = self.b[:, None, None] * dterrain.reshape(shape) / DELTA
        self._winds = {t: (u, v, w)}
        return self._winds[t]

    def _read(self, name, t):
        if name in ("u", "v", "w"):
            return self._wind(t)["uvw".index(name)]
        a = self.departure(t)
        k = np.arange(self.grid.shape[0])[:, None, None]
        if name == "cloud":
            return self.initial_cloud(a, k)
        lat = self.grid.lat[None, :, None]
        return self.background_temperature(lat, self.grid.height) + self._anomaly(a)


def _cell_mean_terrain(relief, lon, lat):
    """Land height (sea floor clipped to 0) averaged over each grid cell, so coarse grids do not alias the relief."""
    rlon = relief[0]
    sub = max(1, int(np.ceil((360.0 / lon.size) / (360.0 / rlon.size))))
    off = (np.arange(sub) + 0.5) / sub - 0.5
    dlon, dlat = 360.0 / lon.size, 180.0 / lat.size
    total = np.zeros((lat.size, lon.size))
    for oy in off:
        for ox in off:
            total += np.maximum(sample_relief(lon[None, :] + ox * dlon, lat[:, None] + oy * dlat, relief), 0.0)
    return total / sub**2


def _lonlat(p):
    x, y, z = p
    return np.rad2deg(np.arctan2(y, x)), np.rad2deg(np.arcsin(np.clip(z, -1.0, 1.0)))


def demo_dataset(size="full", seed=0):
    """The embedded demo climate: ``size="full"`` (320×160×19, 240 hourly steps)
    or ``"small"`` (64×32×8, 48 hourly steps, for tests)."""
    if size not in SIZES:
        raise DataError(f"unknown demo size {size!r} (choose from {', '.join(SIZES)})", path="demo", field="size")
    source = "demo" if size == "full" else f"demo:{size}"
    return SyntheticClimate(**SIZES[size], seed=seed, source=source)


__all__ = ["DELTA", "SIZES", "TOP", "SyntheticClimate", "demo_dataset"]
