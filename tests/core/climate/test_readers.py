"""Readers: real GrADS and ECHAM5 files, synthetic CF layouts, and a clear error for each bad input."""

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

from nephele.core.climate.humidity import standard_height  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402

UNDEF = -2.56e33


# --------------------------------------------------------------------------- real files
def test_grads_sample_model_output(shared_data):
    ctl = shared_data / "climate" / "model.ctl"
    ds = open_dataset(ctl)
    assert ds.grid.shape == (7, 46, 72)
    assert ds.times[0] == np.datetime64("1987-01-02T00:00") and ds.times.size == 5
    np.testing.assert_array_equal(np.diff(ds.hours), 24.0)
    assert ds.grid.periodic_lon and ds.grid.lat[0] == -90.0 and ds.grid.lat[-1] == 90.0
    assert {"u", "v", "temperature", "q", "Z", "pressure", "rh", "cloud"} <= set(ds.variables)
    assert set(ds.skipped) == {"PS", "TS", "P"}
    # Heights: mean geopotential heights, rising, 500 hPa near 5.5 km.
    h = ds.grid.height[:, 0, 0]
    assert np.all(np.diff(h) > 0) and 5000 < h[3] < 6000
    # A value read independently: 36 records of 46x72 per time, U is records 1..7.
    raw = np.fromfile(ctl.parent / "model.dat", dtype="<f4").reshape(5, 36, 46, 72)
    t, k, j, i = 3, 4, 30, 17
    assert ds.read("u", t)[k, j, i] == raw[t, 1 + k, j, i]
    assert ds.read("temperature", t)[k, j, i] == raw[t, 22 + k, j, i]
    # UNDEF (below ground) -> NaN, in the same places.
    np.testing.assert_array_equal(np.isnan(ds.read("temperature", 0)[0]), raw[0, 22] == np.float32(UNDEF))
    assert np.isnan(ds.read("temperature", 0)[0]).sum() == 1738
    # Q has 5 of 7 levels: NaN above 300 hPa.
    q = ds.read("q", 0)
    assert np.isnan(q[5:]).all() and np.isfinite(q[4]).all()
    cloud = ds.read("cloud", 2)
    finite = cloud[np.isfinite(cloud)]
    assert finite.min() >= 0 and finite.max() <= 1 and 0.01 < np.mean(finite > 0.15) < 0.6
    rh = ds.read("rh", 2)
    assert np.nanmax(rh) <= 1.0


def test_echam5_netcdf(shared_data):
    path = shared_data / "climate" / "rectilinear_grid_3D.nc"
    ds = open_dataset(path)
    assert ds.grid.shape == (17, 96, 192)
    assert ds.times[0] == np.datetime64("2001-01-01T00:00")
    g = ds.grid
    assert np.all(np.diff(g.lat) > 0) and g.lon[0] == 0.0 and g.lon[-1] == 358.125 and g.periodic_lon
    np.testing.assert_allclose(g.height[:, 5, 5],
                               standard_height(np.sort([100000, 92500, 85000, 77500, 70000, 60000, 50000, 40000, 30000,
                                                        25000, 20000, 15000, 10000, 7000, 5000, 3000, 1000])[::-1]))
    assert "pressure" in ds.vertical
    with xr.open_dataset(path, decode_times=False) as f:
        t_file = f["t"].values[0]
        rh_file = f["rhumidity"].values[0]
        lon_file = f["lon"].values
        lat_file = f["lat"].values
    # Independent mapping of one file index to ours: lat flipped, lon wrapped to 0..360.
    kf, jf, i_f = 6, 10, 3  # lon -174.375 -> 185.625
    j = int(np.flatnonzero(g.lat == lat_file[jf])[0])
    i = int(np.flatnonzero(g.lon == np.mod(lon_file[i_f], 360))[0])
    assert ds.read("temperature", 0)[kf, j, i] == t_file[kf, jf, i_f]
    rh = ds.read("rh", 0)
    assert rh_file.min() < 0 and rh_file.max() > 1  # the file really is outside [0, 1] ...
    assert rh.min() == 0 and rh.max() == 1  # ... and we clip
    assert ds.derived["cloud"].startswith("rh, Sundqvist")
    cloud = ds.read("cloud", 0)
    assert cloud.min() >= 0 and cloud.max() <= 1 and np.mean(cloud > 0.15) > 0.05


def test_orography_file_is_2d(shared_data):
    with pytest.raises(DataError, match=r"orog_mod1.*no 3-D field"):
        open_dataset(shared_data / "climate" / "orog_mod1_rectilinear_grid_2D.nc")


# ---------------------------------------------------------------- synthetic NetCDF layouts
def _write(path, data_vars, coords, attrs=None):
    ds = xr.Dataset(data_vars, coords=coords, attrs=attrs or {})
    ds.to_netcdf(path)
    return path


def _basic(tmp_path, name="f.nc", lev=(1000.0, 850.0, 500.0), lat=(-60.0, 0.0, 60.0), lon=(0.0, 90.0, 180.0, 270.0),
           var="t", units="K"):
    shape = (2, len(lev), len(lat), len(lon))
    values = np.arange(np.prod(shape), dtype=np.float32).reshape(shape) + 200.0
    coords = {
        "time": ("time", [0.0, 6.0], {"units": "hours since 1987-01-01 00:00:00", "calendar": "standard"}),
        "lev": ("lev", np.asarray(lev), {"units": "hPa", "positive": "down"}),
        "lat": ("lat", np.asarray(lat), {"units": "degrees_north"}),
        "lon": ("lon", np.asarray(lon), {"units": "degrees_east"}),
    }
    return _write(tmp_path / name, {var: (("time", "lev", "lat", "lon"), values, {"units": units})}, coords), values


def test_pressure_levels_reordered_and_times(tmp_path):
    # Top-down levels, north-to-south latitudes, -180..180 longitudes: all put into Nephele's order.
    path, values = _basic(tmp_path, lev=(300.0, 700.0, 1000.0), lat=(60.0, 0.0, -60.0), lon=(-90.0, 0.0, 90.0, 180.0))
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds.grid.lat, [-60, 0, 60])
    np.testing.assert_array_equal(ds.grid.lon, [0, 90, 180, 270])
    assert np.all(np.diff(ds.grid.height[:, 0, 0]) > 0)
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 0, 0], [100000, 70000, 30000])
    np.testing.assert_array_equal(ds.times, np.array(["1987-01-01T00", "1987-01-01T06"], dtype="datetime64[s]"))
    out = ds.read("temperature", 1)
    # ours[k, j, i] = file[2 - k, 2 - j, (i + 1) % 4]
    for k, j, i in ((0, 0, 0), (2, 1, 3), (1, 2, 2)):
        assert out[k, j, i] == values[1, 2 - k, 2 - j, (i + 1) % 4]


def test_hybrid_sigma_pressure_is_terrain_following(tmp_path):
    nk, lat, lon = 4, np.array([-30.0, 0.0, 30.0]), np.arange(0.0, 360.0, 60.0)
    hyam = np.array([0.0, 5000.0, 20000.0, 10000.0])  # Pa
    hybm = np.array([0.99, 0.8, 0.3, 0.0])
    ps = np.full((1, 3, 6), 100000.0)
    ps[0, 1, 2] = 60000.0  # a mountain
    coords = {
        "time": ("time", [0.0], {"units": "days since 2000-01-01"}),
        "lev": ("lev", np.arange(nk, dtype=float), {"standard_name": "atmosphere_hybrid_sigma_pressure_coordinate",
                                                    "formula_terms": "ap: hyam b: hybm ps: aps"}),
        "lat": ("lat", lat, {"units": "degrees_north"}),
        "lon": ("lon", lon, {"units": "degrees_east"}),
    }
    data = {
        "hyam": ("lev", hyam, {"units": "Pa"}),
        "hybm": ("lev", hybm),
        "aps": (("time", "lat", "lon"), ps, {"units": "Pa"}),
        "rh": (("time", "lev", "lat", "lon"), np.full((1, nk, 3, 6), 95.0, dtype=np.float32), {"units": "%"}),
    }
    ds = open_dataset(_write(tmp_path / "hyb.nc", data, coords))
    p = ds.read("pressure", 0)
    np.testing.assert_allclose(p[:, 1, 2], hyam + hybm * 60000.0, rtol=1e-6)
    h = ds.grid.height
    np.testing.assert_allclose(h[0, 1, 2], standard_height(59400.0), rtol=1e-6)
    assert h[0, 1, 2] > h[0, 0, 0] + 3000  # the bottom level rises over the mountain
    np.testing.assert_allclose(ds.read("rh", 0), 0.95, rtol=1e-6)  # percent -> fraction
    np.testing.assert_allclose(ds.read("cloud", 0), 1 - np.sqrt(0.05 / 0.2), rtol=1e-5)
    assert "terrain following" in ds.vertical


def test_hybrid_height_and_plain_height(tmp_path):
    lat, lon = np.array([-10.0, 10.0]), np.array([0.0, 120.0, 240.0])
    orog = np.array([[0.0, 500.0, 1000.0], [200.0, 0.0, 2000.0]])
    coords = {
        "lev": ("lev", np.array([10.0, 1000.0, 5000.0]), {"standard_name": "atmosphere_hybrid_height_coordinate",
                                                          "formula_terms": "a: lev b: bb orog: orog", "units": "m"}),
        "lat": ("lat", lat, {"units": "degrees_north"}),
        "lon": ("lon", lon, {"units": "degrees_east"}),
    }
    data = {
        "bb": ("lev", np.array([1.0, 0.6, 0.0])),
        "orog": (("lat", "lon"), orog),
        "u": (("lev", "lat", "lon"), np.ones((3, 2, 3), dtype=np.float32), {"units": "m s-1"}),
    }
    ds = open_dataset(_write(tmp_path / "hh.nc", data, coords))
    np.testing.assert_allclose(ds.grid.height[0], 10.0 + orog)
    np.testing.assert_allclose(ds.grid.height[1], 1000.0 + 0.6 * orog)
    assert ds.times.size == 1 and ds.grid.periodic_lon
    coords["lev"] = ("lev", np.array([0.5, 2.0, 8.0]), {"units": "km", "positive": "up"})
    del data["bb"]
    ds = open_dataset(_write(tmp_path / "z.nc", data, coords))
    np.testing.assert_allclose(ds.grid.height[:, 1, 1], [500.0, 2000.0, 8000.0])


# ---------------------------------------------------------------------------- bad input
def test_cf_hybrid_without_p0_and_percent_labelled_fraction(tmp_path):
    """formula_terms naming a P0 the file lacks: CAM's 100000 Pa with a note; RH labelled '1' holding percent."""
    lat, lon = np.array([-30.0, 0.0, 30.0]), np.arange(0.0, 360.0, 60.0)
    hyam, hybm = np.array([0.0, 0.05, 0.2, 0.1]), np.array([0.99, 0.8, 0.3, 0.0])
    coords = {
        "lev": ("lev", np.arange(4.0), {"standard_name": "atmosphere_hybrid_sigma_pressure_coordinate",
                                        "formula_terms": "a: hyam b: hybm p0: P0 ps: PS"}),
        "lat": ("lat", lat, {"units": "degrees_north"}),
        "lon": ("lon", lon, {"units": "degrees_east"}),
    }
    data = {
        "hyam": ("lev", hyam),
        "hybm": ("lev", hybm),
        "PS": (("lat", "lon"), np.full((3, 6), 98000.0), {"units": "Pa"}),
        "rh": (("lev", "lat", "lon"), np.full((4, 3, 6), 95.0, dtype=np.float32), {"units": "1"}),
    }
    ds = open_dataset(_write(tmp_path / "nop0.nc", data, coords))
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 2, 3], hyam * 100000.0 + hybm * 98000.0, rtol=1e-6)
    assert "lev: reference pressure 'P0' is not in the file; used CAM's P0 = 100000 Pa" in ds.notes
    assert "rh: units '1' but values reach 95; read as percent" in ds.notes
    np.testing.assert_allclose(ds.read("rh", 0), 0.95, rtol=1e-6)
    assert ds.times.size == 1 and "time: the file has no time axis; one step" in ds.notes


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(DataError, match="missing.nc: file not found"):
        open_dataset(tmp_path / "missing.nc")
    with pytest.raises(DataError, match="missing.ctl: file not found"):
        open_dataset(tmp_path / "missing.ctl")
    txt = tmp_path / "data.txt"
    txt.write_text("hello")
    with pytest.raises(DataError, match=r"data.txt: unknown format '.txt'"):
        open_dataset(txt)
    junk = tmp_path / "junk.nc"
    junk.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(DataError, match="junk.nc: cannot open as NetCDF"):
        open_dataset(junk)


def test_missing_variable(tmp_path):
    path, _ = _basic(tmp_path, var="u", units="m/s")
    ds = open_dataset(path)
    with pytest.raises(DataError, match=r"f.nc: field 'cloud': no such variable"):
        ds.read("cloud", 0)


def test_wrong_dimensions(tmp_path):
    coords = {"lat": ("lat", [0.0, 10.0], {"units": "degrees_north"}),
              "lon": ("lon", [0.0, 10.0, 20.0], {"units": "degrees_east"})}
    path = _write(tmp_path / "flat.nc", {"t": (("lat", "lon"), np.zeros((2, 3)))}, coords)
    with pytest.raises(DataError, match=r"flat.nc: field 'variables': no 3-D field"):
        open_dataset(path)
    path = _write(tmp_path / "nolon.nc", {"t": (("a", "b", "c"), np.zeros((2, 2, 2)))}, {})
    with pytest.raises(DataError, match=r"nolon.nc: field 'lon': no longitude coordinate"):
        open_dataset(path)


def test_nan_coordinates(tmp_path):
    path, _ = _basic(tmp_path, lat=(-60.0, np.nan, 60.0))
    with pytest.raises(DataError, match=r"f.nc: field 'lat': has NaN coordinates"):
        open_dataset(path)
    path, _ = _basic(tmp_path, name="g.nc", lev=(1000.0, np.nan, 500.0))
    with pytest.raises(DataError, match=r"g.nc: field 'lev': has NaN level"):
        open_dataset(path)


def test_non_monotonic_levels(tmp_path):
    path, _ = _basic(tmp_path, lev=(1000.0, 500.0, 700.0))
    with pytest.raises(DataError, match=r"f.nc: field 'lev': levels are not monotonic"):
        open_dataset(path)


def test_unknown_vertical_coordinate(tmp_path):
    path, _ = _basic(tmp_path)
    with xr.open_dataset(path) as f:
        f = f.load()
    f["lev"].attrs = {"units": "level"}
    f.to_netcdf(tmp_path / "lev.nc")
    with pytest.raises(DataError, match=r"lev.nc: field 'lev': cannot tell what the vertical coordinate is"):
        open_dataset(tmp_path / "lev.nc")


# ------------------------------------------------------------------------------ GrADS
def _grads(tmp_path, body, data, name="s"):
    (tmp_path / f"{name}.dat").write_bytes(data)
    ctl = tmp_path / f"{name}.ctl"
    ctl.write_text(body.replace("DATA", f"^{name}.dat"))
    return ctl


CTL = """DSET DATA
OPTIONS {options}
UNDEF -9.99e8
XDEF 4 LINEAR 0 90
YDEF 3 LEVELS -45 0 45
ZDEF 2 LEVELS 1000 500
TDEF 3 LINEAR 06Z1FEB1990 {step}
VARS 2
T 2 99 temperature
RH 1 99 humidity in percent? no: fraction
ENDVARS
"""


def test_grads_endianness_yrev_undef_and_steps(tmp_path):
    nt, nx, ny = 3, 4, 3
    rng = np.random.default_rng(0)
    t = rng.uniform(200, 300, size=(nt, 2, ny, nx)).astype(np.float32)
    rh = rng.uniform(0, 1, size=(nt, 1, ny, nx)).astype(np.float32)
    t[1, 0, 2, 3] = -9.99e8
    rows = np.concatenate([t, rh], axis=1)  # file order: rows north->south under yrev
    ctl = _grads(tmp_path, CTL.format(options="big_endian yrev", step="6hr"), rows.astype(">f4").tobytes())
    ds = open_dataset(ctl)
    np.testing.assert_array_equal(ds.times,
                                  np.array(["1990-02-01T06", "1990-02-01T12", "1990-02-01T18"], dtype="datetime64[s]"))
    np.testing.assert_array_equal(ds.grid.lat, [-45, 0, 45])
    out = ds.read("temperature", 1)
    # yrev: the first file row is the northernmost latitude.
    assert out[1, 2, 1] == t[1, 1, 0, 1] and out[0, 0, 0] == t[1, 0, 2, 0]
    assert np.isnan(out[0, 0, 3])  # UNDEF
    assert np.isnan(ds.read("rh", 0)[1]).all()  # one level of two
    ctl = _grads(tmp_path, CTL.format(options="little_endian", step="1mo"), rows.astype("<f4").tobytes(), name="m")
    ds = open_dataset(ctl)
    np.testing.assert_array_equal(ds.times,
                                  np.array(["1990-02-01T06", "1990-03-01T06", "1990-04-01T06"], dtype="datetime64[s]"))
    assert ds.read("temperature", 2)[1, 0, 2] == t[2, 1, 0, 2]


def test_grads_errors(tmp_path):
    good = CTL.format(options="little_endian", step="1dy")
    size = 3 * 3 * 4 * 3 * 4
    ctl = tmp_path / "nodat.ctl"
    ctl.write_text(good.replace("DATA", "^nodat.dat"))
    with pytest.raises(DataError, match=r"nodat.ctl: field 'dset': data file .* not found"):
        open_dataset(ctl)
    ctl = _grads(tmp_path, good, b"\0" * (size - 8), name="short")
    with pytest.raises(DataError, match=r"short.dat: field 'dset': .*wrong dimensions"):
        open_dataset(ctl)
    ctl = _grads(tmp_path, good.replace("ZDEF 2 LEVELS 1000 500", "ZDEF 3 LEVELS 1000 500 700").replace("T 2", "T 3"),
                 b"\0" * 10_000, name="mono")
    with pytest.raises(DataError, match=r"mono.ctl: field 'zdef': levels are not monotonic"):
        open_dataset(ctl)
    ctl = _grads(tmp_path, good.replace("XDEF 4 LINEAR 0 90\n", ""), b"\0" * size, name="nox")
    with pytest.raises(DataError, match=r"nox.ctl: field 'xdef': descriptor has no XDEF"):
        open_dataset(ctl)
    ctl = _grads(tmp_path, good.replace("06Z1FEB1990", "sometime"), b"\0" * size, name="badt")
    with pytest.raises(DataError, match=r"badt.ctl: field 'tdef': cannot read the time 'sometime'"):
        open_dataset(ctl)


def test_seam_column_and_regional_grid(tmp_path):
    # 0..360 inclusive: the repeated meridian is dropped and the grid is periodic.
    path, values = _basic(tmp_path, lon=(0.0, 90.0, 180.0, 270.0, 360.0))
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds.grid.lon, [0, 90, 180, 270])
    assert ds.grid.periodic_lon
    np.testing.assert_array_equal(ds.read("temperature", 0)[..., 3], values[0][..., 3])
    # A regional grid across 0 degrees stays contiguous and ascending, and is not periodic.
    path, values = _basic(tmp_path, name="r.nc", lon=(350.0, 355.0, 0.0, 5.0, 10.0))
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds.grid.lon, [-10, -5, 0, 5, 10])
    assert not ds.grid.periodic_lon
    np.testing.assert_array_equal(ds.read("temperature", 1), values[1])


def test_pressure_levels_use_geopotential_height_and_sigma_levels(tmp_path):
    lev, lat, lon = np.array([1000.0, 700.0, 300.0]), np.array([-45.0, 45.0]), np.array([0.0, 120.0, 240.0])
    zg = np.empty((1, 3, 2, 3), dtype=np.float32)
    zg[0] = np.array([100.0, 3000.0, 9000.0])[:, None, None] + np.arange(6, dtype=np.float32).reshape(2, 3)
    coords = {
        "time": ("time", [0.0], {"units": "days since 2000-01-01"}),
        "plev": ("plev", lev * 100.0, {"units": "Pa", "standard_name": "air_pressure"}),
        "lat": ("lat", lat, {"units": "degrees_north"}),
        "lon": ("lon", lon, {"units": "degrees_east"}),
    }
    data = {"zg": (("time", "plev", "lat", "lon"), zg, {"units": "m", "standard_name": "geopotential_height"})}
    ds = open_dataset(_write(tmp_path / "zg.nc", data, coords))
    np.testing.assert_allclose(ds.grid.height[:, 0, 0], [102.5, 3002.5, 9002.5])  # level means
    assert "mean geopotential height" in ds.vertical
    # sigma levels: p = ptop + sigma (ps - ptop)
    coords = {
        "lev": ("lev", np.array([0.95, 0.5, 0.1]),
                {"standard_name": "atmosphere_sigma_coordinate", "formula_terms": "sigma: lev ps: ps ptop: ptop"}),
        "lat": ("lat", lat, {"units": "degrees_north"}),
        "lon": ("lon", lon, {"units": "degrees_east"}),
    }
    data = {
        "ptop": ((), 1000.0, {"units": "Pa"}),
        "ps": (("lat", "lon"), np.full((2, 3), 1000.0), {"units": "hPa"}),
        "t": (("lev", "lat", "lon"), np.full((3, 2, 3), 250.0, dtype=np.float32), {"units": "K"}),
    }
    ds = open_dataset(_write(tmp_path / "sigma.nc", data, coords))
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 1, 1], 1000.0 + np.array([0.95, 0.5, 0.1]) * 99000.0,
                               rtol=1e-6)


def test_time_problems(tmp_path):
    """Non-CF times become numbered steps with a note; other calendars keep their elapsed times."""
    path, _ = _basic(tmp_path)
    with xr.open_dataset(path, decode_times=False) as f:
        f = f.load()
    nt = f.sizes["time"]
    steps = np.datetime64("1970-01-01T00:00", "s") + np.arange(nt) * np.timedelta64(3600, "s")
    g = f.drop_vars("time")
    g.to_netcdf(tmp_path / "notime.nc")
    ds = open_dataset(tmp_path / "notime.nc")
    np.testing.assert_array_equal(ds.times, steps)
    assert any("dimension 'time' has no coordinate" in n for n in ds.notes)
    f["time"].attrs["units"] = "Month"  # the NCL sample's units: not '<unit> since <date>'
    f.to_netcdf(tmp_path / "months.nc")
    ds = open_dataset(tmp_path / "months.nc")
    np.testing.assert_array_equal(ds.times, steps)
    assert any("time units 'Month'" in n for n in ds.notes)
    # The caller can say what the file does not.
    ds = open_dataset(tmp_path / "months.nc", time_units="days since 2000-03-01")
    np.testing.assert_array_equal(ds.times, np.datetime64("2000-03-01", "s")
                                  + (f["time"].values * 86400).astype("timedelta64[s]"))
    f["time"].attrs.update(units="hours since 1987-01-01", calendar="360_day")
    f.to_netcdf(tmp_path / "cal.nc")
    ds = open_dataset(tmp_path / "cal.nc")
    np.testing.assert_array_equal(ds.hours, f["time"].values - f["time"].values[0])
    f["time"].attrs.update(calendar="martian")
    f.to_netcdf(tmp_path / "mars.nc")
    with pytest.raises(DataError, match=r"mars.nc: field 'time': calendar 'martian' is not a CF calendar"):
        open_dataset(tmp_path / "mars.nc")


# ----------------------------------------------------- real model output from other packages
# Small real files under tests/data (provenance in tests/data/README.md).
DATA = __import__("pathlib").Path(__file__).resolve().parents[2] / "data"


def _nc(path):
    netCDF4 = pytest.importorskip("netCDF4")
    f = netCDF4.Dataset(path)
    f.set_auto_mask(False)
    return f


def _proj_rotated_to_true(path, mapping, rlon, rlat):
    """True lon/lat of a rotated grid by PROJ, in a fresh Python: pyproj imported after netCDF4 has
    opened a file crashes the interpreter (their bundled libraries clash), so it runs apart."""
    import importlib.util
    import json
    import subprocess
    import sys

    if importlib.util.find_spec("pyproj") is None:
        pytest.skip("pyproj is not installed")
    code = (
        "import json, sys, numpy as np, pyproj, netCDF4\n"
        "a = json.load(sys.stdin)\n"
        "with netCDF4.Dataset(a['path']) as f:\n"
        "    cf = {k: f[a['mapping']].getncattr(k) for k in f[a['mapping']].ncattrs()}\n"
        "crs = pyproj.CRS.from_cf({k: (v.item() if hasattr(v, 'item') else v) for k, v in cf.items()})\n"
        "lon, lat = pyproj.Transformer.from_crs(crs, 'EPSG:4326', always_xy=True).transform(*np.meshgrid(a['rlon'], "
        "a['rlat']))\njson.dump([lon.tolist(), lat.tolist()], sys.stdout)\n"
    )
    args = json.dumps({"path": str(path), "mapping": mapping, "rlon": list(map(float, rlon)),
                       "rlat": list(map(float, rlat))})
    out = subprocess.run([sys.executable, "-c", code], input=args, capture_output=True, text=True, check=True).stdout
    lon, lat = json.loads(out)
    return np.array(lon), np.array(lat)


def _contour(ds, name, level):
    from nephele.core.surface.contour import isosurface

    return isosurface(ds.grid.points(), ds.read(name, 0), level, periodic_lon=ds.grid.periodic_lon)


def test_cam_history_file_ncar_hybrid_levels():
    """CAM: lev in units hybrid_sigma_pressure with A_var/B_var/P0_var/PS_var, P0 not stored."""
    path = DATA / "cam_vinth2p.nc"
    ds = open_dataset(path)
    assert ds.grid.shape == (18, 64, 128) and ds.times.size == 2
    assert ds.times[0] == np.datetime64("0049-09-01", "s") + np.timedelta64(107, "D")
    assert ds.notes == [
        "lev: reference pressure 'P0' is not in the file; used CAM's P0 = 100000 Pa",
        "radius: NCAR hybrid levels, so CAM's planet radius 6.37122e+06 m",
    ]
    assert ds.earth_radius == 6371220.0
    with _nc(path) as f:
        hyam, hybm, ps, t_file, lat = (f[n][:].astype(np.float64) for n in ("hyam", "hybm", "PS", "T", "lat"))
    # File lev runs top -> bottom (index 0 = 3.6 hPa); ours bottom -> top; lat is already ascending.
    assert np.all(np.diff(lat) > 0)
    k, j, i, t = 4, 20, 77, 1
    kf = 17 - k
    p_hand = hyam[kf] * 100000.0 + hybm[kf] * ps[t, j, i]
    np.testing.assert_allclose(ds.read("pressure", t)[k, j, i], p_hand, rtol=1e-6)
    np.testing.assert_allclose(ds.grid.height[k, j, i], standard_height(hyam[kf] * 1e5 + hybm[kf] * ps[0, j, i]),
                               rtol=1e-5)
    assert ds.read("temperature", t)[k, j, i] == np.float32(t_file[t, kf, j, i])
    # The file's own name works too.
    assert "T" in ds and ds.read("T", t) is ds.read("temperature", t)
    # The caller's P0 replaces the default.
    ds2 = open_dataset(path, p0=90000.0)
    np.testing.assert_allclose(ds2.read("pressure", t)[k, j, i], hyam[kf] * 90000.0 + hybm[kf] * ps[t, j, i], rtol=1e-6)
    assert not any("P0" in n for n in ds2.notes)
    # Overrides of what the file says or leaves out: the radius, which variable is which.
    ds3 = open_dataset(path, radius=6.4e6, variables={"theta_like": "T"})
    assert ds3.earth_radius == 6.4e6 and "temperature" not in ds3 and ds3.read("T", t) is ds3.read("theta_like", t)
    with pytest.raises(DataError, match=r"cam_vinth2p.nc: field 'TS': is not a 3-D field"):
        open_dataset(path, variables={"temperature": "TS"})
    mesh = _contour(ds, "temperature", 250.0)
    assert len(mesh.faces) > 1000

    r = np.linalg.norm(mesh.vertices, axis=1)
    radii = ds.grid.radii()
    assert radii.min() - 1e-6 < r.min() and r.max() < radii.max() + 1e-6  # between the lowest and top levels


def test_ncl_file_month_time_and_kelvin_labelled_celsius():
    """NCL's nc4uvt.nc (T only): time units 'Month', T labelled 'C' but 190..311: kelvin, said in a note."""
    path = DATA / "ncl_nc4uvt_T.nc"
    ds = open_dataset(path)
    assert ds.times.size == 1 and ds.grid.shape == (14, 64, 128)
    assert any(n.startswith("time: time units 'Month'") for n in ds.notes)
    assert any("units 'C' but values" in n and "read as K" in n for n in ds.notes)
    with _nc(path) as f:
        t_file, lev, lon = f["T"][0].astype(np.float64), f["lev"][:].astype(np.float64), f["lon"][:].astype(np.float64)
    lon_order = np.argsort(np.mod(lon, 360.0))  # the file runs -180..177.2, ours 0..357.2
    np.testing.assert_array_equal(ds.grid.lon, np.mod(lon, 360.0)[lon_order])
    kf = int(np.argmax(lev))  # 1000 hPa is our level 0
    order = np.argsort(-lev)
    assert order[0] == kf
    got = ds.read("temperature", 0)
    np.testing.assert_array_equal(got, t_file[order][:, :, lon_order].astype(np.float32))  # not 463..584 K
    assert 180 < np.nanmin(got) and np.nanmax(got) < 320
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 0, 0], lev[order] * 100.0)
    assert len(_contour(ds, "T", 260.0).faces) > 1000


def test_vertical_override_on_unlabelled_levels(tmp_path):
    """The NCL file with its level units removed: refused in one line, read as before with vertical=."""
    with xr.open_dataset(DATA / "ncl_nc4uvt_T.nc", decode_times=False) as f:
        f = f.load()
    f["lev"].attrs.pop("units")
    f.to_netcdf(tmp_path / "nounits.nc")
    with pytest.raises(DataError,
                       match=r"nounits.nc: field 'lev': cannot tell what the vertical coordinate is .*vertical="):
        open_dataset(tmp_path / "nounits.nc")
    ds, ref = open_dataset(tmp_path / "nounits.nc", vertical="pressure_hpa"), open_dataset(DATA / "ncl_nc4uvt_T.nc")
    np.testing.assert_array_equal(ds.grid.height, ref.grid.height)
    np.testing.assert_array_equal(ds.read("pressure", 0), ref.read("pressure", 0))
    with pytest.raises(DataError, match=r"field 'lev': vertical='sigma' is not one of"):
        open_dataset(tmp_path / "nounits.nc", vertical="sigma")


def test_um_rotated_pole_hybrid_height():
    """UM: rotated pole, scalar time, hybrid height on the auxiliary level_height/sigma/surface_altitude."""
    path = DATA / "um_hybrid_height.nc"
    ds = open_dataset(path)
    assert ds.grid.shape == (15, 100, 100) and ds.times.size == 1
    with _nc(path) as f:
        a, b, orog = (f[n][:].astype(np.float64) for n in ("level_height", "sigma", "surface_altitude"))
        theta = f["air_potential_temperature"][:]
        rlon, rlat = f["grid_longitude"][:].astype(np.float64), f["grid_latitude"][:].astype(np.float64)
        hours = float(f["time"][...])
    assert ds.times[0] == np.datetime64("1970-01-01", "s") + np.timedelta64(int(round(hours * 3600)), "s")
    assert ds.vertical.startswith("hybrid height")
    assert ds.earth_radius == 6371229.0
    k, j, i = 6, 31, 58
    np.testing.assert_allclose(ds.grid.height[k, j, i], a[k] + b[k] * orog[j, i], rtol=1e-6)
    assert ds.read("air_potential_temperature", 0)[k, j, i] == theta[k, j, i]
    np.testing.assert_array_equal(ds.grid.lon, rlon)
    from nephele.core.climate.grid import xyz_to_lonlat

    mesh = _contour(ds, "air_potential_temperature", 288.0)
    assert len(mesh.faces) > 100
    lon_m, lat_m, _ = xyz_to_lonlat(mesh.vertices)
    assert 52.3 < lat_m.min() and lat_m.max() < 52.5 and -3.3 < lon_m.min() and lon_m.max() < -3.0
    # True position of the grid on the globe, against PROJ's rotated pole (near 52.4 N, 3.1 W: Wales).
    lon_true, lat_true = _proj_rotated_to_true(path, "rotated_latitude_longitude", rlon, rlat)
    got_lon, got_lat = ds.grid.true_lonlat()
    np.testing.assert_allclose(got_lat, lat_true, atol=1e-9)
    np.testing.assert_allclose(got_lon, lon_true, atol=1e-9)
    lon_p, lat_p, _ = xyz_to_lonlat(ds.grid.points(dtype=np.float64)[k, j, i])
    np.testing.assert_allclose([lon_p, lat_p], [lon_true[j, i], lat_true[j, i]], atol=1e-9)


def test_zarr_store_written_from_the_cam_file(tmp_path):
    """The CAM file copied to a Zarr store by xarray reads exactly as the NetCDF file does."""
    pytest.importorskip("zarr")
    src = DATA / "cam_vinth2p.nc"
    store = tmp_path / "cam.zarr"
    with xr.open_dataset(src, decode_times=False) as f:
        f.chunk({"time": 1}).to_zarr(store)
    ds, ref = open_dataset(store), open_dataset(src)
    assert ds.grid.shape == ref.grid.shape and ds.notes == ref.notes
    np.testing.assert_array_equal(ds.times, ref.times)
    np.testing.assert_array_equal(ds.grid.height, ref.grid.height)
    for name in ("T", "pressure"):
        np.testing.assert_array_equal(ds.read(name, 1), ref.read(name, 1))
    (tmp_path / "empty.zarr").mkdir()
    with pytest.raises(DataError, match=r"empty.zarr: cannot open as a Zarr store"):
        open_dataset(tmp_path / "empty.zarr")


def test_packed_and_filled_copy_of_the_cam_file(tmp_path):
    """The CAM T packed to int16 (scale_factor/add_offset) with _FillValue holes: unpacked within half a step,
    holes NaN."""
    src = DATA / "cam_vinth2p.nc"
    with xr.open_dataset(src, decode_times=False) as f:
        f = f.load()
    t = f["T"].values.copy()
    t[0, 17, 10:12, 20:25] = np.nan  # a hole in the bottom level
    f["T"].values[:] = t
    scale, offset = 0.01, 250.0
    f["T"].encoding = {"dtype": "int16", "scale_factor": scale, "add_offset": offset, "_FillValue": np.int16(-32768)}
    f.to_netcdf(tmp_path / "packed.nc")
    with _nc(tmp_path / "packed.nc") as g:
        assert g["T"].dtype == np.int16 and g["T"].scale_factor == scale
    ds = open_dataset(tmp_path / "packed.nc")
    got = ds.read("T", 0)
    want = t[0, ::-1]  # ours bottom -> top
    assert np.isnan(got[0, 10:12, 20:25]).all() and np.isnan(got).sum() == 10
    ok = np.isfinite(want)
    assert np.max(np.abs(got[ok] - want[ok])) <= 0.5 * scale + 1e-4
