"""GRIB grids at their true places: regular and reduced Gaussian, rotated (ECMWF and NCEP 32769),
Lambert conformal and polar stereographic.

Independent truth: ecCodes' own positions of the written message (its geo-iterator, which
also un-rotates ECMWF rotated grids), and PROJ (pyproj, in a subprocess as in
test_projections.py) for NCEP's rotated grid and the projections.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from gribfiles import message, write

from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError

eccodes = pytest.importorskip("eccodes")
DATA = Path(__file__).resolve().parents[2] / "data" / "grib"
LEVELS = (1000, 850, 500)


def _on_levels(path, sample=None, keys=(), values=None, src=None):
    """Three isobaric messages of one grid: from a sample with ``keys`` or cloned from real message ``src``."""
    if src is not None:
        with open(src, "rb") as f:
            base = eccodes.codes_grib_new_from_file(f)
        values = eccodes.codes_get_values(base) if values is None else values
    out = []
    for k, p in enumerate(LEVELS):
        h = eccodes.codes_clone(base) if src is not None else message(sample, keys)
        if eccodes.codes_get(h, "edition") == 1:
            eccodes.codes_set(h, "indicatorOfTypeOfLevel", 100)
        else:
            eccodes.codes_set(h, "typeOfFirstFixedSurface", 100)
            eccodes.codes_set(h, "typeOfSecondFixedSurface", 255)
        eccodes.codes_set(h, "level", p)
        eccodes.codes_set_values(h, np.asarray(values, dtype=np.float64).ravel() + k)
        out.append(h)
    if src is not None:
        eccodes.codes_release(base)
    return write(path, out)


def _positions(path, unrotated=True):
    """ecCodes' latitudes and longitudes of the first message, and its values."""
    with open(path, "rb") as f:
        h = eccodes.codes_grib_new_from_file(f)
    if not unrotated:
        eccodes.codes_set(h, "iteratorDisableUnrotate", 1)
    out = eccodes.codes_get_array(h, "latitudes"), eccodes.codes_get_array(h, "longitudes"), eccodes.codes_get_values(h)
    eccodes.codes_release(h)
    return out


def _same_lon(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


PROJ = (
    "import json, sys, numpy as np, pyproj\n"
    "a = json.load(sys.stdin)\n"
    "crs = pyproj.CRS(a['crs']) if isinstance(a['crs'], str) else pyproj.CRS.from_cf(a['crs'])\n"
    "geo = pyproj.CRS.from_proj4(f\"+proj=longlat +R={a['R']}\") if a.get('R') else crs.geodetic_crs\n"
    "if a['forward']:\n"
    "    x, y = pyproj.Transformer.from_crs(geo, crs, always_xy=True).transform(np.array(a['x']), np.array(a['y']))\n"
    "else:\n"
    "    x, y = pyproj.Transformer.from_crs(crs, geo, always_xy=True).transform(np.array(a['x']), np.array(a['y']))\n"
    "print(json.dumps([np.asarray(x).tolist(), np.asarray(y).tolist()]))\n"
)


def proj(crs, x, y, forward=False, radius=None):
    """PROJ in its own process (its wheels and netCDF4's crash together at exit here)."""
    if importlib.util.find_spec("pyproj") is None:
        pytest.skip("pyproj is not installed")
    args = {"crs": crs, "x": np.asarray(x, dtype=float).ravel().tolist(),
            "y": np.asarray(y, dtype=float).ravel().tolist(), "forward": forward, "R": radius}
    out = subprocess.run([sys.executable, "-c", PROJ], input=json.dumps(args), capture_output=True, text=True,
                         check=True, timeout=120)
    a, b = json.loads(out.stdout)
    return np.array(a).reshape(np.shape(x)), np.array(b).reshape(np.shape(y))


def _rows(g, lat2d_ref):
    """Rows of the reference in the grid's order (the reader may reverse rows to keep the grid right-handed)."""
    return slice(None) if np.allclose(g.lat2d[0], lat2d_ref[0], atol=1e-6) else slice(None, None, -1)


# ---------------------------------------------------------------------------------------------- Gaussian grids
def test_regular_gaussian_latitudes_are_eccodes_gaussian_latitudes(tmp_path):
    path = _on_levels(tmp_path / "gg.grib2", "regular_gg_pl_grib2", values=np.linspace(200, 300, 8192))
    ds = open_dataset(path)
    lat, lon, values = _positions(path)
    np.testing.assert_allclose(ds.grid.lat, np.unique(lat), atol=1e-9)
    assert ds.grid.shape == (3, 64, 128) and ds.grid.periodic_lon
    np.testing.assert_allclose(ds.read("t", 0)[0], values.reshape(64, 128)[::-1], rtol=1e-7)


def _reduced(tmp_path, src=None):
    if src is None:
        h = message("reduced_gg_pl_32_grib2")
        lat, lon = eccodes.codes_get_array(h, "latitudes"), eccodes.codes_get_array(h, "longitudes")
        eccodes.codes_release(h)
        values = 280 + 20 * np.cos(np.deg2rad(lat)) * np.cos(np.deg2rad(lon)) + 5 * np.sin(np.deg2rad(3 * lon))
        return _on_levels(tmp_path / "rgg.grib2", "reduced_gg_pl_32_grib2", values=values)
    return _on_levels(tmp_path / "rgg.grib", src=src)


@pytest.mark.parametrize("real", [False, True], ids=["ecCodes sample N32", "ECMWF reduced_gg.grib N48"])
def test_reduced_gaussian_expands_along_each_latitude_circle(tmp_path, real):
    path = _reduced(tmp_path, DATA / "reduced_gg.grib" if real else None)
    ds = open_dataset(path)
    lat, lon, values = _positions(path)
    rows = np.unique(lat)[::-1]  # north first, as stored
    pl = np.array([(lat == r).sum() for r in rows])
    nlon = pl.max()
    assert ds.grid.shape == (3, rows.size, nlon) and ds.grid.periodic_lon
    np.testing.assert_allclose(ds.grid.lat, rows[::-1], atol=1e-9)
    np.testing.assert_allclose(ds.grid.lon, np.arange(nlon) * 360.0 / nlon, atol=1e-9)
    assert any("reduced Gaussian" in n and "linear interpolation along each latitude circle" in n for n in ds.notes)
    got = ds.read(ds.file_names.get("temperature", next(iter(ds.file_names.values()))), 0)[0][::-1]  # north first again
    start = 0
    for j, n in enumerate(pl):
        v, lo = values[start:start + n], lon[start:start + n]
        want = np.interp(ds.grid.lon, np.append(lo, lo[0] + 360.0), np.append(v, v[0]), period=360.0)
        np.testing.assert_allclose(got[j], want, rtol=1e-6, atol=1e-5)
        if n == nlon:
            np.testing.assert_allclose(got[j], v, rtol=1e-6)  # full rows keep their points exactly
        start += n


# ---------------------------------------------------------------------------------------------- rotated grids
@pytest.mark.parametrize("real", [False, True],
                         ids=["ecCodes sample, pole 35 S 15 E", "rotated_ll.grib1 (pygrib sample)"])
def test_ecmwf_rotated_grid_at_ecCodes_true_positions(tmp_path, grib_samples, real):
    if real:
        path = _on_levels(tmp_path / "rot.grib1", src=grib_samples / "rotated_ll.grib1")
    else:
        keys = (("latitudeOfSouthernPoleInDegrees", -35.0), ("longitudeOfSouthernPoleInDegrees", 15.0))
        path = _on_levels(tmp_path / "rot.grib2", "rotated_ll_pl_grib2", keys, values=np.linspace(250, 290, 496))
    ds = open_dataset(path)
    g = ds.grid
    assert g.rotation is not None and not g.curvilinear
    lat, lon, values = _positions(path)
    nj, ni = g.shape[1:]
    true_lon, true_lat = g.true_lonlat()
    rows = (slice(None, None, -1) if not np.isclose(lat.reshape(nj, ni)[0, 0], true_lat[0, 0], atol=1e-4)
            else slice(None))
    np.testing.assert_allclose(true_lat, lat.reshape(nj, ni)[rows], atol=2e-5)  # ecCodes rounds to ~1e-5 degree
    assert _same_lon(true_lon, lon.reshape(nj, ni)[rows]).max() < 2e-5
    np.testing.assert_allclose(ds.read(ds.resolve(next(iter(ds.file_names.values()))), 0)[0],
                               values.reshape(nj, ni)[rows], rtol=1e-6)


def test_rotated_grid_with_an_angle_is_refused_in_one_line(tmp_path):
    keys = (("latitudeOfSouthernPoleInDegrees", -35.0), ("longitudeOfSouthernPoleInDegrees", 15.0),
            ("angleOfRotationInDegrees", 25.0))
    path = _on_levels(tmp_path / "rot.grib2", "rotated_ll_pl_grib2", keys, values=np.zeros(496))
    with pytest.raises(DataError,
                       match=r"rot.grib2: field 't': rotated grid with an angle of rotation of 25 degrees is not read"):
        open_dataset(path)


def _rotated_to_true(x, y, centre_lat, centre_lon):
    """PROJ's true longitude/latitude of rotated coordinates whose (0, 0) is true (centre_lon, centre_lat)."""
    crs = (f"+proj=ob_tran +o_proj=longlat +o_lat_p={90.0 - centre_lat} +o_lon_p=0 +lon_0={centre_lon} "
           "+R=6371229 +no_defs")
    return proj(crs, x, y, radius=6371229)


def test_ncep_32769_rotated_grid_at_proj_positions(tmp_path):
    """NCEP's encoding: true first and last points, centre of the rotation; grid 2 degrees, centred on 54 N 106 W."""
    x, y = np.arange(-10, 11) * 2.0, np.arange(-5, 6) * 2.0
    (lo1, lo2), (la1, la2) = _rotated_to_true([x[0], x[-1]], [y[0], y[-1]], 54.0, 254.0)
    keys = (("centre", "kwbc"), ("gridDefinitionTemplateNumber", 32769), ("Ni", x.size), ("Nj", y.size),
            ("latitudeOfFirstGridPointInDegrees", float(la1)), ("longitudeOfFirstGridPointInDegrees", float(lo1 % 360)),
            ("latitudeOfLastGridPointInDegrees", 54.0), ("longitudeOfLastGridPointInDegrees", 254.0),
            ("latitudeOfGridPoints", int(round(la2 * 1e6))), ("longitudeOfGridPoints", int(round((lo2 % 360) * 1e6))),
            ("scanningMode", 64))
    values = np.add.outer(y, x)  # rows south to north as scanned
    path = _on_levels(tmp_path / "rap-like.grib2", "regular_ll_pl_grib2", keys, values=values)
    ds = open_dataset(path)
    g = ds.grid
    assert g.rotation is not None
    np.testing.assert_allclose(g.lon, x, atol=1e-5)
    np.testing.assert_allclose(g.lat, y, atol=1e-5)
    X, Y = np.meshgrid(x, y)
    want_lon, want_lat = _rotated_to_true(X, Y, 54.0, 254.0)
    true_lon, true_lat = g.true_lonlat()
    np.testing.assert_allclose(true_lat, want_lat, atol=1e-5)
    assert _same_lon(true_lon, want_lon).max() < 1e-5
    np.testing.assert_array_equal(ds.read("t", 0)[0], values.astype(np.float32))
    assert any("template 3.32769" in n for n in ds.notes)


def test_rap_native_grid_32769_is_centred_on_its_rotation(tmp_path, grib_samples):
    """The real RAP message on three levels: corners at the file's true first/last points, the middle
    column at the centre of the rotation (54 N 254 E), PROJ agreeing everywhere it is asked."""
    path = _on_levels(tmp_path / "rap3.grib2", src=grib_samples / "rap.wrfnat.grib2")
    ds = open_dataset(path)
    g = ds.grid
    nj, ni = g.shape[1:]
    true_lon, true_lat = g.true_lonlat()
    assert (nj, ni) == (834, 953)
    np.testing.assert_allclose([true_lat[0, 0], true_lat[-1, -1]], [-10.590603, 46.591976], atol=1e-6)
    assert _same_lon([true_lon[0, 0], true_lon[-1, -1]], [220.914154, 22.661009]).max() < 1e-6
    assert abs(g.lon[0] + g.lon[-1]) < 1e-3 and abs(g.lat[0] + g.lat[-1]) < 1e-3  # symmetric about the centre
    pick = (np.array([0, 100, 417, 700, 833]), np.array([0, 500, 476, 900, 952]))
    want_lon, want_lat = _rotated_to_true(g.lon[pick[1]], g.lat[pick[0]], 54.0, 254.0)
    np.testing.assert_allclose(true_lat[pick], want_lat, atol=1e-6)
    assert _same_lon(true_lon[pick], want_lon).max() < 1e-6


# ---------------------------------------------------------------------------------------------- projections
def _lambert_keys(nx=30, ny=20):
    return (("gridType", "lambert"), ("Nx", nx), ("Ny", ny), ("latitudeOfFirstGridPointInDegrees", 25.0),
            ("longitudeOfFirstGridPointInDegrees", 240.0), ("LaDInDegrees", 40.0), ("LoVInDegrees", 262.5),
            ("Latin1InDegrees", 33.0), ("Latin2InDegrees", 45.0), ("DxInMetres", 100000.0), ("DyInMetres", 100000.0),
            ("shapeOfTheEarth", 6), ("jScansPositively", 1))


def _projected_truth(path, crs, radius):
    """PROJ's positions of the grid ecCodes describes: the first point projected, then even steps of Dx, Dy."""
    with open(path, "rb") as f:
        h = eccodes.codes_grib_new_from_file(f)
    k = {n: eccodes.codes_get(h, n)
         for n in ("Nx", "Ny", "DxInMetres", "DyInMetres", "latitudeOfFirstGridPointInDegrees",
                                              "longitudeOfFirstGridPointInDegrees", "iScansNegatively",
                                              "jScansPositively")}
    eccodes.codes_release(h)
    (x0,), (y0,) = proj(crs, [k["longitudeOfFirstGridPointInDegrees"]], [k["latitudeOfFirstGridPointInDegrees"]],
                        forward=True, radius=radius)
    assert k["jScansPositively"] == 1 and k["iScansNegatively"] == 0  # NCEP's scanning mode 64, as the products use
    X, Y = np.meshgrid(x0 + k["DxInMetres"] * np.arange(k["Nx"]), y0 + k["DyInMetres"] * np.arange(k["Ny"]))
    return proj(crs, X, Y, radius=radius)


@pytest.mark.parametrize("real", [False, True], ids=["ecCodes Lambert", "NCEP Eta eta.grb"])
def test_lambert_grid_at_proj_positions(tmp_path, grib_samples, real):
    if real:
        path = grib_samples / "eta.grb"
        crs = "+proj=lcc +lat_1=25 +lat_2=25 +lat_0=25 +lon_0=265 +R=6371229 +no_defs"
    else:
        path = _on_levels(tmp_path / "lcc.grib2", "regular_ll_pl_grib2", _lambert_keys(),
                          values=np.linspace(250, 300, 600))
        crs = "+proj=lcc +lat_1=33 +lat_2=45 +lat_0=40 +lon_0=262.5 +R=6371229 +no_defs"
    ds = open_dataset(path)
    g = ds.grid
    assert g.curvilinear
    want_lon, want_lat = _projected_truth(path, crs, 6371229)
    rows = _rows(g, want_lat)
    np.testing.assert_allclose(g.lat2d, want_lat[rows], atol=1e-4)
    assert _same_lon(g.lon2d, want_lon[rows]).max() < 1e-4
    if not real:
        np.testing.assert_allclose(ds.read("t", 0)[1], (np.linspace(250, 300, 600) + 1).reshape(20, 30)[rows],
                                   rtol=1e-7)


def test_polar_stereographic_grid_at_proj_positions(tmp_path):
    keys = (("gridType", "polar_stereographic"), ("Nx", 25), ("Ny", 20), ("latitudeOfFirstGridPointInDegrees", 40.0),
            ("longitudeOfFirstGridPointInDegrees", 200.0), ("LaDInDegrees", 60.0),
            ("orientationOfTheGridInDegrees", 250.0),
            ("DxInMetres", 200000.0), ("DyInMetres", 200000.0), ("shapeOfTheEarth", 6), ("jScansPositively", 1))
    path = _on_levels(tmp_path / "ps.grib2", "regular_ll_pl_grib2", keys, values=np.arange(500.0))
    ds = open_dataset(path)
    want_lon, want_lat = _projected_truth(path, "+proj=stere +lat_0=90 +lat_ts=60 +lon_0=250 +R=6371229 +no_defs",
                                          6371229)
    rows = _rows(ds.grid, want_lat)
    np.testing.assert_allclose(ds.grid.lat2d, want_lat[rows], atol=1e-4)
    assert _same_lon(ds.grid.lon2d, want_lon[rows]).max() < 1e-4


def test_projected_grid_scanning_minus_y_is_placed_as_eccodes_places_it_and_says_so(tmp_path):
    """WMO GRIB2 issue 55: decoders differ on -y scanning of Lambert grids; ecCodes (and so Nephele) steps +y."""
    keys = _lambert_keys()[:-1] + (("jScansPositively", 0),)
    path = _on_levels(tmp_path / "lcc-minus-y.grib2", "regular_ll_pl_grib2", keys, values=np.linspace(250, 300, 600))
    ds = open_dataset(path)
    lat, lon, _ = _positions(path)
    rows = _rows(ds.grid, lat.reshape(20, 30))
    np.testing.assert_allclose(ds.grid.lat2d, lat.reshape(20, 30)[rows], atol=1e-9)
    assert any("wgrib2 would mirror it" in n for n in ds.notes)
