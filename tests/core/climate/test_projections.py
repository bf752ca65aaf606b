"""Inverse CF map projections (core/projections.py) against PROJ, run in its own process.

PROJ (pyproj) is the independent truth.  It runs in a subprocess because the
pyproj and netCDF4 wheels crash together at interpreter exit here (two bundled
libcurl copies); without pyproj (the numpy 1.26 venv) these tests skip.
"""

import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from nephele.core.climate.projections import inverse
from nephele.core.errors import DataError

CASES = {
    "lcc_2sp_sphere_wrf": {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
                           "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0,
                           "earth_radius": 6370000.0},
    "lcc_1sp_wgs84_false_origin": {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": 25.0,
                                   "longitude_of_central_meridian": -95.0, "latitude_of_projection_origin": 25.0,
                                   "false_easting": 500000.0, "false_northing": -200000.0,
                                   "semi_major_axis": 6378137.0, "inverse_flattening": 298.257223563},
    "lcc_southern": {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [-20.0, -40.0],
                     "longitude_of_central_meridian": 135.0, "latitude_of_projection_origin": -30.0,
                     "semi_major_axis": 6378137.0, "semi_minor_axis": 6356752.314245},
    "polar_north_sp60_ellipsoid": {"grid_mapping_name": "polar_stereographic",
                                   "straight_vertical_longitude_from_pole": -105.0,
                                   "latitude_of_projection_origin": 90.0, "standard_parallel": 60.0,
                                   "semi_major_axis": 6378137.0, "inverse_flattening": 298.257223563},
    "polar_south_k0_sphere": {"grid_mapping_name": "polar_stereographic", "straight_vertical_longitude_from_pole": 0.0,
                              "latitude_of_projection_origin": -90.0, "scale_factor_at_projection_origin": 0.97,
                              "earth_radius": 6371229.0},
    "polar_south_sp71_ellipsoid": {"grid_mapping_name": "polar_stereographic",
                                   "straight_vertical_longitude_from_pole": 0.0,
                                   "latitude_of_projection_origin": -90.0, "standard_parallel": -71.0,
                                   "semi_major_axis": 6378137.0, "inverse_flattening": 298.257223563},
    "stereographic_polar_sphere_toa": {"grid_mapping_name": "stereographic", "longitude_of_projection_origin": -35.0,
                                       "latitude_of_projection_origin": 90.0, "scale_factor_at_projection_origin": 1.0,
                                       "earth_radius": 6378169.0},
    "stereographic_oblique_sphere": {"grid_mapping_name": "stereographic", "longitude_of_projection_origin": 10.0,
                                     "latitude_of_projection_origin": 52.0, "scale_factor_at_projection_origin": 0.9999,
                                     "earth_radius": 6371000.0},
    "mercator_sp_ellipsoid": {"grid_mapping_name": "mercator", "longitude_of_projection_origin": 120.0,
                              "standard_parallel": 20.0,
                              "semi_major_axis": 6378137.0, "inverse_flattening": 298.257223563},
    "mercator_k0_sphere": {"grid_mapping_name": "mercator", "longitude_of_projection_origin": 0.0,
                           "scale_factor_at_projection_origin": 1.0, "earth_radius": 6371229.0},
}

PROJ = (
    "import json, sys, numpy as np, pyproj\n"
    "a = json.load(sys.stdin)\n"
    "out = {}\n"
    "for key, (cf, x, y) in a.items():\n"
    "    crs = pyproj.CRS.from_cf(cf)\n"
    "    lon, lat = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform(np.array(x), "
    "np.array(y))\n    out[key] = [np.asarray(lon).tolist(), np.asarray(lat).tolist()]\n"
    "json.dump(out, sys.stdout)\n"
)


def _points(seed, n=200, half=3.0e6):
    rng = np.random.default_rng(seed)
    return rng.uniform(-half, half, n), rng.uniform(-half, half, n)


@pytest.fixture(scope="module")
def proj_answers():
    if importlib.util.find_spec("pyproj") is None:
        pytest.skip("pyproj is not installed")
    args = {}
    for k, (key, cf) in enumerate(CASES.items()):
        x, y = _points(k, half=1.5e6 if key.startswith("mercator") else 3.0e6)
        args[key] = [cf, x.tolist(), y.tolist()]
    out = subprocess.run([sys.executable, "-c", PROJ], input=json.dumps(args), capture_output=True, text=True,
                         check=True, timeout=120)
    return args, json.loads(out.stdout)


@pytest.mark.parametrize("key", list(CASES))
def test_inverse_matches_proj(proj_answers, key):
    args, answers = proj_answers
    cf, x, y = args[key]
    lon, lat, notes = inverse(cf, np.array(x), np.array(y))
    plon, plat = (np.array(a) for a in answers[key])
    assert not notes
    np.testing.assert_allclose(lat, plat, atol=1e-9)
    np.testing.assert_allclose((lon - plon + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)


def test_origin_and_assumed_figure():
    lon, lat, notes = inverse({"grid_mapping_name": "polar_stereographic",
                               "straight_vertical_longitude_from_pole": 45.0,
                               "latitude_of_projection_origin": 90.0, "scale_factor_at_projection_origin": 1.0}, 0.0,
                              0.0)
    assert lat == pytest.approx(90.0) and notes == ["the grid mapping states no earth figure; WGS84 assumed"]
    cf = CASES["lcc_2sp_sphere_wrf"]
    lon, lat, _ = inverse(cf, 0.0, 0.0)
    assert (float(lon), float(lat)) == pytest.approx((-100.0, 45.0), abs=1e-12)


def test_unknown_or_incomplete_mapping_is_one_line():
    with pytest.raises(DataError, match=r"f.nc: field 'crs': grid mapping 'sinusoidal' is not one of"):
        inverse({"grid_mapping_name": "sinusoidal"}, 0.0, 0.0, path="f.nc", field="crs")
    with pytest.raises(DataError, match=r"lambert_conformal_conic grid mapping lacks 'standard_parallel'"):
        inverse({"grid_mapping_name": "lambert_conformal_conic", "earth_radius": 6.37e6}, 0.0, 0.0)
    with pytest.raises(DataError, match="oblique stereographic grid on an ellipsoid"):
        inverse({"grid_mapping_name": "stereographic", "latitude_of_projection_origin": 50.0,
                 "longitude_of_projection_origin": 0.0,
                 "semi_major_axis": 6378137.0, "inverse_flattening": 298.257223563}, 0.0, 0.0)
