"""Curvilinear horizontal grids: 2-D latitude/longitude (CF, WRF names) and projection-only files via PROJ.

No small real 3-D file on a Lambert conformal or WRF grid was found in the
packages used for tests/data, so the 3-D files here are written by the tests:
a Lambert conformal conic grid whose 2-D latitude/longitude come from Snyder's
spherical inverse written out here.  The reader's own projections are checked
against PROJ in test_projections.py, and the real polar stereographic file
(tests/data/toa_brightness_stereographic.nc, satellite brightness, 2-D, a
subset) checks them against the producer's stored latitude/longitude.
"""

from pathlib import Path

import numpy as np
import pytest

xr = pytest.importorskip("xarray")

from projections import lcc_inverse  # noqa: E402

from nephele.core.climate.grid import lonlat_to_xyz, xyz_to_lonlat  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "data"
R = 6370000.0  # WRF's sphere
LCC = {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
       "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0,
       "false_easting": 0.0, "false_northing": 0.0, "earth_radius": R}


def _lcc_file(path, *, with_latlon=True, wrf_names=False, y_down=False, nx=30, ny=20, dx=30000.0):
    x = (np.arange(nx) - (nx - 1) / 2) * dx
    y = (np.arange(ny) - (ny - 1) / 2) * dx
    if y_down:
        y = y[::-1]
    X, Y = np.meshgrid(x, y)
    lon, lat = lcc_inverse(X, Y, radius=R)
    z = np.array([500.0, 1500.0, 3000.0, 6000.0])
    # Temperature falling 6.5 K/km and warmer to the south: contours at 270 K are tilted sheets.
    t = 300.0 - 0.0065 * z[:, None, None] - 0.3 * (lat[None] - 45.0)
    t = np.repeat(t[None], 2, axis=0).astype(np.float32)
    coords = {"time": ("time", [0.0, 3.0], {"units": "hours since 2020-01-01", "standard_name": "time"}),
              "z": ("z", z, {"units": "m", "standard_name": "height", "positive": "up"}),
              "y": ("y", y, {"units": "m", "standard_name": "projection_y_coordinate"}),
              "x": ("x", x, {"units": "m", "standard_name": "projection_x_coordinate"})}
    data = {"T": (("time", "z", "y", "x"), t, {"units": "K", "grid_mapping": "lambert"}),
            "lambert": ((), 0, LCC)}
    if with_latlon and wrf_names:  # WRF writes XLAT/XLONG with a Time dimension and no CF standard_name
        data["XLAT"] = (("time", "y", "x"), np.repeat(lat[None], 2, 0), {"units": "degree_north"})
        data["XLONG"] = (("time", "y", "x"), np.repeat(lon[None], 2, 0), {"units": "degree_east"})
    elif with_latlon:
        coords["lat"] = (("y", "x"), lat, {"units": "degrees_north", "standard_name": "latitude"})
        coords["lon"] = (("y", "x"), lon, {"units": "degrees_east", "standard_name": "longitude"})
    xr.Dataset(data, coords=coords).to_netcdf(path)
    return lon, lat, t


@pytest.mark.parametrize("wrf_names", [False, True])
def test_2d_latlon_grid_positions_and_contour(tmp_path, wrf_names):
    from nephele.core.surface.contour import isosurface

    lon, lat, t = _lcc_file(tmp_path / "lcc.nc", wrf_names=wrf_names)
    ds = open_dataset(tmp_path / "lcc.nc")
    g = ds.grid
    assert g.curvilinear and not g.periodic_lon and g.shape == (4, 20, 30)
    assert ds.earth_radius == R
    # Every column sits at the file's 2-D latitude/longitude.
    np.testing.assert_allclose(g.points(dtype=np.float64)[0], lonlat_to_xyz(lon, lat, g.radii()[0]), atol=1e-12)
    tl, tt = g.true_lonlat()
    np.testing.assert_allclose(tt, lat) and np.testing.assert_allclose(tl, lon)
    np.testing.assert_array_equal(ds.read("temperature", 1), t[1])
    # The contour at 285 K: a tilted sheet at z = (300 - 0.3 (lat - 45) - 285) / 0.0065 m.
    mesh = isosurface(g.points(dtype=np.float64), ds.read("T", 0), 285.0,
                      attributes={"altitude": g.height.astype(np.float32)})
    assert len(mesh.faces) > 500
    vlon, vlat, _ = xyz_to_lonlat(mesh.vertices)
    expected = (15.0 - 0.3 * (vlat - 45.0)) / 0.0065
    inside = (expected > 600) & (expected < 5900)
    # Linear in height between levels, straight chords between columns: within 20 m of the plane.
    np.testing.assert_allclose(mesh.attributes["altitude"][inside], expected[inside], atol=20.0)
    assert lon.min() - 1e-6 < vlon.min() and vlon.max() < lon.max() + 1e-6


def test_rows_north_to_south_are_flipped_to_a_right_handed_grid(tmp_path):
    from nephele.core.surface.contour import isosurface

    _lcc_file(tmp_path / "up.nc")
    _lcc_file(tmp_path / "down.nc", y_down=True)
    up, down = open_dataset(tmp_path / "up.nc"), open_dataset(tmp_path / "down.nc")
    np.testing.assert_allclose(down.grid.lat2d, up.grid.lat2d, atol=1e-12)
    np.testing.assert_array_equal(down.read("T", 0), up.read("T", 0))
    a = isosurface(up.grid.points(), up.read("T", 0), 285.0)
    b = isosurface(down.grid.points(), down.read("T", 0), 285.0)
    assert a.area() == pytest.approx(b.area()) and len(a.faces) == len(b.faces)
    # The flipped file gives the very same mesh, faces wound the same way (normals agree).
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-6)
    np.testing.assert_allclose(a.normals, b.normals, atol=1e-5)


def test_projection_only_file_positions_match_snyder(tmp_path):
    lon, lat, _ = _lcc_file(tmp_path / "xy.nc", with_latlon=False)
    ds = open_dataset(tmp_path / "xy.nc")
    assert ds.grid.curvilinear
    assert "grid: longitudes/latitudes computed from the lambert_conformal_conic grid mapping" in ds.notes
    np.testing.assert_allclose(ds.grid.lat2d, lat, atol=1e-9)
    np.testing.assert_allclose(ds.grid.lon2d, lon, atol=1e-9)


def test_real_polar_stereographic_file_projection_matches_stored_latlon():
    from nephele.core.climate.netcdf import projected_lonlat

    with xr.open_dataset(DATA / "toa_brightness_stereographic.nc") as f:
        lon, lat, _ = projected_lonlat(dict(f["stereographic"].attrs), f["x"].values, f["y"].values)
        assert lat.shape == f["lat"].shape
        # The producer's float32 latitudes/longitudes: equal to ~1e-5 degrees (float32 resolution at 80 degrees).
        np.testing.assert_allclose(lat, f["lat"].values, atol=3e-5)
        np.testing.assert_allclose(((lon - f["lon"].values) + 180.0) % 360.0 - 180.0, 0.0, atol=3e-5)


def test_grid_coordinates_of_points_refuse_a_curvilinear_grid(tmp_path):
    # Points map back to a curvilinear grid only through its columns (ColumnLocator), never to_grid.
    _lcc_file(tmp_path / "lcc.nc")
    ds = open_dataset(tmp_path / "lcc.nc")
    with pytest.raises(DataError, match="curvilinear grid"):
        ds.grid.to_grid(np.zeros((1, 3)))


def _t_closed_form(h, lat):
    return 300.0 - 0.0065 * h - 0.3 * (lat - 45.0)  # the LCC file's T (linear in height, in latitude)


def test_column_locator_inverts_the_grid_and_its_cells(tmp_path):
    from nephele.core.climate.columns import ColumnLocator

    _lcc_file(tmp_path / "lcc.nc")
    g = open_dataset(tmp_path / "lcc.nc").grid
    loc = ColumnLocator(g.lon2d, g.lat2d)
    nj, ni = g.lon2d.shape
    jj, ii = np.meshgrid(np.arange(nj), np.arange(ni), indexing="ij")
    i, j = loc(lonlat_to_xyz(g.lon2d, g.lat2d, 1.002).reshape(-1, 3))  # every column, above the sphere
    np.testing.assert_allclose(i, ii.ravel(), atol=1e-9)
    np.testing.assert_allclose(j, jj.ravel(), atol=1e-9)
    # Points made as the bilinear mix of a cell's corners in the chart come back with their fractions.
    rng = np.random.default_rng(3)
    j0, i0, s, t = rng.integers(0, nj - 1, 5000), rng.integers(0, ni - 1, 5000), rng.random(5000), rng.random(5000)
    P = loc.xy
    xy = (((1 - s) * (1 - t))[:, None] * P[j0, i0] + (s * (1 - t))[:, None] * P[j0, i0 + 1]
          + ((1 - s) * t)[:, None] * P[j0 + 1, i0] + (s * t)[:, None] * P[j0 + 1, i0 + 1])
    i, j = loc(np.c_[xy, np.ones(len(xy))] @ loc.basis)
    np.testing.assert_allclose(i, i0 + s, atol=1e-9)
    np.testing.assert_allclose(j, j0 + t, atol=1e-9)
    # Outside the region (and on the far side of the globe): -1.
    i, j = loc(lonlat_to_xyz(np.array([-140.0, 80.0, -100.0]), np.array([45.0, -45.0, 20.0])))
    assert np.all(i == -1) and np.all(j == -1)
    assert 0.2 < loc.cell_degrees() < 0.4  # 30 km cells (0.27 degrees), diagonals 0.38


def test_voxel_volume_on_a_curvilinear_grid_matches_the_closed_form(tmp_path):
    from nephele.core.climate.grid import height_from_radius
    from nephele.core.volume.sparse import CurvilinearField, height_scale, resample
    from nephele.core.volume.transfer import TransferFunction

    _lcc_file(tmp_path / "lcc.nc")
    ds = open_dataset(tmp_path / "lcc.nc")
    g, t = ds.grid, ds.read("T", 0)
    field = CurvilinearField.from_grid(g, {"value": t})
    # Random points inside the grid's columns and levels: the interpolated T is the written T there
    # (exact in height, second order across a 30 km cell in latitude).
    rng = np.random.default_rng(5)
    nj, ni = g.lon2d.shape
    jj, ii = rng.uniform(0, nj - 1, 4000), rng.uniform(0, ni - 1, 4000)
    j0, i0 = np.minimum(jj.astype(int), nj - 2), np.minimum(ii.astype(int), ni - 2)
    fj, fi = jj - j0, ii - i0
    corners = lonlat_to_xyz(g.lon2d, g.lat2d)
    u = (((1 - fj) * (1 - fi))[:, None] * corners[j0, i0] + ((1 - fj) * fi)[:, None] * corners[j0, i0 + 1]
         + (fj * (1 - fi))[:, None] * corners[j0 + 1, i0] + (fj * fi)[:, None] * corners[j0 + 1, i0 + 1])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    h = rng.uniform(500.0, 6000.0, 4000)
    xyz = u * (1.0 + 30.0 * h / 6371000.0)[:, None]
    lon, lat, _ = xyz_to_lonlat(xyz)
    got = field.sample("value", xyz)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, _t_closed_form(h, lat), atol=2e-3)
    # Outside: NaN (beyond the region, below the lowest level, above the top).
    out = np.array([lonlat_to_xyz(-140.0, 45.0, 1.001), u[0] * (1 + 30 * 100.0 / 6371000.0),
                    u[0] * (1 + 30 * 7000.0 / 6371000.0)])
    assert np.all(np.isnan(field.sample("value", out)))

    # The resampled volume: opacity rising from 0 at T = 279 K to 1 at 281 K (a tilted slab near the ground).
    tf = TransferFunction.ramp(279.0, 281.0)
    vol = resample(g, t, tf, voxel_size=0.002)
    assert not vol.empty and vol.stats["active_voxels"] > 1000
    idx = np.argwhere(vol.density > 0.5)
    centres = (vol.blocks[idx[:, 0]] * vol.block + idx[:, 1:]) * vol.voxel_size
    _, vlat, r = xyz_to_lonlat(centres)
    hv = height_from_radius(r)
    # Every opaque voxel lies over the grid's columns, between its levels or at most 1.75 voxels under the
    # lowest (500 m), where the resampler extends the lowest level's values (CurvilinearField.locate).
    depth = 1.75 * 0.002 / height_scale()
    flat, f, _, ok = field.locate(centres, clamp_below=depth)
    assert np.all(ok) and hv.min() > 500.0 - depth - 1.0 and hv.max() < 6000.0
    expect = _t_closed_form(np.maximum(hv, 500.0), vlat)
    np.testing.assert_allclose(field.interpolate("value", flat, f, ok), expect, atol=2e-3)
    # Opacity > 0.5 means T > 280 K at the voxel centre (up to the 2e-3 K interpolation error) ...
    assert np.all(expect > 280.0 - 2e-3)
    # ... and is exact trilinear resampling: the voxel holds the transfer function of that value.
    np.testing.assert_allclose(vol.density[tuple(idx.T)], tf(expect), atol=2e-3)
    # Nothing is missed: well inside the grid where T > 286 K (every voxel corner around such a point,
    # at most 2.8 K cooler, is opaque), the volume is opaque.
    deep = (_t_closed_form(h, lat) > 286.0) & (h > 1000.0) & (ii > 1) & (ii < ni - 2) & (jj > 1) & (jj < nj - 2)
    assert deep.sum() > 300
    np.testing.assert_allclose(vol.sample(xyz[deep]), 1.0, atol=1e-6)


def test_bad_curvilinear_files(tmp_path):
    lon, lat, t = _lcc_file(tmp_path / "lcc.nc")
    with xr.open_dataset(tmp_path / "lcc.nc") as f:
        f = f.load()
    bad = f.copy()
    bad["lat"] = bad["lat"].where(bad["lat"] < 46.0)
    bad.to_netcdf(tmp_path / "nan.nc")
    with pytest.raises(DataError, match=r"nan.nc: field 'lon': has NaN or infinite 2-D longitudes/latitudes"):
        open_dataset(tmp_path / "nan.nc")
    nomap = f.drop_vars(["lat", "lon"])
    nomap["x"].attrs["units"] = "furlong"
    nomap.to_netcdf(tmp_path / "units.nc")
    with pytest.raises(DataError, match=r"units.nc: .*projection coordinates need units m or km"):
        open_dataset(tmp_path / "units.nc")


def test_cli_info_and_contour_on_a_projected_file(tmp_path, capsys):
    trimesh = pytest.importorskip("trimesh")
    from nephele.farm.cli import main

    lon, lat, _ = _lcc_file(tmp_path / "xy.nc", with_latlon=False)
    assert main(["info", str(tmp_path / "xy.nc"), "--json"]) == 0
    import json

    info = json.loads(capsys.readouterr().out)
    assert info["curvilinear"] and info["earth_radius_m"] == R
    assert info["true_lon"] == pytest.approx([lon.min(),
                                              lon.max()]) and info["true_lat"] == pytest.approx([lat.min(), lat.max()])
    out = tmp_path / "t.ply"
    assert main(["contour", str(tmp_path / "xy.nc"), "--var", "T", "--level", "285", "-o", str(out)]) == 0
    v = np.asarray(trimesh.load(out, force="mesh", process=False).vertices, dtype=np.float64)
    vlon, vlat, _ = xyz_to_lonlat(v)
    assert len(v) > 500 and lat.min() - 1e-4 < vlat.min() and vlat.max() < lat.max() + 1e-4
    capsys.readouterr()
    assert main(["contour", str(tmp_path / "xy.nc"), "--var", "T", "--level", "400", "-o", str(out)]) == 2
    assert "outside the data range" in capsys.readouterr().err


@pytest.mark.parametrize("case", ["date line", "pole", "real stereographic"])
def test_column_locator_hard_places(tmp_path, case):
    """The chart works on unit vectors: no seam at the date line, no singularity at a pole inside the
    grid, and on the real satellite file's producer latitudes/longitudes (float32, 17..81 N)."""
    from nephele.core.climate.columns import ColumnLocator

    if case == "real stereographic":
        with xr.open_dataset(DATA / "toa_brightness_stereographic.nc") as f:
            lon2d, lat2d = f["lon"].values.astype(np.float64), f["lat"].values.astype(np.float64)
    else:
        x = (np.arange(30) - 14.5) * 30000.0
        X, Y = np.meshgrid(x, x[:20])
        lon2d, lat2d = lcc_inverse(X, Y, lon0=180.0 if case == "date line" else -100.0, radius=R)
        if case == "date line":
            lon2d = (lon2d + 180.0) % 360.0 - 180.0  # as files write it: a jump from 180 to -180
            assert lon2d.max() > 179.0 and lon2d.min() < -179.0
        else:  # a polar cap: 20 x 30 columns 100 km apart around the North Pole (azimuthal, equal spacing)
            rho = np.hypot(X * 3.3, Y * 3.3)
            lon2d, lat2d = np.rad2deg(np.arctan2(X, -Y)), 90.0 - np.rad2deg(rho / R)
            assert lat2d.max() > 89.0
    loc = ColumnLocator(lon2d, lat2d)
    nj, ni = lon2d.shape
    jj, ii = np.meshgrid(np.arange(nj), np.arange(ni), indexing="ij")
    i, j = loc(lonlat_to_xyz(lon2d, lat2d).reshape(-1, 3))
    np.testing.assert_allclose(i, ii.ravel(), atol=1e-8)
    np.testing.assert_allclose(j, jj.ravel(), atol=1e-8)
    # Cell centres (mean of the corners' unit vectors) land inside their own cell.
    p = lonlat_to_xyz(lon2d, lat2d)
    centre = p[:-1, :-1] + p[1:, :-1] + p[:-1, 1:] + p[1:, 1:]
    i, j = loc(centre.reshape(-1, 3))
    cj, ci = np.meshgrid(np.arange(nj - 1), np.arange(ni - 1), indexing="ij")
    assert np.all((i > ci.ravel()) & (i < ci.ravel() + 1) & (j > cj.ravel()) & (j < cj.ravel() + 1))
