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

``X_k(·, t) = Z_t ∘ W_N ∘ … ∘ W_1``,   ``W_i = Z_{s_i}⁻¹ ∘ V_i(t) ∘ Z_{s_i}``

* ``Z_t`` — zonal differential rotation about the polar axis by
  ``j_k Θ(φ, t)``: westerly jets near 38 °N and 47 °S, easterlies in the
  tropics and near the poles, strengths oscillating in time (periods of 3–6
  days), ``j_k`` peaking near 11 km.  ``Θ`` is tabulated in ``z = sin φ`` and
  interpolated linearly, the same way for the map and its inverse.  Latitude
  is unchanged by ``Z``, so ``Z⁻¹`` is the rotation by ``−j_k Θ``, and all
  ``Z`` commute.
* ``V_i(t)`` — storm group ``i``: vortex "twists", each a rotation about its
  centre ``c`` by ``ψ = g_k Γ S((t − t_i)/L_i) P(ρ/ρ_i)`` where ``ρ = |p − c|``
  is the chord distance from the centre (kept by the rotation, so the inverse
  is the rotation by ``−ψ``), ``P(s) = (1 − s²)³`` for ``s < 1`` (compact, C²)
  and ``S`` the C² smootherstep: the storm spins up over ``L_i`` = 1–3 days
  from its birth ``t_i`` and leaves its twist in place.  A group is either a
  mid-latitude wave train (4, 6 or 8 alternating cyclones and weaker
  anticyclones evenly spaced around one latitude, disjoint caps of up to 20°,
  so they commute) or one tropical cyclone; ``g_k`` weakens them above 6 km.
* Conjugating by ``Z_{s_i}`` (``s_i`` = middle of the spin-up) places the
  storms in the jets' frame: they drift with the jet at their latitude, and
  the jets shear them only by what builds up over their own life, so the
  winds stay bounded (≤ ~50 m/s) over the 10 days.  (For speed, the cosine
  and sine of each frame's angle are tabulated per level on 2049 nodes in
  ``z`` and interpolated with renormalisation: still an exact rotation, the
  same one in the map and its inverse.)

Rotations and differential rotations preserve area, so the horizontal wind on
every level is non-divergent.  The fields follow from the map:

* ``cloud(x, t) = C0_k(X_k⁻¹(x, t))`` with ``C0_k`` a smooth initial
  pattern (storm-track bands, a deep ITCZ just south of the equator, low
  cloud, 3-D "plane-wave" noise for structure; values clipped to 0..1 and
  shaped in height by the level's nominal height);
* horizontal wind = ``∂X_k/∂t`` at ``a = X_k⁻¹(x, t)``, by the forward
  difference ``(X_k(a, t + δ) − x) / δ`` with ``δ`` = 1 s (truncation error
  below 1e-3 m/s), projected on east/north and scaled by the Earth radius
  (m/s; the shallow-atmosphere convention: angular speed × ``EARTH_RADIUS``
  at every height);
* level heights ``h_k(x) = η_k H + b_k T(x)`` over the relief ``T`` (the
  shipped 1° ETOPO60, sea floor clipped to 0), ``η_k`` from 0 to 1
  (finer near the ground), ``H`` = 20 km, ``b_k = (1 − η_k)³``: terrain
  following at the bottom, flat at the top, strictly increasing wherever
  ``T < H/3``; ``T`` is the relief averaged over each grid cell, and between
  grid nodes it is the bilinear interpolant of those values (so the level
  surfaces are exactly those of the grid);
* ``w`` = the vertical speed of the parcel that stays on its level surface,
  ``Dh_k/Dt = b_k (T(X(a, t + δ)) − T(x)) / δ``;
* ``temperature`` = a January surface temperature by latitude, a 6.5 K/km
  lapse rate up to a latitude-dependent tropopause (isothermal above), plus a
  ±3 K anomaly that is advected like the clouds.

So a parcel moved by ``(u, v, w)`` keeps its level index and its cloudiness:
the clouds are carried exactly by the winds (up to the time-interpolation of
hourly steps and the spatial interpolation of the grid, as with any data).
Cost: one inverse map per step for cloud and temperature, one forward map
more for the three wind components (see ``benchmarks/bench_data.py``).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (the 320×160×19 hourly 10-day climate run of Fig. 1 and its film).
.. [2] D. L. Williamson et al., "A standard test set for numerical
   approximations to the shallow water equations in spherical geometry",
   J. Comput. Phys. 102 (1992) — closed-form flows on the sphere.
"""

import functools

import numpy as np

from ..errors import DataError
from .dataset import Dataset, Variable
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


CLOUD_GAIN, CLOUD_BIAS = 1.3, 0.3
"""Contrast and offset of the initial cloud pattern: tuned so that about a fifth of the
volume (half of the low levels) is above 15 % in many separate bodies, as in Fig. 1."""


def _locked(method):
    """Run under the dataset's lock: the caches it fills may be shared with a read-ahead thread."""

    @functools.wraps(method)
    def run(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return run


def _smootherstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def _gauss(x, centre, width):
    return np.exp(-(((x - centre) / width) ** 2))


_ZNODES = np.linspace(-1.0, 1.0, 8193)
"""Nodes in z = sin(latitude) of the zonal rotation tables (linear interpolation between them
defines Θ exactly for the forward and the inverse map alike)."""

_FNODES = np.linspace(-1.0, 1.0, 2049)
"""Nodes in z of the storms' frame-rotation tables (cos and sin per jet factor)."""


# Zonal jets: (centre latitude, width, peak m/s at the jet level, relative oscillation,
# period in days, phase).  January: the northern jet is the stronger.
_JETS = (
    (38.0, 18.0, 32.0, 0.35, 4.0, 0.0),
    (-47.0, 17.0, 26.0, 0.35, 5.0, 1.7),
    (-2.0, 18.0, -7.0, 0.40, 3.0, 0.6),
    (72.0, 8.0, -6.0, 0.50, 6.0, 2.4),
    (-70.0, 8.0, -5.0, 0.50, 6.0, 4.0),
)


class SyntheticClimate(Dataset):
    """The synthetic demo climate (see the module docstring for the model).

    Air rides its terrain-following level (``w`` is the lift of doing so), so
    ``levels_follow_air`` is True.

    Parameters
    ----------
    ni, nj, nk : int
        Longitudes (evenly spaced from 0 °E), latitudes (cell centres, the
        poles themselves are not rows) and levels.
    days : float
        Length of the hourly time axis: ``round(24 * days)`` steps (240 for
        10 days, as in the paper).
    seed : int
        Seed of the storms and cloud patterns; equal seeds give identical data.
    start : str
        First time (ISO date).
    n_storms : int, optional
        Number of storm groups (wave trains or single tropical cyclones);
        about 2.5 a day by default.
    relief : (lon, lat, elevation), optional
        Relief grid for the terrain (the shipped 1° ETOPO60 by default);
        averaged over each grid cell, sea floor counted as 0.
    cache_steps : int
        (field, step) arrays kept in memory.
    """

    levels_follow_air = True

    def __init__(self, ni=320, nj=160, nk=19, days=10, seed=0, start="1987-01-01", n_storms=None, relief=None,
                 cache_steps=8, source="demo"):
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
            raise DataError(f"terrain {terrain.max():.0f} m is too high for a {TOP:.0f} m model top", path=source,
                            field="terrain")
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
        self._jet_factor = 0.25 + 0.75 * _gauss(z, 11_000.0, 3_500.0)
        self._storm_factor = np.where(z < 6_000.0, 1.0, 0.3 + 0.7 * _gauss(z, 6_000.0, 5_000.0))
        rng = np.random.default_rng(self.seed)
        self._storms = self._make_storms(rng, days, n_storms)
        phi = np.rad2deg(np.arcsin(_ZNODES))
        self._jet_shapes = [peak / np.cos(np.deg2rad(lat0)) * _gauss(phi, lat0, width) / EARTH_RADIUS
                            for lat0, width, peak, *_ in _JETS]
        # Storm frames Z_s: per group, per distinct jet factor, cos and sin of the rotation angle
        # j Θ(z, s) on _FNODES; between nodes they are interpolated and normalised, which defines
        # the frame rotation exactly (and without trigonometry) for the map and its inverse alike.
        self._jet_values = np.unique(self._jet_factor)
        self._frames = []
        for g in self._storms:
            angle = self._jet_values[:, None] * np.interp(_FNODES, _ZNODES, self._theta_table(g["frame"]))[None, :]
            self._frames.append((np.cos(angle).ravel(), np.sin(angle).ravel()))
        self._noise = [self._make_waves(rng, 10, 3.0, 7.0, 4.0), self._make_waves(rng, 16, 12.0, 22.0, 25.0),
                       self._make_waves(rng, 10, 4.0, 12.0, 3.0)]
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
        """Storm groups: mid-latitude wave trains of alternating cyclones and anticyclones
        (an even number of vortices evenly spaced around one latitude, with disjoint caps)
        and single tropical cyclones.  ``n`` = number of groups (about 2.5 a day by default)."""
        n = max(1, int(round(2.5 * days))) if n is None else int(n)
        groups = []
        for _ in range(n):
            tropical = rng.random() < 0.3
            hemi = -1.0 if rng.random() < (0.7 if tropical else 0.5) else 1.0  # tropical cyclones: mostly SH in January
            if tropical:
                lat, count = hemi * rng.uniform(8.0, 20.0), 1
                radius = rng.uniform(5.0, 9.0)
                strengths = np.array([hemi * rng.uniform(3.0, 5.0)])  # counter-clockwise in the north
            else:
                lat, count = hemi * rng.uniform(35.0, 62.0), int(rng.choice([4, 6, 8]))
                dlon = 2 * np.pi / count
                phi = np.deg2rad(lat)
                sep = np.arccos(np.sin(phi) ** 2 + np.cos(phi) ** 2 * np.cos(dlon))  # angle between neighbours
                radius = min(np.rad2deg(0.48 * sep), 20.0, rng.uniform(12.0, 22.0))
                # Keep each cap within its own longitude sector so a point's sector names its vortex.
                while np.arcsin(min(1.0, np.sin(np.deg2rad(radius)) / np.cos(phi))) >= 0.49 * dlon:
                    radius *= 0.95
                signs = np.where(np.arange(count) % 2 == 0, 1.0, -0.7)  # cyclone, weaker anticyclone, ...
                strengths = hemi * signs * rng.uniform(1.2, 2.4, size=count)
            lon0 = rng.uniform(0.0, 2 * np.pi)
            lons = lon0 + np.arange(count) * (2 * np.pi / count)
            phi, alpha = np.deg2rad(lat), np.deg2rad(radius)
            centres = np.stack([np.cos(phi) * np.cos(lons), np.cos(phi) * np.sin(lons), np.full(count, np.sin(phi))],
                               axis=1)
            birth = rng.uniform(0.0, max(days - 0.5, 0.0)) * DAY
            life = rng.uniform(1.0, 2.5) * DAY if tropical else rng.uniform(1.5, 3.0) * DAY
            zlim = (np.sin(phi - alpha), np.sin(min(phi + alpha, 0.5 * np.pi)))
            groups.append(dict(centres=centres, lon0=lon0, lons=lons, count=count, cos_lat=np.cos(phi),
                               sin_lat=np.sin(phi), rho=2.0 * np.sin(alpha / 2.0), strengths=strengths,
                               birth=birth, life=life, frame=birth + 0.5 * life, zlim=zlim))
        groups.sort(key=lambda g: g["frame"])
        return groups

    @staticmethod
    def _make_waves(rng, n, kmin, kmax, vmax):
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        k = d * rng.uniform(kmin, kmax, size=(n, 1))
        return k, rng.uniform(0.0, 2 * np.pi, size=n), rng.uniform(0.5, 1.0, size=n), rng.uniform(-vmax, vmax, size=n)

    # --------------------------------------------------------------- flow map parts
    def _theta_table(self, t):
        """Zonal rotation angle per unit jet factor after ``t`` seconds, tabulated on ``_ZNODES``."""
        total = np.zeros_like(_ZNODES)
        for (_lat0, _width, _peak, osc, period, phase), shape in zip(_JETS, self._jet_shapes):
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

    def _frame_rotation(self, frame, rows, z):
        """cos and sin of the storm frame's rotation at ``z`` for jet-factor rows ``rows``."""
        cos_t, sin_t = frame
        m = _FNODES.size
        x = (np.clip(z, -1.0, 1.0) + 1.0) * (0.5 * (m - 1))
        i = np.minimum(x.astype(np.intp), m - 2)
        f = x - i
        g = 1.0 - f
        i += rows * m
        j = i + 1
        c = cos_t[i] * g + cos_t[j] * f
        s = sin_t[i] * g + sin_t[j] * f
        n = np.hypot(c, s)
        return c / n, s / n

    def _jet_rows(self, jet):
        rows = np.minimum(np.searchsorted(self._jet_values, jet), self._jet_values.size - 1)
        if not np.array_equal(self._jet_values[rows], jet):
            raise ValueError("jet factors must come from level_factors()")
        return rows

    def _twists(self, p, t, jet, storm, inverse):
        """Apply the storms' twists ``Z_s⁻¹ V_i Z_s`` (or their inverses, in reverse order) to ``p`` in place.

        The vortices of one group have disjoint caps, so they commute and are applied together."""
        x, y, z = p
        all_rows = None
        pairs = list(zip(self._storms, self._frames))
        for g, frame in reversed(pairs) if inverse else pairs:
            grow = _smootherstep((t - g["birth"]) / g["life"])
            if grow == 0.0:
                continue
            # Z_s keeps latitude: candidates by the caps' latitude range, then the exact chord test.
            zlo, zhi = g["zlim"]
            cand = np.nonzero((z > zlo) & (z < zhi))[0]
            if cand.size == 0:
                continue
            if all_rows is None:  # the grid's own level factors: rows looked up once (see _flat_grid)
                all_rows = self._flat[2] if self._flat is not None and jet is self._flat[1][0] else self._jet_rows(jet)
            rows = all_rows[cand]
            pz = z[cand]
            c, s = self._frame_rotation(frame, rows, pz)
            x0, y0 = x[cand], y[cand]
            px, py = c * x0 - s * y0, s * x0 + c * y0  # into the storm's frame
            count = g["count"]
            if count > 1:  # the vortex of the point's longitude sector
                sector = np.floor((np.arctan2(py, px) - g["lon0"]) * (count / (2 * np.pi))
                                  + 0.5).astype(np.intp) % count
            else:
                sector = np.zeros(cand.size, dtype=np.intp)
            cen = g["centres"]
            cx, cy, cz = cen[sector, 0], cen[sector, 1], cen[sector, 2]
            cdot = cx * px + cy * py + cz * pz
            s2 = 2.0 * (1.0 - cdot) / (g["rho"] ** 2)
            inside = np.nonzero(s2 < 1.0)[0]
            cand, rows, px, py, pz, cx, cy, cz, cdot, s2, sector = (
                v[inside] for v in (cand, rows, px, py, pz, cx, cy, cz, cdot, s2, sector)
            )
            psi = g["strengths"][sector] * grow * storm[cand] * (1.0 - s2) ** 3
            if inverse:
                psi = -psi
            cs, sn = np.cos(psi), np.sin(psi)
            k = cdot * (1.0 - cs)
            qx = px * cs + (cy * pz - cz * py) * sn + cx * k
            qy = py * cs + (cz * px - cx * pz) * sn + cy * k
            qz = pz * cs + (cx * py - cy * px) * sn + cz * k
            c, s = self._frame_rotation(frame, rows, qz)
            x[cand], y[cand], z[cand] = c * qx + s * qy, c * qy - s * qx, qz  # back from the storm's frame
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
        px, py = self._rotate_z(np.asarray(x[0], dtype=np.float64), np.asarray(x[1], dtype=np.float64),
                                -jet * self._lookup(self._theta_table(t), z))
        return tuple(self._twists([px, py, z], t, jet, storm, inverse=True))

    def level_factors(self, k):
        """Jet and storm strength factors for level indices ``k`` (array)."""
        k = np.asarray(k)
        return self._jet_factor[k], self._storm_factor[k]

    # -------------------------------------------------------------- initial fields
    def _waves(self, which, a, level_height=None):
        """Unit-variance sum of plane waves in 3-D evaluated on unit vectors ``a``; their
        phases also turn with the level's nominal height, so structures change upward."""
        kvec, phase, amp, vertical = self._noise[which]
        x, y, z = (np.asarray(v, dtype=np.float32) for v in a)
        eta = np.float32(0.0) if level_height is None else np.asarray(level_height, dtype=np.float32) / np.float32(TOP)
        out = np.zeros(np.broadcast(x, eta).shape, dtype=np.float32)
        for (kx, ky, kz), ph, am, m in zip(kvec.astype(np.float32), phase.astype(np.float32), amp.astype(np.float32),
                                           vertical.astype(np.float32)):
            out += am * np.sin(kx * x + ky * y + kz * z + (ph + m * eta))
        return out * np.float32(1.0 / np.sqrt(0.5 * np.sum(amp**2)))

    def initial_cloud(self, a, k):
        """``C0_k(a)``: cloud fraction at ``t = 0`` at unit vectors ``a`` on levels ``k``."""
        z = self.nominal_height[np.asarray(k)].astype(np.float32)
        lat = np.rad2deg(np.arcsin(np.clip(np.asarray(a[2], dtype=np.float32), -1.0, 1.0)))
        systems, cells = self._waves(0, a, z), self._waves(1, a, z)
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
        c = CLOUD_GAIN * wet * (CLOUD_BIAS + 0.6 * systems + 0.55 * cells) * top - 0.05
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
    @_locked
    def _flat_grid(self):
        """Grid points as flat unit-vector components, their level factors and jet rows (computed once)."""
        if self._flat is None:
            nk, nj, ni = self.grid.shape
            x = tuple(np.broadcast_to(u, (nk, nj, ni)).ravel() for u in self._unit)
            factors = self.level_factors(np.repeat(np.arange(nk), nj * ni))
            self._flat = x, factors, self._jet_rows(factors[0])
        return self._flat

    @_locked
    def departure(self, t):
        """Labels (unit vectors at ``t = 0``) of the grid points at step ``t``: three ``(nk, nj, ni)`` arrays."""
        t = int(t) % self.times.size
        if t not in self._departures:
            _, (jet, storm), _ = self._flat_grid()
            secs = self.hours[t] * 3600.0
            # inverse() on the grid: the zonal rotation angle depends only on (level, row), so take it once per pair.
            ang = -self._jet_factor[:, None] * self._lookup(self._theta_table(secs), self._unit[2][:, 0])[None, :]
            px, py = self._rotate_z(self._unit[0], self._unit[1], ang[:, :, None])
            z = np.broadcast_to(self._unit[2], self.grid.shape).ravel()
            a = self._twists([px.ravel(), py.ravel(), z], secs, jet, storm, inverse=True)
            if len(self._departures) >= 2:
                self._departures.pop(next(iter(self._departures)))
            self._departures[t] = tuple(v.reshape(self.grid.shape) for v in a)
        return self._departures[t]

    @_locked
    def _wind(self, t):
        if t in self._winds:
            return self._winds[t]
        shape = self.grid.shape
        a = tuple(v.ravel() for v in self.departure(t))
        p0, (jet, storm), _ = self._flat_grid()
        p1 = self.forward(a, self.hours[t] * 3600.0 + DELTA, jet, storm)
        scale = EARTH_RADIUS / DELTA
        d = [((q1 - q0) * scale).reshape(shape) for q1, q0 in zip(p1, p0)]
        u = d[0] * self._east[0] + d[1] * self._east[1]
        v = d[0] * self._north[0] + d[1] * self._north[1] + d[2] * self._north[2]
        dterrain = sample_relief(*_lonlat(p1), self._terrain).reshape(shape) - self.grid.terrain
        w = self.b[:, None, None] * dterrain / DELTA
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
