"""Curvilinear longitude × latitude × terrain-following level grids on the globe.

Conventions used everywhere in Nephele:

* arrays of a field are ordered ``(nk, nj, ni)`` = (level, latitude, longitude),
  level 0 at the bottom, latitude ascending (south to north), longitude ascending;
* longitudes and latitudes are in degrees, heights in metres above sea level;
* Cartesian positions are in scene units: the sea-level sphere has radius
  ``radius`` (1 by default) and a height ``h`` sits at
  ``radius * (1 + exaggeration * h / EARTH_RADIUS)``, x toward (0°E, 0°N),
  z toward the north pole.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError

EARTH_RADIUS = 6_371_000.0
"""Mean Earth radius in metres."""

DEFAULT_EXAGGERATION = 30.0
"""Vertical exaggeration of heights on the globe; the atmosphere is otherwise
a shell 0.3 % of the radius thick."""


def globe_radius(height, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
    """Scene-unit distance from the globe's centre of a point ``height`` metres up."""
    return radius * (1.0 + exaggeration * np.asarray(height, dtype=np.float64) / EARTH_RADIUS)


def height_from_radius(r, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
    """Inverse of :func:`globe_radius`: metres above sea level."""
    return (np.asarray(r, dtype=np.float64) / radius - 1.0) * EARTH_RADIUS / exaggeration


def lonlat_to_xyz(lon, lat, r=1.0):
    """Cartesian points from longitude, latitude (degrees) and distance ``r``.

    Inputs broadcast; the result has a trailing axis of length 3.
    """
    lam = np.deg2rad(np.asarray(lon, dtype=np.float64))
    phi = np.deg2rad(np.asarray(lat, dtype=np.float64))
    r = np.asarray(r, dtype=np.float64)
    cphi = np.cos(phi)
    return np.stack(np.broadcast_arrays(r * cphi * np.cos(lam), r * cphi * np.sin(lam), r * np.sin(phi)), axis=-1)


def xyz_to_lonlat(xyz):
    """Longitude in [-180, 180), latitude (degrees) and distance of Cartesian points."""
    xyz = np.asarray(xyz, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    r = np.sqrt(x * x + y * y + z * z)
    lon = np.rad2deg(np.arctan2(y, x))
    lat = np.rad2deg(np.arctan2(z, np.hypot(x, y)))
    lon = np.where(lon >= 180.0, lon - 360.0, lon)
    return lon, lat, r


def rotated_pole_matrix(pole_lon, pole_lat, pole_grid_lon=0.0):
    """Rotation taking Cartesian points of a rotated-pole grid to the true globe.

    CF ``rotated_latitude_longitude``: the grid's north pole lies at true
    (``pole_lon``, ``pole_lat``) = (``grid_north_pole_longitude``,
    ``grid_north_pole_latitude``) and the true north pole at grid longitude
    ``pole_grid_lon`` (``north_pole_grid_longitude``).  Grid (0°, 0°) is true
    (``pole_lon`` + 180°, 90° − ``pole_lat``).  The same transformation as
    PROJ's ``ob_tran`` with ``o_lon_p = pole_grid_lon``, ``lon_0 = pole_lon + 180``.

    References
    ----------
    .. [1] CF Conventions 1.11, Appendix F (rotated pole).
    """
    phi = np.deg2rad(float(pole_lat))
    lam = np.deg2rad(float(pole_lon) + 180.0)
    o = np.deg2rad(float(pole_grid_lon))
    # Grid longitude pole_grid_lon → 180°, so that the true pole's meridian lines up.
    rz_o = np.array([[np.cos(np.pi - o), -np.sin(np.pi - o), 0.0], [np.sin(np.pi - o), np.cos(np.pi - o), 0.0],
                     [0.0, 0.0, 1.0]])
    ry = np.array([[np.sin(phi), 0.0, -np.cos(phi)], [0.0, 1.0, 0.0], [np.cos(phi), 0.0, np.sin(phi)]])
    rz = np.array([[np.cos(lam), -np.sin(lam), 0.0], [np.sin(lam), np.cos(lam), 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rz_o @ np.diag([-1.0, -1.0, 1.0])


def right_handed(lon2d, lat2d):
    """Whether grid i, grid j and up form a right-handed frame (east-ish, north-ish, up) at the centre."""
    nj, ni = lon2d.shape
    j, i = nj // 2, ni // 2
    j0, i0 = min(j, nj - 2), min(i, ni - 2)
    p = lonlat_to_xyz(lon2d[j0 : j0 + 2, i0 : i0 + 2], lat2d[j0 : j0 + 2, i0 : i0 + 2])
    return float(np.dot(np.cross(p[0, 1] - p[0, 0], p[1, 0] - p[0, 0]), p[0, 0])) > 0.0


def _distinct(a):
    """``a`` with every broadcast axis (stride 0) cut to length 1: the same values, each once."""
    return a[tuple(slice(0, 1) if stride == 0 and n > 1 else slice(None)
                   for stride, n in zip(a.strides, a.shape, strict=True))]


@dataclass(frozen=True, eq=False)
class GlobeGrid:
    """A terrain-following longitude × latitude × level grid.

    Parameters
    ----------
    lon : (ni,) array
        Longitudes in degrees, strictly ascending, spanning less than 360°.
    lat : (nj,) array
        Latitudes in degrees, strictly ascending, within [-90, 90].
    height : (nk, nj, ni) array
        Height in metres above sea level of every grid vertex, strictly
        increasing with level.  The lowest level follows the terrain.
    terrain : (nj, ni) array, optional
        Surface height in metres (defaults to the lowest level).
    rotation : (3, 3) array, optional
        For a rotated-pole grid (``lon``/``lat`` are grid coordinates): the
        rotation taking grid Cartesian points to the true globe
        (:func:`rotated_pole_matrix`); :meth:`points` applies it.  Winds in
        such files are relative to the grid, so everything else works in grid
        coordinates unchanged; code turning scene points back into grid
        coordinates applies :meth:`to_grid` first.
    lon2d, lat2d : (nj, ni) arrays, optional
        For a curvilinear horizontal grid (2-D latitude/longitude: WRF,
        Lambert conformal, polar stereographic regional models): the true
        longitude and latitude of every column.  ``lon``/``lat`` are then the
        grid's own ascending axis coordinates (projection x/y or indices), not
        degrees; :meth:`points` places the columns at ``lon2d``/``lat2d``.
        Contours work on such grids (they need only :meth:`points`), and voxel
        volumes (:class:`~nephele.core.climate.columns.ColumnLocator` turns
        points into column indices); other code that must turn scene points
        back into grid indices calls :meth:`require_lonlat` first.
    """

    lon: np.ndarray
    lat: np.ndarray
    height: np.ndarray
    terrain: np.ndarray = None
    rotation: np.ndarray = None
    lon2d: np.ndarray = None
    lat2d: np.ndarray = None

    def __post_init__(self):
        lon = np.asarray(self.lon, dtype=np.float64)
        lat = np.asarray(self.lat, dtype=np.float64)
        height = np.asarray(self.height, dtype=np.float64)
        object.__setattr__(self, "lon", lon)
        object.__setattr__(self, "lat", lat)
        object.__setattr__(self, "height", height)
        terrain = height[0] if self.terrain is None else np.asarray(self.terrain, dtype=np.float64)
        object.__setattr__(self, "terrain", terrain)
        if self.rotation is not None:
            object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        if (self.lon2d is None) != (self.lat2d is None):
            raise DataError("a curvilinear grid needs both lon2d and lat2d",
                            field="lon2d" if self.lon2d is None else "lat2d")
        if self.lon2d is not None:
            if self.rotation is not None:
                raise DataError("a grid is either rotated-pole or curvilinear (2-D lon/lat), not both", field="lon2d")
            object.__setattr__(self, "lon2d", np.asarray(self.lon2d, dtype=np.float64))
            object.__setattr__(self, "lat2d", np.asarray(self.lat2d, dtype=np.float64))

    @property
    def curvilinear(self):
        """True for a grid with 2-D longitude/latitude (:attr:`lon2d`, :attr:`lat2d`)."""
        return self.lon2d is not None

    def require_lonlat(self, what, path=None):
        """Raise :class:`DataError` for a curvilinear grid: ``what`` needs 1-D longitude/latitude axes."""
        if self.curvilinear:
            raise DataError(
                f"{what} on a curvilinear grid (2-D longitude/latitude) is not supported yet; contours, volumes, "
                "advected textures and flow volumes are",
                path=path,
                field="grid",
            )
        return self

    @property
    def shape(self):
        """``(nk, nj, ni)``."""
        return self.height.shape

    @property
    def periodic_lon(self):
        """True when the longitudes close the circle (the last column's
        neighbour is the first one, 360° on)."""
        if self.lon.size < 3 or self.curvilinear:
            return False
        step = np.median(np.diff(self.lon))
        gap = self.lon[0] + 360.0 - self.lon[-1]
        return bool(abs(gap - step) <= 0.01 * step)

    def validate(self, path=None):
        """Raise :class:`DataError` naming ``path`` and the coordinate at fault."""
        lon, lat, height = self.lon, self.lat, self.height
        for name, c in (("lon", lon), ("lat", lat)):
            if c.ndim != 1 or c.size < 2:
                raise DataError(f"needs at least 2 values along one axis, got shape {c.shape}", path=path, field=name)
            if not np.all(np.isfinite(c)):
                raise DataError("has NaN or infinite coordinates", path=path, field=name)
            if not np.all(np.diff(c) > 0):
                raise DataError("is not strictly ascending", path=path, field=name)
        if self.curvilinear:
            for name, c in (("lon2d", self.lon2d), ("lat2d", self.lat2d)):
                if c.shape != (lat.size, lon.size):
                    raise DataError(f"shape {c.shape} does not match (lat={lat.size}, lon={lon.size})", path=path,
                                    field=name)
                if not np.all(np.isfinite(c)):
                    raise DataError("has NaN or infinite coordinates", path=path, field=name)
            if np.any(np.abs(self.lat2d) > 90.0):
                raise DataError("lies outside [-90, 90] degrees", path=path, field="lat2d")
        elif lon[-1] - lon[0] >= 360.0:
            raise DataError("spans 360 degrees or more (duplicate seam column?)", path=path, field="lon")
        elif lat[0] < -90.0 or lat[-1] > 90.0:
            raise DataError("lies outside [-90, 90] degrees", path=path, field="lat")
        if height.ndim != 3 or height.shape[1:] != (lat.size, lon.size) or height.shape[0] < 2:
            raise DataError(
                f"shape {height.shape} does not match (levels>=2, lat={lat.size}, lon={lon.size})",
                path=path,
                field="height",
            )
        height = _distinct(height)  # flat levels broadcast over the columns: check each value once
        if not np.all(np.isfinite(height)):
            raise DataError("has NaN or infinite level heights", path=path, field="height")
        if not np.all(np.diff(height, axis=0) > 0):
            raise DataError("levels are not strictly increasing upward (non-monotonic levels)", path=path,
                            field="height")
        return self

    def radii(self, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
        """Scene-unit distance from the centre of every vertex, ``(nk, nj, ni)``."""
        return globe_radius(self.height, radius, exaggeration)

    def points(self, radius=1.0, exaggeration=DEFAULT_EXAGGERATION, dtype=np.float32):
        """Cartesian vertex positions, ``(nk, nj, ni, 3)``, in scene units."""
        r = self.radii(radius, exaggeration)
        if self.curvilinear:
            lam, phi = np.deg2rad(self.lon2d)[None], np.deg2rad(self.lat2d)[None]
        else:
            lam = np.deg2rad(self.lon)[None, None, :]
            phi = np.deg2rad(self.lat)[None, :, None]
        out = np.empty(self.shape + (3,), dtype=dtype)
        cphi = np.cos(phi)
        out[..., 0] = r * cphi * np.cos(lam)
        out[..., 1] = r * cphi * np.sin(lam)
        out[..., 2] = r * np.sin(phi)
        if self.rotation is not None:
            out[...] = out @ self.rotation.T.astype(dtype)
        return out

    def to_grid(self, xyz):
        """Cartesian points on the true globe in the grid's own (possibly rotated) frame."""
        self.require_lonlat("turning points into grid coordinates")
        xyz = np.asarray(xyz, dtype=np.float64)
        return xyz if self.rotation is None else xyz @ self.rotation

    def true_lonlat(self):
        """True longitude and latitude (degrees) of every column, ``(nj, ni)`` each."""
        if self.curvilinear:
            return self.lon2d.copy(), self.lat2d.copy()
        xyz = lonlat_to_xyz(self.lon[None, :], self.lat[:, None])
        if self.rotation is not None:
            xyz = xyz @ self.rotation.T
        lon, lat, _ = xyz_to_lonlat(xyz)
        return lon, lat
