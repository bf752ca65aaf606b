"""The synthetic demo climate: determinism, ranges, and clouds carried by its own winds."""

import numpy as np
import pytest

from nephele.core.climate.grid import EARTH_RADIUS, lonlat_to_xyz, xyz_to_lonlat
from nephele.core.climate.readers import open_dataset
from nephele.core.climate.synthetic import SyntheticClimate, demo_dataset
from nephele.core.errors import DataError


@pytest.fixture(scope="module")
def climate():
    # Fine enough in space for interpolated winds to be accurate, short enough to be quick.
    return SyntheticClimate(ni=128, nj=64, nk=3, days=1, seed=3, n_storms=6)


def _bilinear(field, grid, lon, lat):
    ni, nj = grid.lon.size, grid.lat.size
    x = np.mod(lon - grid.lon[0], 360.0) / (360.0 / ni)
    i0 = np.floor(x).astype(int)
    fx = x - i0
    i0 %= ni
    i1 = (i0 + 1) % ni
    y = np.interp(lat, grid.lat, np.arange(nj))
    j0 = np.minimum(np.floor(y).astype(int), nj - 2)
    fy = y - j0
    return (field[j0, i0] * (1 - fx) + field[j0, i1]
            * fx) * (1 - fy) + (field[j0 + 1, i0] * (1 - fx) + field[j0 + 1, i1] * fx) * fy


def _velocity(ds, k, p, hours):
    """Unit-sphere velocity (per hour) from the dataset's gridded hourly u, v on level k."""
    lon, lat, _ = xyz_to_lonlat(p)
    i0, i1, w = ds.locate_time(hours)
    u = (1 - w) * _bilinear(ds.read("u", i0)[k], ds.grid, lon,
                            lat) + w * _bilinear(ds.read("u", i1)[k], ds.grid, lon, lat)
    v = (1 - w) * _bilinear(ds.read("v", i0)[k], ds.grid, lon,
                            lat) + w * _bilinear(ds.read("v", i1)[k], ds.grid, lon, lat)
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    east = np.stack([-np.sin(lam), np.cos(lam), 0 * lam], -1)
    north = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], -1)
    return (u[:, None] * east + v[:, None] * north) * (3600.0 / EARTH_RADIUS)


def test_clouds_are_carried_by_the_datasets_own_winds(climate):
    """Trace every grid column of level 1 back from the last hour to t = 0 with RK4 through
    the dataset's hourly gridded winds: the start points match the exact flow map and the
    cloud there (C0) matches the cloud read now, within interpolation error."""
    ds, k = climate, 1
    last = ds.times.size - 1
    lon, lat = np.meshgrid(ds.grid.lon, ds.grid.lat)
    x = lonlat_to_xyz(lon.ravel(), lat.ravel())
    p, t, h = x.copy(), float(last), 0.25
    for _ in range(int(round(last / h))):
        k1 = _velocity(ds, k, p, t)
        k2 = _velocity(ds, k, p - 0.5 * h * k1, t - 0.5 * h)
        k3 = _velocity(ds, k, p - 0.5 * h * k2, t - 0.5 * h)
        k4 = _velocity(ds, k, p - h * k3, t - h)
        p = p - h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        t -= h
    exact = np.stack([c[k].ravel() for c in ds.departure(last)], -1)
    err_km = np.arccos(np.clip((exact * p).sum(1), -1, 1)) * EARTH_RADIUS / 1e3
    travel_km = np.arccos(np.clip((exact * x).sum(1), -1, 1)) * EARTH_RADIUS / 1e3
    assert np.median(travel_km) > 200  # the air really moved
    assert np.median(err_km) < 1.0 and np.percentile(err_km, 95) < 25.0
    cloud_now = ds.read("cloud", last)[k].ravel()
    levels = np.full(len(p), k)
    traced = ds.initial_cloud(tuple(p.T), levels)
    unmoved = ds.initial_cloud(tuple(x.T), levels)
    assert np.abs(cloud_now - traced).mean() < 0.02 * np.abs(cloud_now - unmoved).mean()
    np.testing.assert_allclose(cloud_now, ds.initial_cloud(tuple(exact.T), levels), atol=1e-6)


def test_flow_map_inverts_and_starts_at_identity(climate):
    ds = climate
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 5000))
    a /= np.linalg.norm(a, axis=0)
    jet, storm = ds.level_factors(rng.integers(0, ds.grid.shape[0], 5000))
    for sec in (0.0, 7.3 * 3600, 23 * 3600):
        x = ds.forward(tuple(a), sec, jet, storm)
        np.testing.assert_allclose(np.linalg.norm(np.stack(x), axis=0), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.stack(ds.inverse(x, sec, jet, storm)), a, atol=1e-11)
    np.testing.assert_allclose(np.stack(ds.forward(tuple(a), 0.0, jet, storm)), a, atol=1e-15)


def test_wind_matches_central_difference_of_the_flow_map(climate):
    ds, t = climate, 9
    shape = ds.grid.shape
    a = tuple(c.ravel() for c in ds.departure(t))
    jet, storm = ds.level_factors(np.repeat(np.arange(shape[0]), shape[1] * shape[2]))
    sec = ds.hours[t] * 3600.0
    d = 30.0
    x1, x0 = np.stack(ds.forward(a, sec + d, jet, storm)), np.stack(ds.forward(a, sec - d, jet, storm))
    vel = (x1 - x0) * EARTH_RADIUS / (2 * d)
    lam = np.deg2rad(ds.grid.lon)[None, None, :]
    u_ref = (-np.sin(lam) * vel[0].reshape(shape) + np.cos(lam) * vel[1].reshape(shape))
    u, v, w = ds.wind(t)
    np.testing.assert_allclose(u, u_ref, atol=5e-3)


def test_horizontal_wind_is_non_divergent(climate):
    """Every part of the flow map preserves area, so div(u, v) on a level vanishes up to
    finite-difference error: compare with the relative vorticity's size."""
    ds, k = climate, 1
    u, v, _ = (f[k].astype(np.float64) for f in ds.wind(12))
    lam, phi = np.deg2rad(ds.grid.lon), np.deg2rad(ds.grid.lat)
    dlam, dphi = lam[1] - lam[0], phi[1] - phi[0]
    cphi = np.cos(phi)[:, None]
    du_dlam = (np.roll(u, -1, 1) - np.roll(u, 1, 1)) / (2 * dlam)
    dv_dlam = (np.roll(v, -1, 1) - np.roll(v, 1, 1)) / (2 * dlam)
    dvc_dphi = np.gradient(v * cphi, dphi, axis=0)
    duc_dphi = np.gradient(u * cphi, dphi, axis=0)
    inner = slice(3, -3)
    div = ((du_dlam + dvc_dphi) / (EARTH_RADIUS * cphi))[inner]
    vort = ((dv_dlam - duc_dphi) / (EARTH_RADIUS * cphi))[inner]
    assert np.sqrt(np.mean(div**2)) < 0.05 * np.sqrt(np.mean(vort**2))


def test_w_is_the_lift_along_terrain_following_levels(climate):
    """w = u·∇h_k on the level surface: between grid nodes the surface is the bilinear
    interpolant of the grid's heights, so at a node the lift is the upwind difference."""
    ds, t = climate, 15
    for k in (0, 1):
        u, v, w = (f[k].astype(np.float64) for f in ds.wind(t))
        h = ds.grid.height[k]
        lam, phi = np.deg2rad(ds.grid.lon), np.deg2rad(ds.grid.lat)
        dx = (lam[1] - lam[0]) * EARTH_RADIUS * np.cos(phi)[:, None]
        dy = (phi[1] - phi[0]) * EARTH_RADIUS
        east, west = (np.roll(h, -1, 1) - h) / dx, (h - np.roll(h, 1, 1)) / dx
        north = np.diff(h, axis=0, append=h[-1:]) / dy
        south = np.diff(h, axis=0, prepend=h[:1]) / dy
        lift = u * np.where(u > 0, east, west) + v * np.where(v > 0, north, south)
        inner = slice(1, -1)
        np.testing.assert_allclose(w[inner], lift[inner], atol=2e-3 * np.abs(lift).max())
        assert np.abs(w).max() > 0.01
    np.testing.assert_array_equal(ds.wind(t)[2][-1], 0.0)  # the top is flat: no lift


def test_deterministic_and_seeded():
    a = open_dataset("demo:small")
    b = demo_dataset("small")
    c = SyntheticClimate(ni=64, nj=32, nk=8, days=2, seed=1)
    for name in ("cloud", "u", "temperature"):
        np.testing.assert_array_equal(a.read(name, 30), b.read(name, 30))
    assert not np.array_equal(a.read("cloud", 30), c.read("cloud", 30))


def test_small_demo_ranges_poles_and_seam():
    ds = open_dataset("demo:small")
    assert ds.grid.shape == (8, 32, 64) and ds.times.size == 48
    assert ds.times[0] == np.datetime64("1987-01-01T00:00:00")
    np.testing.assert_allclose(np.diff(ds.hours), 1.0)
    assert ds.grid.periodic_lon
    for t in (0, 47):
        c = ds.read("cloud", t)
        u, v, w = ds.wind(t)
        temp = ds.read("temperature", t)
        for f in (c, u, v, w, temp):
            assert np.isfinite(f).all()  # pole rows included
        assert c.min() >= 0.0 and c.max() <= 1.0
        assert 0.05 < np.mean(c > 0.15) < 0.6
        speed = np.hypot(u, v)
        assert 15.0 < speed.max() < 80.0
        assert np.abs(w).max() < 2.0
        assert 180.0 < temp.min() and temp.max() < 320.0
        # Seam: the jump from the last column to the first is like any other column step.
        for f in (c, u, v, temp):
            inner = np.abs(np.diff(f, axis=2)).max()
            assert np.abs(f[..., 0] - f[..., -1]).max() <= 1.01 * inner + 1e-6


def test_grid_is_terrain_following_and_flat_on_top():
    ds = open_dataset("demo:small")
    g = ds.grid
    g.validate()
    np.testing.assert_allclose(g.height[0], g.terrain)
    assert g.terrain.min() >= 0.0 and g.terrain.max() > 2000.0
    np.testing.assert_allclose(g.height[-1], 20_000.0)
    temp = ds.read("temperature", 0)
    assert np.all(np.diff(temp[:4].mean(axis=(1, 2))) < 0)  # colder upward in the troposphere


def test_full_demo_shape_and_one_step():
    ds = open_dataset("demo")
    assert ds.grid.shape == (19, 160, 320) and ds.times.size == 240
    assert ds.times[-1] == np.datetime64("1987-01-10T23:00:00")
    assert np.all(np.abs(ds.grid.lat) < 90.0)
    c = ds.read("cloud", 0)
    assert c.shape == (19, 160, 320) and c.dtype == np.float32
    from scipy import ndimage

    # Fig. 1 shows many separate cloud bodies at 15 % through the troposphere.
    bodies = [ndimage.label(level > 0.15)[1] for level in c[:11]]
    assert min(bodies) >= 5 and sum(bodies) >= 80
    assert 0.1 < np.mean(c > 0.15) < 0.4


def test_bounded_memory():
    ds = SyntheticClimate(ni=32, nj=16, nk=3, days=1, cache_steps=4)
    for t in range(ds.times.size):
        ds.read("cloud", t)
        ds.wind(t)
    assert len(ds._cache) <= 4 and len(ds._departures) <= 2 and len(ds._winds) <= 1


@pytest.mark.parametrize("kw, field", [(dict(ni=2), "ni"), (dict(nk=1), "nk"), (dict(days=0), "days")])
def test_bad_parameters(kw, field):
    with pytest.raises(DataError, match=field):
        SyntheticClimate(**kw)


def test_unknown_demo_size():
    with pytest.raises(DataError, match="demo:huge"):
        open_dataset("demo:huge")
