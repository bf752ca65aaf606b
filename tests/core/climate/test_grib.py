"""GRIB through ecCodes: a real regional GRIB2 file refused clearly, a real field written
to GRIB2 by ecCodes read back exactly."""

import numpy as np
import pytest

from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError

DATA = __import__("pathlib").Path(__file__).resolve().parents[2] / "data"


def test_polar_stereographic_grib2_single_level_is_refused_in_one_line():
    eccodes = pytest.importorskip("eccodes")
    path = DATA / "polar_stereo.grib2"
    with open(path, "rb") as f:  # independent: what ecCodes itself says the grid is
        h = eccodes.codes_grib_new_from_file(f)
        grid, edition = eccodes.codes_get(h, "gridType"), eccodes.codes_get(h, "edition")
        eccodes.codes_release(h)
    assert (grid, edition) == ("polar_stereographic", 2)
    # The projected grid is read now; the file's one field on one level is not a 3-D field.
    with pytest.raises(DataError, match=r"polar_stereo.grib2: field 'variables': no 3-D field") as err:
        open_dataset(path)
    assert "\n" not in str(err.value)


def test_polar_stereographic_grib2_levels_as_a_curvilinear_grid(tmp_path):
    """The real message cloned onto three pressure levels: a 3-D field on the projected grid."""
    eccodes = pytest.importorskip("eccodes")
    from nephele.core.surface.contour import isosurface

    out = tmp_path / "ps3.grib2"
    with open(DATA / "polar_stereo.grib2", "rb") as f:
        src = eccodes.codes_grib_new_from_file(f)
    ni, nj = eccodes.codes_get(src, "Nx"), eccodes.codes_get(src, "Ny")
    lats = eccodes.codes_get_array(src, "latitudes").reshape(nj, ni)
    lons = eccodes.codes_get_array(src, "longitudes").reshape(nj, ni)
    base = eccodes.codes_get_values(src).reshape(nj, ni)
    with open(out, "wb") as w:
        for k, p in enumerate((1000, 850, 500)):
            h = eccodes.codes_clone(src)
            eccodes.codes_set(h, "typeOfFirstFixedSurface", 100)
            eccodes.codes_set(h, "level", p)
            eccodes.codes_set_values(h, (base - 10.0 * k).ravel())
            eccodes.codes_write(h, w)
            eccodes.codes_release(h)
    eccodes.codes_release(src)
    ds = open_dataset(out)
    g = ds.grid
    assert g.curvilinear and g.shape == (3, nj, ni)
    # Columns at ecCodes' own latitudes/longitudes (rows possibly reversed to keep the grid right-handed).
    rows = slice(None) if np.allclose(g.lat2d[0], lats[0]) else slice(None, None, -1)
    np.testing.assert_allclose(g.lat2d, lats[rows], atol=1e-9)
    np.testing.assert_allclose((g.lon2d - lons[rows] + 180) % 360 - 180, 0.0, atol=1e-9)
    t = ds.read("temperature", 0)
    with open(out, "rb") as f:  # what ecCodes decodes from each written (re-packed) message
        written = []
        while (h := eccodes.codes_grib_new_from_file(f)) is not None:
            written.append(eccodes.codes_get_values(h).reshape(nj, ni))
            eccodes.codes_release(h)
    for k in range(3):
        np.testing.assert_allclose(t[k], written[k][rows], rtol=1e-7)
    np.testing.assert_allclose(t[2], base[rows] - 20.0, atol=0.01)  # the message's packing step
    level = float(np.nanmedian(t[1]))
    mesh = isosurface(g.points(), t, level)
    assert len(mesh.faces) > 1000


def _write_grib(path, t_levels, levels_hpa, lon, lat_north_to_south, step=0, mode="wb"):
    eccodes = pytest.importorskip("eccodes")
    with open(path, mode) as out:
        for k, p in enumerate(levels_hpa):
            h = eccodes.codes_grib_new_from_samples("regular_ll_pl_grib2")
            for key, val in (
                ("Ni", lon.size), ("Nj", lat_north_to_south.size),
                ("latitudeOfFirstGridPointInDegrees", float(lat_north_to_south[0])),
                ("latitudeOfLastGridPointInDegrees", float(lat_north_to_south[-1])),
                ("longitudeOfFirstGridPointInDegrees", float(lon[0])),
                ("longitudeOfLastGridPointInDegrees", float(lon[-1])),
                ("iDirectionIncrementInDegrees", float(lon[1] - lon[0])),
                ("jDirectionIncrementInDegrees", float(lat_north_to_south[0] - lat_north_to_south[1])),
                ("level", int(p)), ("dataDate", 19870102), ("dataTime", 0),
                ("stepRange", str(step)), ("packingType", "grid_ieee"), ("precision", 1),
            ):  # fmt: skip
                eccodes.codes_set(h, key, val)
            eccodes.codes_set_values(h, np.asarray(t_levels[k], dtype=np.float64).ravel())
            eccodes.codes_write(h, out)
            eccodes.codes_release(h)


def test_regular_grib2_of_real_grads_temperatures(shared_data, tmp_path):
    """The GrADS sample's T (5 x 4 degrees, 7 pressure levels) written to GRIB2 (IEEE float32) by ecCodes."""
    raw = np.fromfile(shared_data / "climate" / "model.dat", dtype="<f4").reshape(5, 36, 46, 72)
    t = raw[1, 22:29]  # second day, T on 1000..100 hPa, rows from 90 S
    levels = np.array([1000, 850, 700, 500, 300, 200, 100])
    keep = slice(1, None)  # 1000 hPa has UNDEF below ground: GRIB without a bitmap cannot carry it
    lon, lat = np.arange(72) * 5.0, -90.0 + np.arange(46) * 4.0
    path = tmp_path / "grads_T.grib2"
    _write_grib(path, t[keep][:, ::-1], levels[keep], lon, lat[::-1])
    ds = open_dataset(path)
    assert ds.grid.shape == (6, 46, 72) and ds.grid.periodic_lon
    np.testing.assert_array_equal(ds.grid.lat, lat)
    np.testing.assert_array_equal(ds.read("temperature", 0), t[keep])
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 0, 0], levels[keep] * 100.0)
    assert ds.times[0] == np.datetime64("1987-01-02T00:00", "s")
    assert ds.read("t", 0) is ds.read("temperature", 0)
    # A forecast: the same day's T and the next day's as steps 0 h and 24 h of one run.
    fc = tmp_path / "forecast.grib2"
    _write_grib(fc, t[keep][:, ::-1], levels[keep], lon, lat[::-1], step=0)
    _write_grib(fc, raw[2, 22:29][keep][:, ::-1], levels[keep], lon, lat[::-1], step=24, mode="ab")
    ds = open_dataset(fc)
    np.testing.assert_array_equal(ds.times, np.array(["1987-01-02T00", "1987-01-03T00"], dtype="datetime64[s]"))
    np.testing.assert_array_equal(ds.read("temperature", 1), raw[2, 22:29][keep])


def test_corrupted_grib_is_one_line(tmp_path):
    pytest.importorskip("eccodes")
    path = tmp_path / "cut.grib2"
    path.write_bytes((DATA / "polar_stereo.grib2").read_bytes()[:20000])  # a real message cut short
    with pytest.raises(DataError, match=r"cut.grib2: cannot open as GRIB") as err:
        open_dataset(path)
    assert "\n" not in str(err.value)
