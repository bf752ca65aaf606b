import numpy as np
import pytest

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import EARTH_RADIUS, GlobeGrid, globe_radius, lonlat_to_xyz, xyz_to_lonlat
from nephele.core.errors import DataError


def small_grid(ni=8, nj=5, nk=3):
    lon = np.arange(ni) * 360.0 / ni
    lat = np.linspace(-80, 80, nj)
    h = np.linspace(0, 10000, nk)[:, None, None] + np.zeros((nk, nj, ni))
    return GlobeGrid(lon, lat, h)


def test_points_lie_at_exaggerated_radius():
    g = small_grid()
    p = g.points(radius=2.0, exaggeration=10.0, dtype=np.float64)
    r = np.linalg.norm(p, axis=-1)
    np.testing.assert_allclose(r, 2.0 * (1 + 10.0 * g.height / EARTH_RADIUS))
    lon, lat, _ = xyz_to_lonlat(p)
    np.testing.assert_allclose(np.mod(lon, 360)[0, 0], g.lon, atol=1e-9)
    np.testing.assert_allclose(lat[0, :, 0], g.lat, atol=1e-9)


def test_lonlat_roundtrip_and_poles():
    lon = np.array([-179.5, 0.0, 90.0, 179.0])
    lat = np.array([-90.0, 0.0, 45.0, 90.0])
    xyz = lonlat_to_xyz(lon, lat, globe_radius(1000.0))
    lon2, lat2, _ = xyz_to_lonlat(xyz)
    np.testing.assert_allclose(lat2, lat, atol=1e-12)
    np.testing.assert_allclose(lon2[1:3], lon[1:3], atol=1e-12)
    assert np.all(np.isfinite(lon2))


def test_periodic_detection():
    assert small_grid(ni=9).periodic_lon
    g = GlobeGrid(np.linspace(0, 90, 10), np.linspace(-10, 10, 3),
                  np.zeros((2, 3, 10)) + np.array([0, 1.0])[:, None, None])
    assert not g.periodic_lon


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(lon=[0, 10, 5]), "lon"),
        (dict(lat=[-95, 0, 10]), "lat"),
        (dict(lon=[0, np.nan, 20]), "lon"),
    ],
)
def test_validate_names_the_coordinate(kwargs, field):
    base = dict(lon=[0, 10, 20], lat=[-10, 0, 10], height=np.arange(2)[:, None, None] + np.zeros((2, 3, 3)))
    base.update(kwargs)
    with pytest.raises(DataError, match=field) as e:
        GlobeGrid(**base).validate(path="x.nc")
    assert "x.nc" in str(e.value)


def test_non_monotonic_levels_rejected():
    h = np.zeros((3, 3, 3))
    h[1] = 5.0
    h[2] = 4.0
    with pytest.raises(DataError, match="non-monotonic"):
        GlobeGrid([0, 10, 20], [-10, 0, 10], h).validate(path="f.nc")


def test_array_dataset_time_interpolation_and_errors():
    g = small_grid()
    a = np.stack([np.full(g.shape, float(t)) for t in range(4)])
    ds = ArrayDataset(g, hourly("2000-01-01", 4), {"cloud": a}, source="mem")
    np.testing.assert_allclose(ds.read_at("cloud", 1.25), 1.25)
    np.testing.assert_allclose(ds.read_at("cloud", 3.0), 3.0)
    with pytest.raises(DataError, match="outside the data range"):
        ds.read_at("cloud", 3.5)
    with pytest.raises(DataError, match="no such variable"):
        ds.read("rain", 0)
    assert ds.read("cloud", 2) is ds.read("cloud", 2)
