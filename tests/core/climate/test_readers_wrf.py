"""WRF history layout: XLAT/XLONG(Time, y, x), eta levels with the geopotential PH + PHB on staggered levels,
T as perturbation potential temperature, P + PB as pressure.

No small real WRF output was found in the packages used for tests/data (Debian, PyPI sample data), so the
file is written here with WRF's variable names, dimensions and units from a known atmosphere: heights,
pressure and temperature are then known by hand at every mass level.
"""

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

from nephele.core.climate.grid import lonlat_to_xyz  # noqa: E402
from nephele.core.climate.humidity import G0  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402

NZ, NY, NX, NT = 6, 12, 16, 2


def _atmosphere(z):
    """The written atmosphere: pressure (Pa) and air temperature (K) at height z (m)."""
    return 1.0e5 * np.exp(-z / 8000.0), 288.0 - 0.0065 * z


K = 0.7  # wavenumber (per grid step) of the written winds


def _staggered_winds(z_stag, alpha):
    """U = 10 sin(K x) on west_east_stag (x = -1/2 .. NX - 1/2), V = 5 + 3 cos(K y) on south_north_stag,
    W = 0.001 z on bottom_top_stag; their mean over two neighbours is known in closed form:
    10 sin(K i) cos(K/2), 5 + 3 cos(K j) cos(K/2), and 0.001 z at the mass levels (W linear in z)."""
    xs, ys = np.arange(NX + 1) - 0.5, np.arange(NY + 1) - 0.5
    u = np.broadcast_to(10.0 * np.sin(K * xs), (NT, NZ, NY, NX + 1)).astype(np.float32)
    v = np.broadcast_to((5.0 + 3.0 * np.cos(K * ys))[:, None], (NT, NZ, NY + 1, NX)).astype(np.float32)
    w = np.repeat((1e-3 * z_stag)[None], NT, axis=0).astype(np.float32)
    out = {
        "U": (("Time", "bottom_top", "south_north", "west_east_stag"), u, {"units": "m s-1", "stagger": "X"}),
        "V": (("Time", "bottom_top", "south_north_stag", "west_east"), v, {"units": "m s-1", "stagger": "Y"}),
        "W": (("Time", "bottom_top_stag", "south_north", "west_east"), w, {"units": "m s-1", "stagger": "Z"}),
    }
    if alpha is not None:  # WRF's rotation from grid to earth axes, here one angle per column
        for name, f in (("COSALPHA", np.cos), ("SINALPHA", np.sin)):
            out[name] = (("Time", "south_north", "west_east"), np.repeat(f(alpha)[None], NT, axis=0).astype(np.float32),
                         {"units": ""})
    return out


def _wrf_file(path, winds=False, alpha=None):
    y, x = np.meshgrid(np.arange(NY), np.arange(NX), indexing="ij")
    lat = 40.0 + 0.25 * y + 0.02 * x  # a slightly sheared curvilinear grid
    lon = -105.0 + 0.3 * x - 0.01 * y
    hgt = 1500.0 + 800.0 * np.exp(-((x - 8) ** 2 + (y - 6) ** 2) / 10.0)  # a mountain
    eta_w = np.linspace(0.0, 1.0, NZ + 1)
    z_stag = hgt[None] + eta_w[:, None, None] * (12000.0 - hgt[None])  # terrain following, top at 12 km
    z_mass = 0.5 * (z_stag[:-1] + z_stag[1:])
    p, t_air = _atmosphere(z_mass)
    theta_pert = t_air * (1.0e5 / p) ** (2.0 / 7.0) - 300.0
    cloud = np.clip((z_mass - 1500.0) / 5000.0, 0.0, 1.0)  # linear in height through the 0.5 crossing
    rep = lambda a: np.repeat(a[None], NT, axis=0).astype(np.float32)  # noqa: E731
    data = {
        "XLAT": (("Time", "south_north", "west_east"), rep(lat),
                 {"units": "degree_north", "description": "LATITUDE, SOUTH IS NEGATIVE"}),
        "XLONG": (("Time", "south_north", "west_east"), rep(lon),
                  {"units": "degree_east", "description": "LONGITUDE, WEST IS NEGATIVE"}),
        "XTIME": (("Time",), np.array([0.0, 60.0]),
                  {"units": "minutes since 2020-06-01 00:00:00", "description": "minutes since 2020-06-01 00:00:00"}),
        "HGT": (("Time", "south_north", "west_east"), rep(hgt), {"units": "m"}),
        "PH": (("Time", "bottom_top_stag", "south_north", "west_east"), rep(0.1 * G0 * z_stag), {"units": "m2 s-2"}),
        "PHB": (("Time", "bottom_top_stag", "south_north", "west_east"), rep(0.9 * G0 * z_stag), {"units": "m2 s-2"}),
        "T": (("Time", "bottom_top", "south_north", "west_east"), rep(theta_pert),
              {"units": "K", "description": "perturbation potential temperature (theta-t0)"}),
        "P": (("Time", "bottom_top", "south_north", "west_east"), rep(0.2 * p), {"units": "Pa"}),
        "PB": (("Time", "bottom_top", "south_north", "west_east"), rep(0.8 * p), {"units": "Pa"}),
        "CLDFRA": (("Time", "bottom_top", "south_north", "west_east"), rep(cloud),
                   {"units": "", "description": "CLOUD FRACTION"}),
    }
    if winds:
        data.update(_staggered_winds(z_stag, alpha))
    xr.Dataset(data, attrs={"TITLE": " OUTPUT FROM WRF V4 MODEL (written by the Nephele test)",
                            "MAP_PROJ": 1}).to_netcdf(path)
    return lon, lat, z_mass, p, t_air, cloud


def test_wrf_levels_temperature_and_positions(tmp_path):
    lon, lat, z_mass, p, t_air, cloud = _wrf_file(tmp_path / "wrfout_d01.nc")
    ds = open_dataset(tmp_path / "wrfout_d01.nc")
    g = ds.grid
    assert g.curvilinear and g.shape == (NZ, NY, NX)
    assert ds.vertical.startswith("WRF eta levels")
    assert ds.earth_radius == 6370000.0 and any(n.startswith("radius: WRF") for n in ds.notes)
    np.testing.assert_allclose(g.height, z_mass, rtol=1e-6)  # (PH + PHB)/g destaggered, float32 in the file
    np.testing.assert_allclose(g.points(dtype=np.float64)[0], lonlat_to_xyz(lon, lat, g.radii()[0]), atol=1e-6)
    np.testing.assert_allclose(ds.read("pressure", 1), p, rtol=1e-6)
    np.testing.assert_allclose(ds.read("temperature", 0), t_air, atol=2e-3)  # Poisson from theta and P + PB
    assert ds.variables["temperature"].units == "K" and "WRF T" in ds.derived["temperature"]
    # The file's own T is the perturbation potential temperature, by its own name.
    np.testing.assert_allclose(ds.read("T", 0) + 300.0, t_air * (1e5 / p) ** (2 / 7), atol=2e-3)
    np.testing.assert_allclose(ds.read("cloud", 0), cloud, atol=1e-6)
    np.testing.assert_array_equal(ds.hours, [0.0, 1.0])
    assert "staggered: PH, PHB read at the mass points (mean of the two neighbours)" in ds.notes  # no winds here
    assert "u" not in ds.variables and not any(n.startswith("wind") for n in ds.notes)


def test_staggered_winds_at_mass_points_closed_form(tmp_path):
    _lon, _lat, z_mass, *_ = _wrf_file(tmp_path / "wrfout_d01.nc", winds=True)
    ds = open_dataset(tmp_path / "wrfout_d01.nc")
    assert {"u", "v", "w"} <= set(ds.variables) and not {"U", "V", "W"} & set(ds.skipped)
    assert ds.file_names["u"] == "U" and ds.file_names["w"] == "W"
    i, j = np.arange(NX), np.arange(NY)
    u, v, w = ds.wind(1)
    assert u.shape == v.shape == w.shape == ds.grid.shape == (NZ, NY, NX)
    np.testing.assert_allclose(u, np.broadcast_to(10.0 * np.sin(K * i) * np.cos(K / 2), u.shape), atol=2e-6)
    np.testing.assert_allclose(v, np.broadcast_to((5.0 + 3.0 * np.cos(K * j) * np.cos(K / 2))[:, None], v.shape),
                               atol=2e-6)
    np.testing.assert_allclose(w, 1e-3 * z_mass, rtol=1e-6)
    assert np.array_equal(ds.read("U", 0), u)  # the file's own name
    # The destaggered geopotential is the level heights' geopotential: (PH + PHB) / g at mass points.
    np.testing.assert_allclose((ds.read("PH", 0) + ds.read("PHB", 0)) / G0, z_mass, rtol=1e-5)
    assert any(n.startswith("staggered: PH, PHB, U, V, W") for n in ds.notes)
    assert any("along the grid's axes" in n for n in ds.notes)


def test_staggered_winds_turned_to_earth_axes_with_cosalpha(tmp_path):
    y, x = np.meshgrid(np.arange(NY), np.arange(NX), indexing="ij")
    alpha = np.deg2rad(-20.0 + 2.0 * x + 0.5 * y)  # the grid's x axis turned from east, column by column
    _wrf_file(tmp_path / "wrfout_d01.nc", winds=True, alpha=alpha)
    ds = open_dataset(tmp_path / "wrfout_d01.nc")
    ug = np.broadcast_to(10.0 * np.sin(K * x) * np.cos(K / 2), (NZ, NY, NX))
    vg = np.broadcast_to(5.0 + 3.0 * np.cos(K * y) * np.cos(K / 2), (NZ, NY, NX))
    u, v, _ = ds.wind(0)
    np.testing.assert_allclose(u, ug * np.cos(alpha) - vg * np.sin(alpha), atol=5e-6)
    np.testing.assert_allclose(v, vg * np.cos(alpha) + ug * np.sin(alpha), atol=5e-6)
    np.testing.assert_allclose(np.hypot(u, v), np.hypot(ug, vg), atol=5e-6)  # a rotation keeps the speed
    assert any(n.startswith("wind: U, V turned") for n in ds.notes)


def test_staggered_field_of_the_wrong_size_is_skipped_with_its_reason(tmp_path):
    import xarray as xr

    _wrf_file(tmp_path / "a.nc")
    with xr.open_dataset(tmp_path / "a.nc") as f:
        f = f.load()
    f["U"] = (("Time", "bottom_top", "south_north", "west_east_stag"), np.zeros((NT, NZ, NY, NX + 2), np.float32))
    f.to_netcdf(tmp_path / "b.nc")
    ds = open_dataset(tmp_path / "b.nc")
    assert "u" not in ds.variables and "expected one more" in ds.skipped["U"]


def test_wrf_cloud_contour_follows_the_written_cloud_layer(tmp_path):
    from nephele.core.surface.contour import isosurface

    _wrf_file(tmp_path / "wrfout_d01.nc")
    ds = open_dataset(tmp_path / "wrfout_d01.nc")
    g = ds.grid
    mesh = isosurface(g.points(), ds.read("cloud", 1), 0.5, attributes={"altitude": g.height.astype(np.float32)})
    assert len(mesh.faces) > 100
    alt = mesh.attributes["altitude"]
    # cloud = (z - 1500) / 5000 is 0.5 at z = 4000 m; linear in height along every cell edge there, so the
    # contour's interpolated altitude is exact up to float32.
    np.testing.assert_allclose(alt, 4000.0, atol=0.05)


def test_wrf_cloud_voxel_volume_follows_the_written_cloud_layer(tmp_path):
    from nephele.core.climate.grid import height_from_radius, xyz_to_lonlat
    from nephele.core.volume.sparse import height_scale, resample
    from nephele.core.volume.transfer import TransferFunction

    _wrf_file(tmp_path / "wrfout_d01.nc")
    ds = open_dataset(tmp_path / "wrfout_d01.nc")
    tf = TransferFunction.ramp(0.3, 0.7)  # cloud 0.3..0.7: heights 3000..5000 m, over the mountain too
    vol = resample(ds.grid, ds.read("cloud", 0), tf, voxel_size=0.002)
    assert vol.stats["active_voxels"] > 1000
    idx = np.argwhere((vol.density > 0.0) & (vol.density < 1.0))
    centres = (vol.blocks[idx[:, 0]] * vol.block + idx[:, 1:]) * vol.voxel_size
    lon, lat, r = xyz_to_lonlat(centres)
    h = height_from_radius(r)
    # Over the mountain the lowest level (up to 3108 m) is already in the ramp: the resampler extends it
    # at most 1.75 voxels into the ground (CurvilinearField.locate), nothing lower.
    lowest = ds.grid.height[0].max()
    assert 3000.0 < lowest < 3200.0
    assert idx.shape[0] > 500 and h.min() > 3000.0 - 1.75 * 0.002 / height_scale() and h.max() < 5000.0 + 1.0
    assert lat.min() >= 40.0 - 1e-6 and lat.max() <= 40.0 + 0.25 * (NY - 1) + 0.02 * (NX - 1) + 1e-6
    # cloud = (z - 1500) / 5000 is linear in height and the cells' heights are trilinear too, so the
    # resampled cloud at a voxel centre above every column's lowest level is exactly (h - 1500) / 5000.
    above = h > lowest
    assert above.sum() > 500
    np.testing.assert_allclose(vol.density[tuple(idx[above].T)], tf((h[above] - 1500.0) / 5000.0), atol=2e-5)


def test_destagger_closed_form_and_too_few_points():
    from nephele.core.climate.netcdf import destagger

    a = np.arange(24.0).reshape(2, 3, 4) ** 2  # f(x) = x^2 along the last axis: mean of neighbours f(x + 1/2) + 1/4
    x = np.arange(24.0).reshape(2, 3, 4)[..., :-1]
    np.testing.assert_allclose(destagger(a, 2), (x + 0.5) ** 2 + 0.25, rtol=1e-15)
    assert destagger(a, 0).shape == (1, 3, 4) and destagger(a, 1).shape == (2, 2, 4)
    with pytest.raises(ValueError, match="at least 2"):
        destagger(np.zeros((1, 3)), 0)
