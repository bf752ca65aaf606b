"""One splat per sample: selection, geometry from the cell Jacobian, colour, wind, bad input."""

import numpy as np
import pytest

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import EARTH_RADIUS, GlobeGrid
from nephele.core.climate.synthetic import demo_dataset
from nephele.core.errors import DataError
from nephele.core.splats import splat_kernel, splat_samples
from nephele.core.volume.transfer import ALTITUDE_COLORS, TransferFunction

TF = TransferFunction.ramp(0.15, 0.6)


@pytest.fixture(scope="module")
def small():
    return demo_dataset("small")


def test_one_splat_per_sample_above_the_threshold(small):
    sp = splat_samples(small, "cloud", 5.0, TF, color_var="altitude", vertical="native")
    cloud = small.read_at("cloud", 5.0)
    expected = np.count_nonzero(TF(cloud) > 0)
    assert len(sp) == expected > 100
    k, j, i = sp.index.T
    assert np.allclose(sp.opacity, TF(cloud[k, j, i]), atol=1e-6)
    assert np.allclose(sp.centers, small.grid.points(1.0, 30.0, dtype=np.float64)[k, j, i], atol=1e-12)
    assert np.allclose(sp.color, ALTITUDE_COLORS(small.grid.height[k, j, i]), atol=1e-6)
    assert len(splat_samples(small, "cloud", 5.0, TF, threshold=0.5,
                             vertical="native")) == np.count_nonzero(TF(cloud) > 0.5)


def test_axes_are_the_cells_principal_axes(small):
    kern = splat_kernel()
    sp = splat_samples(small, "cloud", 0.0, TF, kernel=kern, vertical="native")
    a = sp.axes
    gram = np.einsum("nji,njk->nik", a, a)
    off = gram - np.einsum("nii->ni", gram)[:, :, None] * np.eye(3)
    assert np.abs(off).max() < 1e-12 and np.all(np.linalg.det(a) > 0)
    # |det M| = R³ |det J|, and the semi-axes span the cell's neighbours: a sample away from
    # the edges has its neighbours one lon/lat/level step away at cell offset ~1.
    p = small.grid.points(1.0, 30.0, dtype=np.float64)
    s = int(np.flatnonzero((sp.index[:, 0] == 3) & (sp.index[:, 1] > 2) & (sp.index[:, 1] < 29))[0])
    k, j, i = sp.index[s]
    for nb in [(k, j, (i + 1) % 64), (k, j + 1, i), (k + 1, j, i), (k, j, (i - 1) % 64)]:
        d = sp.cell_offsets(p[nb], s)[0]
        assert 0.85 < np.linalg.norm(d) < 1.15


def test_stride_grows_the_kernels(small):
    one = splat_samples(small, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), vertical="native")
    two = splat_samples(small, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), stride=2, vertical="native")
    assert len(one) == 8 * 32 * 64 and len(two) == 4 * 16 * 32
    # Same sample (0, 10, 20): the Jacobian's columns are differences over two grid steps.
    p = small.grid.points(1.0, 30.0, dtype=np.float64)
    jac = np.column_stack([(p[0, 10, 22] - p[0, 10, 18]) / 2, (p[0, 12, 20] - p[0, 8, 20]) / 2,
                           p[2, 10, 20] - p[0, 10, 20]])
    a2 = two.axes[np.flatnonzero((two.index == [0, 10, 20]).all(1))[0]]
    assert np.linalg.det(a2) == pytest.approx(2.5**3 * abs(np.linalg.det(jac)), rel=1e-9)


def uniform_dataset(u=0.0, v=0.0, w=0.0, cloud=1.0):
    lon = np.arange(0, 360, 10.0)
    lat = np.arange(-60, 61, 10.0)
    h = np.broadcast_to(np.array([0.0, 2000.0, 4000.0])[:, None, None], (3, lat.size, lon.size)).copy()
    g = GlobeGrid(lon, lat, h)
    shape = (1,) + g.shape
    fields = {"cloud": np.full(shape, cloud), "u": np.full(shape, u), "v": np.full(shape, v), "w": np.full(shape, w)}
    return ArrayDataset(g, hourly("2000-01-01", 1), fields)


def test_wind_in_scene_units_per_hour():
    sp = splat_samples(uniform_dataset(u=10.0), "cloud", 0.0, TF)
    r = np.linalg.norm(sp.centers, axis=1)
    speed = np.linalg.norm(sp.wind, axis=1)
    assert np.allclose(speed, 10.0 * 3600 / EARTH_RADIUS * r, rtol=1e-12)
    assert np.allclose(sp.wind[:, 2], 0.0, atol=1e-15)  # eastward: no z component
    assert np.allclose(np.einsum("ij,ij->i", sp.wind, sp.centers), 0.0, atol=1e-15)
    # Eastward = counter-clockwise seen from the north pole: cross(centre, wind) points north.
    assert np.all(np.cross(sp.centers, sp.wind)[:, 2] > 0)
    up = splat_samples(uniform_dataset(w=0.5), "cloud", 0.0, TF, exaggeration=20.0)
    radial = np.einsum("ij,ij->i", up.wind, up.centers / np.linalg.norm(up.centers, axis=1)[:, None])
    assert np.allclose(radial, 0.5 * 3600 * 20.0 / EARTH_RADIUS, rtol=1e-12)


def test_full_demo_gives_about_1e5_splats():
    sp = splat_samples("demo", "cloud", 12.0, TransferFunction.ramp(0.3, 0.8), color_var="altitude")
    print(f"full demo, ramp 0.3..0.8 at 12 h: {len(sp)} splats")
    assert 5e4 < len(sp) < 3e5


def test_real_grads_file(shared_data):
    path = shared_data / "climate" / "model.ctl"
    sp = splat_samples(str(path), "rh", 24.0, TransferFunction.ramp(0.7, 1.0), color_var="temperature")
    assert len(sp) > 100 and np.all(np.isfinite(sp.wind)) and np.linalg.norm(sp.wind, axis=1).max() > 0
    assert np.all(sp.opacity > 0)


def test_nan_samples_are_transparent():
    ds = uniform_dataset()
    cloud = np.ones((1,) + ds.grid.shape)
    cloud[0, 1, 5, 7] = np.nan
    nan_ds = ArrayDataset(ds.grid, ds.times, {"cloud": cloud})
    sp = splat_samples(nan_ds, "cloud", 0.0, TF, vertical="native")
    assert len(sp) == cloud.size - 1 and not (sp.index == [1, 5, 7]).all(1).any()
    assert np.all(sp.wind == 0)  # no wind fields: calm


def test_bad_input_raises_one_line_data_error(small, tmp_path):
    bad_wind = uniform_dataset(u=np.nan)
    calls = [
        lambda: splat_samples(small, "nope", 0.0, TF),
        lambda: splat_samples(small, "cloud", 0.0, "ramp"),
        lambda: splat_samples(small, "cloud", 99.0, TF),
        lambda: splat_samples(small, "cloud", 0.0, TF, exaggeration=-1),
        lambda: splat_samples(small, "cloud", 0.0, TF, stride=0),
        lambda: splat_samples(small, "cloud", 0.0, TF, threshold=np.nan),
        lambda: splat_samples(small, "cloud", 0.0, TF, kernel="gaussian"),
        lambda: splat_samples(str(tmp_path / "missing.nc"), "cloud", 0.0, TF),
        lambda: splat_samples(42, "cloud", 0.0, TF),
        lambda: splat_samples(bad_wind, "cloud", 0.0, TF),
    ]
    for call in calls:
        with pytest.raises(DataError) as e:
            call()
        assert "\n" not in str(e.value)


def test_seam_poles_threshold_and_empty(small):
    one = TransferFunction(points=((0.0, 1.0),))
    sp = splat_samples(small, "cloud", 0.0, one, vertical="native")
    by_index = {tuple(i): a for i, a in zip(sp.index, sp.axes)}
    # Across the seam (lon 0 and the last column) the ellipsoids match as elsewhere (top level: no terrain).
    def size(a):
        return np.sort(np.linalg.norm(a, axis=0))

    seam = np.abs(size(by_index[(7, 16, 0)]) - size(by_index[(7, 16, 63)])).max()
    assert seam < 1e-6 * size(by_index[(7, 16, 0)])[2]  # a one-sided seam would differ by ~1e-3
    # Next to the poles: finite, invertible, narrow in longitude.
    for j in (0, 31):
        a = by_index[(2, j, 5)]
        assert np.all(np.isfinite(a)) and abs(np.linalg.det(a)) > 0
        assert size(a)[0] < 0.2 * size(by_index[(2, 16, 5)])[1]
    # Opacity exactly at the threshold is not kept; a transparent transfer function gives none.
    cloud = small.read_at("cloud", 0.0)
    ramp = TransferFunction.ramp(0.2, 0.7)
    at = float(ramp(cloud).flat[np.argmax(ramp(cloud) > 0.1)])
    kept = splat_samples(small, "cloud", 0.0, ramp, threshold=at)
    assert np.all(kept.opacity > at)
    none = splat_samples(small, "cloud", 0.0, TransferFunction(points=((0.0, 0.0),)))
    assert len(none) == 0 and none.axes.shape == (0, 3, 3)


def test_real_netcdf_file_without_winds(shared_data):
    # ECHAM5 pressure levels with relative humidity but no u/v: splats without wind (calm streaks).
    path = shared_data / "climate" / "rectilinear_grid_3D.nc"
    sp = splat_samples(str(path), "rh", 0.0, TransferFunction.ramp(0.8, 1.0), color_var="temperature", stride=2)
    assert len(sp) > 100 and np.all(sp.wind == 0)
    assert np.all(np.linalg.det(sp.axes) > 0) and np.all(np.isfinite(sp.color))


def terrain_dataset():
    """Terrain-following levels over a 3 km ridge, a field linear in height, uniform wind."""
    lon = np.arange(0, 360, 10.0)
    lat = np.arange(-60, 61, 10.0)
    ridge = 3000.0 * np.exp(-((lon[None, :] - 180.0) / 30.0) ** 2) * np.ones((lat.size, 1))
    eta = np.linspace(0.0, 1.0, 6)
    h = eta[:, None, None] * 10000.0 + (1 - eta[:, None, None]) ** 2 * ridge[None]
    g = GlobeGrid(lon, lat, h)
    shape = (1,) + g.shape
    fields = {"cloud": (h / 10000.0)[None], "u": np.full(shape, 5.0), "v": np.zeros(shape), "w": np.zeros(shape)}
    return ArrayDataset(g, hourly("2000-01-01", 1), fields)


def test_shells_sample_each_column_linearly_in_height():
    from nephele.core.splats.partition import ShellSampler, shell_factors, shell_heights

    ds = terrain_dataset()
    g = ds.grid
    shells = shell_heights(g)
    assert np.allclose(shells, np.linspace(0.0, 10000.0, 6))  # the levels over flat ground
    vals = ShellSampler(g, shells)(ds.read_at("cloud", 0.0))
    below = shells[:, None, None] < g.terrain[None]
    assert np.all(np.isnan(vals[below]))
    assert np.allclose(vals[~below], np.broadcast_to(shells[:, None, None] / 1e4, vals.shape)[~below], atol=1e-12)
    ident = TransferFunction(points=((0.0, 0.0), (1.0, 1.0)))
    sp = splat_samples(ds, "cloud", 0.0, ident, color_var="altitude")
    k, j, i = sp.index.T
    # One splat per shell sample above the ground with cloud > 0.
    assert len(sp) == np.count_nonzero(np.nan_to_num(vals) > 0) > 0.7 * vals.size
    r = np.linalg.norm(sp.centers, axis=1)
    assert np.allclose(r, 1.0 + shells[k] * 30.0 / EARTH_RADIUS, rtol=0, atol=1e-12)
    assert np.allclose(sp.color, ALTITUDE_COLORS(shells[k]), atol=1e-6)
    factors = shell_factors(g.lat, shells, 10.0, 30.0, splat_kernel())
    assert np.allclose(sp.opacity, (shells[k] / 1e4 * factors[k, j]).astype(np.float32), rtol=1e-6)
    assert np.allclose(np.linalg.norm(sp.wind, axis=1), 5.0 * 3600 / EARTH_RADIUS * r, rtol=1e-9)
    # The native layout keeps one splat per grid sample on the terrain-following levels.
    native = splat_samples(ds, "cloud", 0.0, ident, vertical="native")
    assert len(native) == np.count_nonzero(g.height > 0)


def test_shell_kernels_widen_towards_the_poles_and_with_stretched_levels():
    from nephele.core.splats.partition import widening

    lat = np.arange(-89.5, 90, 1.0)
    lam_lon, lam_lev = widening(lat, np.arange(10) ** 1.5 * 1000.0, 2.5)
    assert lam_lon.min() == 1.0 and lam_lon[0] == lam_lon.max() > 5  # 2.5 rows from the pole row
    eq = np.abs(lat) < 45
    assert np.all(lam_lon[eq] < 1.05)
    assert np.all(np.diff(lam_lev[:-3]) < 0) and lam_lev[-1] == 1.0  # spacing grows upwards
    _, even = widening(lat, np.linspace(0, 9000.0, 10), 2.5)
    assert np.allclose(even, 1.0)


def test_shells_bad_input_raises_one_line_data_error(small):
    ds = terrain_dataset()
    uneven = ArrayDataset(
        GlobeGrid(np.r_[0.0, 5.0, np.arange(20, 360, 10.0)], ds.grid.lat,
                  np.broadcast_to(ds.grid.height[:, :, :1], (6, 13, 36)).copy()),
        ds.times, {"cloud": np.ones((1, 6, 13, 36))},
    )
    for call in (
        lambda: splat_samples(ds, "cloud", 0.0, TF, vertical="terrain"),
        lambda: splat_samples(ds, "cloud", 0.0, TF, shells=[0.0, 5000.0, 3000.0]),
        lambda: splat_samples(ds, "cloud", 0.0, TF, shells=[np.nan, 1.0]),
        lambda: splat_samples(uneven, "cloud", 0.0, TF),
    ):
        with pytest.raises(DataError) as e:
            call()
        assert "\n" not in str(e.value)
