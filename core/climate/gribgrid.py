"""Where a GRIB message's values lie on the globe, and how they become a 2-D ``(rows, columns)`` array.

ecCodes computes the positions (its geo-iterator): Nephele reads them and only
arranges the values.  Kinds of grid:

================================= ===================================================================
ecCodes ``gridType``              read as
================================= ===================================================================
``regular_ll``, ``regular_gg``    1-D longitudes and latitudes
``reduced_gg`` (global)           expanded to the regular Gaussian grid of the same latitudes with
                                  ``max(pl)`` columns, by linear interpolation along each latitude
                                  circle (periodic); the original points are kept exactly where the
                                  columns coincide
``rotated_ll``, ``rotated_gg``    the grid's own (rotated) 1-D axes and the rotation to the true globe
                                  (:func:`~nephele.core.climate.grid.rotated_pole_matrix` from the
                                  southern pole and angle of rotation)
``ncep_32769`` (RAP, HRRR native) NCEP's rotated latitude/longitude: first and last points in true
                                  coordinates and the centre of the rotation; the rotated axes run
                                  evenly from the first point to the last
``lambert``, ``polar_stereographic``, ``mercator``, ``lambert_azimuthal_equal_area``, ...
                                  curvilinear: the 2-D true longitudes/latitudes ecCodes computes
================================= ===================================================================

Spectral fields (``sh``), sub-area reduced grids and other unstructured
layouts are refused in one line.

References
----------
.. [1] WMO Manual on Codes, FM 92 GRIB edition 2, grid definition templates 3.0, 3.1, 3.40, 3.30, 3.20.
.. [2] NCEP, GRIB2 grid definition template 3.32769 (rotated latitude/longitude, non-E staggered).
.. [3] ECMWF, "Gaussian grids", https://confluence.ecmwf.int/display/FCST/Gaussian+grids
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import DataError
from .grid import lonlat_to_xyz, rotated_pole_matrix, xyz_to_lonlat

_REGULAR = ("regular_ll", "regular_gg")
_ROTATED = ("rotated_ll", "rotated_gg")
_KEYS = ("gridType", "Ni", "Nj", "N", "pl", "jPointsAreConsecutive", "alternativeRowScanning", "iScansNegatively",
         "jScansPositively", "latitudeOfFirstGridPointInDegrees", "longitudeOfFirstGridPointInDegrees",
         "latitudeOfLastGridPointInDegrees", "longitudeOfLastGridPointInDegrees", "latitudeOfSouthernPoleInDegrees",
         "longitudeOfSouthernPoleInDegrees", "angleOfRotationInDegrees", "latitudeOfGridPoints",
         "longitudeOfGridPoints",
         "angleDivisor", "radius", "earthIsOblate", "earthMajorAxis", "earthMinorAxis", "numberOfDataPoints",
         "gridDefinitionDescription", "isOctahedral")


@dataclass
class GribGrid:
    """A GRIB grid as Nephele reads it: see the module docstring.

    ``lon``/``lat`` are 1-D axes in the order of the 2-D array's columns and rows
    (rotated coordinates for a rotated grid), or ``None`` for a curvilinear grid
    (``lon2d``/``lat2d``).  :meth:`to_2d` turns a message's values into that array.
    """

    kind: str
    shape: tuple
    lon: np.ndarray = None
    lat: np.ndarray = None
    lon2d: np.ndarray = None
    lat2d: np.ndarray = None
    rotation: np.ndarray = None
    transpose: bool = False
    pl: np.ndarray = None
    radius: float = None
    notes: list = field(default_factory=list)
    _expand: tuple = None

    def to_2d(self, values, dtype=np.float32):
        """``(rows, columns)`` array of one message's values (float32: fields; float64: the surface pressure
        and heights the levels are placed with)."""
        v = np.asarray(values, dtype=dtype)
        if self.kind == "reduced_gg":
            i0, i1, w = self._expansion()
            return (v[i0] * (1.0 - w) + v[i1] * w).astype(dtype)
        nj, ni = self.shape
        return v.reshape(ni, nj).T if self.transpose else v.reshape(nj, ni)

    def _expansion(self):
        """Indices of the two neighbours along the latitude circle and the weight of the second, per output point."""
        if self._expand is None:
            pl = self.pl.astype(np.int64)
            nj, ni = self.shape
            start = np.concatenate([[0], np.cumsum(pl)[:-1]])
            x = np.arange(ni) / ni  # output longitudes as fractions of the circle
            pos = x[None, :] * pl[:, None]  # position along each row in its own points
            j0 = np.floor(pos + 1e-9).astype(np.int64)
            w = np.clip(pos - j0, 0.0, 1.0)
            j0 %= pl[:, None]
            j1 = (j0 + 1) % pl[:, None]
            self._expand = (start[:, None] + j0, start[:, None] + j1, w.astype(np.float32))
        return self._expand

    def arrays(self):
        """The grid as plain arrays and JSON-able metadata (to keep with the GRIB index)."""
        meta = {"kind": self.kind, "shape": list(self.shape), "transpose": self.transpose, "radius": self.radius,
                "notes": self.notes}
        arrays = {k: getattr(self, k) for k in ("lon", "lat", "lon2d", "lat2d", "rotation", "pl")
                  if getattr(self, k) is not None}
        return meta, arrays

    @classmethod
    def from_arrays(cls, meta, arrays):
        return cls(meta["kind"], tuple(meta["shape"]), transpose=meta["transpose"], radius=meta["radius"],
                   notes=list(meta["notes"]),
                   **{k: arrays[k] for k in ("lon", "lat", "lon2d", "lat2d", "rotation", "pl") if k in arrays})


def grid_of(index, i, path, field):
    """The :class:`GribGrid` of message ``i`` of a :class:`~nephele.core.climate.gribscan.GribIndex`.

    Raises
    ------
    DataError
        A grid Nephele does not place (spectral, sub-area reduced, unknown), naming the field.
    """
    k = index.get(i, _KEYS)
    kind = str(k["gridType"])
    radius = _radius(k)
    if kind in _REGULAR:
        g = _regular(index, i, k, path, field)
    elif kind == "reduced_gg":
        g = _reduced_gaussian(index, i, k, path, field)
    elif kind in _ROTATED:
        g = _rotated(index, i, k, path, field)
    elif kind == "ncep_32769":
        g = _ncep_rotated(k, radius)
    elif kind == "sh":
        raise DataError("is a spectral field (spherical harmonics); transform it to a grid first (e.g. 'cdo sp2gp')",
                        path=path, field=field)
    elif int(k["Ni"] or 0) > 0 and int(k["Nj"] or 0) > 0 and not str(kind).startswith("reduced"):
        g = _projected(index, i, k, path, field)
    else:
        raise DataError(f"grid type {kind!r} ({k['gridDefinitionDescription']}) is not read: regular, reduced "
                        "Gaussian, rotated and projected grids are", path=path, field=field)
    g.radius = radius
    return g


def _radius(k):
    """Planet radius (m): the sphere's, or the mean radius (2a + b) / 3 of an oblate figure."""
    if k.get("earthIsOblate") and k.get("earthMajorAxis"):
        return (2.0 * float(k["earthMajorAxis"]) + float(k["earthMinorAxis"] or k["earthMajorAxis"])) / 3.0
    return float(k["radius"]) if k.get("radius") else None


def _scan_shape(k, path, field):
    if k.get("alternativeRowScanning"):
        raise DataError("uses alternative (boustrophedon) row scanning, which is not read", path=path, field=field)
    return (int(k["Nj"]), int(k["Ni"])), bool(k.get("jPointsAreConsecutive"))


def _positions(index, i, path, field, unrotated=True):
    """ecCodes' latitude and longitude of every point of message ``i`` (as stored)."""
    eccodes = __import__("eccodes")
    from .gribscan import _LOCK

    with _LOCK:
        h = index.handle(i)
        try:
            if not unrotated:
                eccodes.codes_set(h, "iteratorDisableUnrotate", 1)
            lat = eccodes.codes_get_array(h, "latitudes")
            lon = eccodes.codes_get_array(h, "longitudes")
        except eccodes.CodesInternalError as exc:
            raise DataError(f"ecCodes cannot place the grid's points ({exc})", path=path, field=field) from None
        finally:
            eccodes.codes_release(h)
    return lon, lat


def _as_2d(a, shape, transpose):
    nj, ni = shape
    return a.reshape(ni, nj).T if transpose else a.reshape(nj, ni)


def _axes(index, i, k, path, field, unrotated=True):
    shape, transpose = _scan_shape(k, path, field)
    lon, lat = (_as_2d(a, shape, transpose) for a in _positions(index, i, path, field, unrotated))
    return shape, transpose, lon[0].copy(), lat[:, 0].copy()


def _regular(index, i, k, path, field):
    shape, transpose, lon, lat = _axes(index, i, k, path, field)
    return GribGrid("regular", shape, lon=lon, lat=lat, transpose=transpose)


def _rotated(index, i, k, path, field):
    """ECMWF's rotated grids: the axes in rotated coordinates; the grid's north pole is the antipode of
    the southern pole the message states.  A non-zero angle of rotation is refused: its sense differs
    between tools (ecCodes shifts true longitudes by it), and products use 0."""
    angle = float(k["angleOfRotationInDegrees"] or 0.0)
    if angle != 0.0:
        raise DataError(f"rotated grid with an angle of rotation of {angle:g} degrees is not read (only 0 is)",
                        path=path, field=field)
    shape, transpose, lon, lat = _axes(index, i, k, path, field, unrotated=False)
    sp_lat, sp_lon = float(k["latitudeOfSouthernPoleInDegrees"]), float(k["longitudeOfSouthernPoleInDegrees"])
    rotation = rotated_pole_matrix(sp_lon + 180.0, -sp_lat, 0.0)
    note = f"grid: rotated pole, southern pole at {sp_lat:g} N {sp_lon:g} E"
    return GribGrid("rotated", shape, lon=lon, lat=lat, rotation=rotation, transpose=transpose, notes=[note])


def _ncep_rotated(k, radius):
    """NCEP's template 3.32769: true first point (La1, Lo1), centre of the rotation (ecCodes' La2/Lo2) and true
    last point (octets 73-80); the rotated coordinates run evenly from the first point to the last."""
    shape, transpose = _scan_shape(k, None, None)
    nj, ni = shape
    c_lat, c_lon = float(k["latitudeOfLastGridPointInDegrees"]), float(k["longitudeOfLastGridPointInDegrees"])
    rotation = rotated_pole_matrix(c_lon + 180.0, 90.0 - c_lat, 0.0)  # the centre becomes rotated (0, 0)
    div = float(k.get("angleDivisor") or 1e6)
    first = (float(k["longitudeOfFirstGridPointInDegrees"]), float(k["latitudeOfFirstGridPointInDegrees"]))
    last = (float(k["longitudeOfGridPoints"]) / div, float(k["latitudeOfGridPoints"]) / div)
    (x0, x1), (y0, y1), _ = xyz_to_lonlat(lonlat_to_xyz(*np.array([first, last]).T) @ rotation)
    lon, lat = np.linspace(x0, x1, ni), np.linspace(y0, y1, nj)
    note = (f"grid: NCEP rotated latitude/longitude (template 3.32769) centred on {c_lat:g} N {c_lon:g} E, "
            f"{abs(x1 - x0) / (ni - 1):.6f} x {abs(y1 - y0) / (nj - 1):.6f} degrees from its first and last points")
    return GribGrid("rotated", shape, lon=lon, lat=lat, rotation=rotation, transpose=transpose, notes=[note])


def _projected(index, i, k, path, field):
    shape, transpose = _scan_shape(k, path, field)
    lon, lat = (_as_2d(a, shape, transpose) for a in _positions(index, i, path, field))
    lon = np.mod(lon + 180.0, 360.0) - 180.0
    notes = [f"grid: {k['gridType']} ({k['gridDefinitionDescription']}), positions from ecCodes"]
    if k.get("iScansNegatively") or not k.get("jScansPositively"):
        # WMO GRIB2 issue 55: decoders differ on whether the scanning flags turn projected grids; ecCodes steps +x, +y.
        notes.append("grid: the message scans -x or -y; placed as ecCodes places it (+x, +y from the first point; "
                     "wgrib2 would mirror it)")
    return GribGrid("projected", shape, lon2d=lon, lat2d=lat, transpose=transpose, notes=notes)


def _reduced_gaussian(index, i, k, path, field):
    pl = np.asarray(index.get(i, ["pl"])["pl"], dtype=np.int64).ravel()
    nj = int(k["Nj"])
    lon_first = float(k["longitudeOfFirstGridPointInDegrees"])
    if pl.size != nj or int(pl.sum()) != int(k["numberOfDataPoints"]) or lon_first != 0.0 or int(k["N"]) * 2 != nj:
        raise DataError(f"is a sub-area of a reduced Gaussian grid ({nj} rows, first longitude {lon_first:g}); only "
                        "global reduced Gaussian grids are expanded", path=path, field=field)
    _, lat = _positions(index, i, path, field)
    starts = np.concatenate([[0], np.cumsum(pl)[:-1]])
    ni = int(pl.max())
    octa = "octahedral " if k.get("isOctahedral") else ""
    note = (f"grid: {octa}reduced Gaussian N{int(k['N'])} ({int(pl.sum())} points, {int(pl.min())}..{ni} per "
            f"latitude) expanded to a regular {ni} x {nj} Gaussian grid by linear interpolation along each latitude "
            "circle")
    return GribGrid("reduced_gg", (nj, ni), lon=np.arange(ni) * (360.0 / ni), lat=lat[starts], pl=pl, notes=[note])


__all__ = ["GribGrid", "grid_of"]
