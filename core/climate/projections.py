"""Inverse map projections of CF grid mappings: projection x/y (metres) to longitude/latitude.

Regional models (WRF, HRRR, NAM, the Canadian and polar models) write their
grids on Lambert conformal, polar stereographic or Mercator projections; a CF
file that stores only the projection coordinates and the grid mapping needs
these to place its columns on the globe.  Closed forms on the sphere or the
ellipsoid (geodetic latitude; the globe then takes it as its latitude), so
reading needs no PROJ: the PROJ wheels and the netCDF4 wheels crash together
at interpreter exit in this environment (two bundled libcurl/OpenSSL copies).
The tests check every case against PROJ run in its own process.

References
----------
.. [1] J. P. Snyder, "Map Projections: A Working Manual", USGS Professional
   Paper 1395, 1987: chapters 7 (Mercator), 15 (Lambert conformal conic) and
   21 (stereographic), and eq. 7-9 for the latitude from ``t``.
.. [2] CF Conventions 1.11, Appendix F (grid mappings).
"""

import numpy as np

from ..errors import DataError

WGS84 = (6378137.0, 1.0 / 298.257223563)
"""Semi-major axis (m) and flattening assumed when a grid mapping states no figure (as PROJ's ``from_cf``)."""

SUPPORTED = ("lambert_conformal_conic", "polar_stereographic", "stereographic", "mercator")
"""CF ``grid_mapping_name`` values :func:`inverse` understands."""


def figure(mapping):
    """``(a, e, note)``: semi-major axis (m), eccentricity and a note when the figure was assumed."""
    if "earth_radius" in mapping:
        return float(np.asarray(mapping["earth_radius"]).ravel()[0]), 0.0, None
    if "semi_major_axis" in mapping:
        a = float(np.asarray(mapping["semi_major_axis"]).ravel()[0])
        if "semi_minor_axis" in mapping:
            b = float(np.asarray(mapping["semi_minor_axis"]).ravel()[0])
            f = 1.0 - b / a
        else:
            inv = float(np.asarray(mapping.get("inverse_flattening", 0.0)).ravel()[0])
            f = 1.0 / inv if inv else 0.0
        return a, float(np.sqrt(f * (2.0 - f))), None
    a, f = WGS84
    return a, float(np.sqrt(f * (2.0 - f))), "the grid mapping states no earth figure; WGS84 assumed"


def _t(phi, e):
    """Snyder eq. 15-9 / 7-10: ``tan(pi/4 - phi/2) / ((1 - e sin phi) / (1 + e sin phi))^(e/2)``."""
    s = e * np.sin(phi)
    return np.tan(np.pi / 4 - phi / 2) / ((1 - s) / (1 + s)) ** (e / 2)


def _m(phi, e):
    """Snyder eq. 14-15: ``cos phi / sqrt(1 - e^2 sin^2 phi)``."""
    return np.cos(phi) / np.sqrt(1 - (e * np.sin(phi)) ** 2)


def _phi_from_t(t, e):
    """Snyder eq. 7-9, iterated to convergence (exact in one step on the sphere)."""
    phi = np.pi / 2 - 2 * np.arctan(t)
    if e == 0.0:
        return phi
    for _ in range(30):
        s = e * np.sin(phi)
        new = np.pi / 2 - 2 * np.arctan(t * ((1 - s) / (1 + s)) ** (e / 2))
        if np.nanmax(np.abs(new - phi)) < 1e-14:
            return new
        phi = new
    return phi


def _get(mapping, key, default=None, index=0):
    if key not in mapping:
        if default is None:
            raise KeyError(key)
        return float(default)
    v = np.atleast_1d(np.asarray(mapping[key], dtype=np.float64))
    return float(v[min(index, v.size - 1)])


def inverse(mapping, x, y, path=None, field="grid_mapping"):
    """Longitude and latitude (degrees) of projection coordinates ``x``, ``y`` (metres, broadcast).

    Parameters
    ----------
    mapping : dict
        CF grid-mapping attributes (:data:`SUPPORTED` names).
    x, y : array_like
        Projection coordinates in metres (false easting/northing included).

    Returns
    -------
    lon, lat : arrays
        Degrees; longitudes in [-180, 180).
    notes : list of str
        Assumptions made (a default earth figure).

    Raises
    ------
    DataError
        Unknown or incomplete grid mapping, naming ``path`` and ``field``.
    """
    name = str(mapping.get("grid_mapping_name", "")).strip()
    if name not in SUPPORTED:
        raise DataError(f"grid mapping {name or 'none'!r} is not one of {', '.join(SUPPORTED)} (store 2-D "
                        "latitude/longitude instead)", path=path, field=field)
    a, e, note = figure(mapping)
    x = np.asarray(x, dtype=np.float64) - _get(mapping, "false_easting", 0.0)
    y = np.asarray(y, dtype=np.float64) - _get(mapping, "false_northing", 0.0)
    try:
        if name == "lambert_conformal_conic":
            lon, lat = _lcc(mapping, x, y, a, e)
        elif name == "mercator":
            lon, lat = _mercator(mapping, x, y, a, e)
        else:
            lon, lat = _stereographic(mapping, name, x, y, a, e, path, field)
    except KeyError as exc:
        raise DataError(f"{name} grid mapping lacks {exc.args[0]!r}", path=path, field=field) from None
    lon = np.mod(np.rad2deg(lon) + 180.0, 360.0) - 180.0
    return lon, np.rad2deg(lat), [note] if note else []


def _lcc(mapping, x, y, a, e):
    """Snyder eqs. 15-1..15-3, 15-5, 14-4, 15-10, 15-11, 7-9 (one or two standard parallels)."""
    p1 = np.deg2rad(_get(mapping, "standard_parallel", index=0))
    p2 = np.deg2rad(_get(mapping, "standard_parallel", index=1))
    p0 = np.deg2rad(_get(mapping, "latitude_of_projection_origin"))
    lam0 = np.deg2rad(_get(mapping, "longitude_of_central_meridian"))
    m1, m2, t1, t2, t0 = _m(p1, e), _m(p2, e), _t(p1, e), _t(p2, e), _t(p0, e)
    n = np.sin(p1) if abs(p1 - p2) < 1e-12 else (np.log(m1) - np.log(m2)) / (np.log(t1) - np.log(t2))
    F = m1 / (n * t1**n)
    rho0 = a * F * t0**n
    sign = np.sign(n)
    rho = sign * np.hypot(x, rho0 - y)
    theta = np.arctan2(sign * x, sign * (rho0 - y))
    with np.errstate(divide="ignore"):
        t = (rho / (a * F)) ** (1.0 / n)
    return theta / n + lam0, _phi_from_t(t, e)


def _mercator(mapping, x, y, a, e):
    """Snyder eqs. 7-12, 7-13, 7-9; the scale from ``standard_parallel`` or ``scale_factor_at_projection_origin``."""
    lam0 = np.deg2rad(_get(mapping, "longitude_of_projection_origin", 0.0))
    if "standard_parallel" in mapping:
        k0 = _m(np.deg2rad(_get(mapping, "standard_parallel")), e)
    else:
        k0 = _get(mapping, "scale_factor_at_projection_origin", 1.0)
    return x / (a * k0) + lam0, _phi_from_t(np.exp(-y / (a * k0)), e)


def _stereographic(mapping, name, x, y, a, e, path, field):
    """Polar (Snyder 21-33..21-39, any figure) or oblique (sphere, Snyder 20-18, 21-15, 21-16) stereographic."""
    lat0 = _get(mapping, "latitude_of_projection_origin")
    if name == "polar_stereographic":
        lam0 = np.deg2rad(_get(mapping, "straight_vertical_longitude_from_pole",
                               mapping.get("longitude_of_projection_origin", 0.0)))
    else:
        lam0 = np.deg2rad(_get(mapping, "longitude_of_projection_origin"))
    if abs(abs(lat0) - 90.0) < 1e-9:
        south = lat0 < 0
        if south:  # Snyder: the south-polar case is the north-polar one with signs of x, y, phi, lambda reversed
            x, y, lam0 = -x, -y, -lam0
        if "standard_parallel" in mapping:
            pc = np.deg2rad(_get(mapping, "standard_parallel")) * (-1 if south else 1)
            scale = a * _m(pc, e) / _t(pc, e)
        else:
            k0 = _get(mapping, "scale_factor_at_projection_origin", 1.0)
            scale = 2 * a * k0 / np.sqrt((1 + e) ** (1 + e) * (1 - e) ** (1 - e))
        rho = np.hypot(x, y)
        lam, phi = lam0 + np.arctan2(x, -y), _phi_from_t(rho / scale, e)
        return (-lam, -phi) if south else (lam, phi)
    if e != 0.0:
        raise DataError("an oblique stereographic grid on an ellipsoid is not read (store 2-D latitude/longitude)",
                        path=path, field=field)
    k0 = _get(mapping, "scale_factor_at_projection_origin", 1.0)
    p1 = np.deg2rad(lat0)
    rho = np.hypot(x, y)
    c = 2 * np.arctan(rho / (2 * a * k0))
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.where(rho > 0,
                       np.arcsin(np.cos(c) * np.sin(p1) + y * np.sin(c) * np.cos(p1) / np.where(rho > 0, rho, 1.0)), p1)
    lam = lam0 + np.arctan2(x * np.sin(c), rho * np.cos(p1) * np.cos(c) - y * np.sin(p1) * np.sin(c))
    return lam, phi


__all__ = ["SUPPORTED", "WGS84", "figure", "inverse"]
