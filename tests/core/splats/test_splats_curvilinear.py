"""Splats on curvilinear (2-D latitude/longitude) and regional grids: shells, partition of unity, winds, streaks.

Grids: a Lambert conformal conic grid over North America, a north polar
stereographic grid with a column exactly at the pole, and a longitude/latitude
grid across the date line that does not close the circle (Snyder's spherical
inverses written out here, as in ``tests/core/flow/test_advect_curvilinear.py``),
50 km cells, shells stretched towards the ground.  Independent truth: the
weights are summed here by brute force (a k-d tree over the splat centres,
each splat's own axes and opacity, no index stencil); the winds of a rigid
rotation about any axis are ``ω × x`` (closed form).
"""

import numpy as np
import pytest
from projections import lcc_inverse, polar_inverse
from scipy.spatial import cKDTree

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import EARTH_RADIUS, GlobeGrid, lonlat_to_xyz
from nephele.core.splats import Camera, project_splats, splat_kernel, splat_samples
from nephele.core.splats.partition import shell_heights
from nephele.core.volume.transfer import TransferFunction

R = EARTH_RADIUS
EXAGGERATION = 30.0
ONE = TransferFunction(points=((0.0, 1.0),))
SHELLS = np.linspace(0.0, 1.0, 12) ** 1.4 * 20000.0  # stretched: 600 m at the ground, 2.5 km at the top


def regional_grid(kind, heights=SHELLS, terrain=None, nx=None, ny=None, dx=50e3):
    """Odd sizes on the polar grid put a column at the pole; ``terrain(lon2d, lat2d)`` lifts the
    lowest level and squeezes the others towards it (terrain-following)."""
    nx, ny = nx or (41 if kind == "polar" else 40), ny or (31 if kind == "polar" else 30)
    x, y = (np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx
    X, Y = np.meshgrid(x, y)
    lon, lat = lcc_inverse(X, Y) if kind == "lcc" else polar_inverse(X, Y)
    h = np.asarray(heights, dtype=np.float64)[:, None, None] + np.zeros((len(heights), ny, nx))
    if terrain is not None:
        top = h[-1]
        h = terrain(lon, lat)[None] + h / top * (top - terrain(lon, lat))[None]
    return GlobeGrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), h, lon2d=lon, lat2d=lat).validate()


def dataset(grid, **fields):
    shape = (1,) + grid.shape
    return ArrayDataset(grid, hourly("2000-01-01", 1), {k: np.broadcast_to(v, shape).copy() for k, v in fields.items()})


def trilinear(points, f):
    """Scene points at fractional indices ``f`` (m, 3) of a grid of ``points`` (nk, nj, ni, 3)."""
    b = np.floor(f).astype(int)
    fr = f - b
    x = np.zeros((len(f), 3))
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([fr[:, a] if c else 1 - fr[:, a] for a, c in enumerate(corner)], axis=0)
        x += w[:, None] * points[b[:, 0] + corner[0], b[:, 1] + corner[1], b[:, 2] + corner[2]]
    return x


def brute_sum(sp, kernel, x):
    """Σ opacity_s w_s(x): every splat whose cut-off ellipsoid can hold ``x`` (k-d tree over the
    centres, the largest semi-axis as the search radius), each with its own axes."""
    reach = np.linalg.norm(sp.axes, axis=1).max()
    inv = sp.radius * np.linalg.inv(sp.axes)
    out = np.zeros(len(x))
    for n, near in enumerate(cKDTree(sp.centers).query_ball_point(x, reach)):
        near = np.asarray(near, dtype=int)
        d = np.einsum("nij,nj->ni", inv[near], x[n] - sp.centers[near])
        out[n] = np.sum(sp.opacity[near] * kernel.weight(d))
    return out


@pytest.mark.parametrize("kind", ["lcc", "polar", "lonlat"])
def test_shells_on_regional_grids_are_a_partition_within_1e3(kind):
    # The default layout on a regional grid: shells at fixed heights, kernels from each sample's
    # own cell Jacobian, per-sample factors in the opacity ("lonlat": 1-D axes across the date
    # line that do not close the circle, the per-row factors).  Measured with the splats' own
    # axes and opacities at 3000 random points of the interior (3 cells from every edge, the
    # top and the ground), positions trilinear in the cells' corners.
    if kind == "lonlat":
        lon, lat = np.arange(160.0, 200.01, 0.5), np.arange(30.0, 60.01, 0.5)
        g = GlobeGrid(lon, lat, SHELLS[:, None, None] + np.zeros((SHELLS.size, lat.size, lon.size))).validate()
        assert not g.periodic_lon
    else:
        g = regional_grid(kind)
    kernel = splat_kernel()
    sp = splat_samples(dataset(g, cloud=1.0), "cloud", 0.0, ONE, kernel=kernel, exaggeration=EXAGGERATION)
    nk, nj, ni = g.shape
    assert len(sp) == g.height.size  # one splat per shell sample (flat ground: shells = levels)
    layout = g.points(1.0, EXAGGERATION, dtype=np.float64)
    rng = np.random.default_rng(0)
    f = np.column_stack([rng.uniform(3, n - 4, 3000) for n in (nk, nj, ni)])
    e = np.abs(brute_sum(sp, kernel, trilinear(layout, f)) - 1)
    plain = splat_samples(dataset(g, cloud=1.0), "cloud", 0.0, ONE, kernel=kernel, exaggeration=EXAGGERATION,
                          vertical="native")
    e_native = np.abs(brute_sum(plain, kernel, trilinear(layout, f)) - 1)
    low = f[:, 0] < 6
    print(f"{kind} on shells: worst |sum - 1| = {e.max():.2e}, median {np.median(e):.2e}, shells 3-6 worst "
          f"{e[low].max():.2e}; native (no widening, no factors) worst {e_native.max():.2e}, median "
          f"{np.median(e_native):.2e}")
    assert e.max() < 1e-3
    assert e_native.max() > 5e-3  # the factors are what makes it a partition
    if kind == "polar":  # the pole is a column, and inside the measured block
        pole = np.unravel_index(np.argmax(g.lat2d), g.lat2d.shape)
        assert g.lat2d[pole] == pytest.approx(90.0) and np.min(np.hypot(f[:, 1] - pole[0], f[:, 2] - pole[1])) < 0.5


def test_shells_sample_each_curvilinear_column_linearly_in_height():
    # A 2 km bump under the LCC grid (terrain-following levels), a field linear in height.
    bump = lambda lon, lat: 2000.0 * np.exp(-((lon + 100.0) ** 2 + (lat - 45.0) ** 2) / 8.0)  # noqa: E731
    g = regional_grid("lcc", heights=np.linspace(0.0, 12000.0, 7), terrain=bump)
    ds = dataset(g, cloud=g.height / 12000.0)
    shells = shell_heights(g)
    np.testing.assert_allclose(shells, np.linspace(0.0, 12000.0, 7), atol=1e-9)
    ident = TransferFunction(points=((0.0, 0.0), (1.0, 1.0)))
    sp = splat_samples(ds, "cloud", 0.0, ident, exaggeration=EXAGGERATION)
    k, j, i = sp.index.T
    above = shells[:, None, None] >= g.terrain[None]
    # One splat per shell sample above the ground with cloud > 0 (the lowest shell: the lowest ground, 1e-10 m).
    assert len(sp) == np.count_nonzero(above & (shells > 0)[:, None, None]) and np.all(above[k, j, i])
    # Centres on each column's own true position, at the shell's height.
    r = 1.0 + shells[k] * EXAGGERATION / R
    np.testing.assert_allclose(sp.centers, lonlat_to_xyz(g.lon2d[j, i], g.lat2d[j, i]) * r[:, None], rtol=0, atol=1e-12)
    # Opacity: the field at the shell height (exact: linear in height) times the sample's factor,
    # which is the same for a column wherever its cloud is: compare two fields.
    twice = splat_samples(dataset(g, cloud=0.5 * g.height / 12000.0), "cloud", 0.0, ident, exaggeration=EXAGGERATION)
    np.testing.assert_allclose(twice.opacity, 0.5 * sp.opacity, rtol=1e-6)
    factor = sp.opacity / (shells[k] / 12000.0)
    assert 0.4 < factor.min() and factor.max() < 1.2


def test_kernel_axes_come_from_each_samples_own_cell():
    g = regional_grid("polar", heights=np.linspace(0.0, 10000.0, 6))
    sp = splat_samples(dataset(g, cloud=1.0), "cloud", 0.0, ONE, exaggeration=EXAGGERATION, vertical="native")
    p = g.points(1.0, EXAGGERATION, dtype=np.float64)
    at = {tuple(ix): s for s, ix in enumerate(sp.index)}
    pole = np.unravel_index(np.argmax(g.lat2d), g.lat2d.shape)
    for k, j, i in [(2, *pole), (3, 5, 7), (2, 25, 34)]:
        s = at[(k, j, i)]
        for nb in [(k, j, i + 1), (k, j, i - 1), (k, j + 1, i), (k, j - 1, i), (k + 1, j, i), (k - 1, j, i)]:
            d = sp.cell_offsets(p[nb], s)[0]
            assert np.linalg.norm(d) == pytest.approx(1.0, abs=0.01)


def test_winds_and_streaks_follow_a_rigid_rotation_across_the_pole():
    # East/north winds (m/s) of a rotation about an equatorial axis, the flow crossing the pole:
    # the splats' scene winds are ω × centre (scene units per hour), on shells and natively,
    # and the streaks lie along the projected wind.
    g = regional_grid("polar", heights=np.linspace(0.0, 10000.0, 8))
    axis = lonlat_to_xyz(-30.0, 0.0)
    omega = 30.0 * 3600.0 / R  # rad/h: 30 m/s at the pole
    col = lonlat_to_xyz(g.lon2d, g.lat2d)
    vel = np.cross(axis, col) * (omega * R / 3600.0)
    lam, phi = np.deg2rad(g.lon2d), np.deg2rad(g.lat2d)
    east = np.stack([-np.sin(lam), np.cos(lam), 0 * lam], axis=-1)
    north = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], axis=-1)
    u, v = np.sum(vel * east, axis=-1), np.sum(vel * north, axis=-1)
    ds = dataset(g, cloud=1.0, u=u, v=v, w=0.0)
    for vertical in ("shells", "native"):
        sp = splat_samples(ds, "cloud", 0.0, ONE, exaggeration=EXAGGERATION, vertical=vertical)
        exact = omega * np.cross(axis, sp.centers)
        err = np.linalg.norm(sp.wind - exact, axis=1).max() / np.linalg.norm(exact, axis=1).max()
        print(f"rigid rotation winds ({vertical}): max relative error {err:.1e} over {len(sp)} splats")
        assert err < 1e-6  # u, v are stored as float32
    cam = Camera.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), orthographic=True, ortho_scale=0.5)
    scr = project_splats(sp, splat_kernel(), cam, 256, 256)
    c = sp.centers[scr.keep]
    a, _ = cam.project(c, 256, 256)
    b, _ = cam.project(c + 1e-3 * omega * np.cross(axis, c), 256, 256)
    expected = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
    moving = np.linalg.norm(b - a, axis=1) > 1e-6
    assert moving.sum() > 1000
    np.testing.assert_allclose(scr.wind_dir[moving], expected[moving], atol=1e-9)


def test_stride_on_a_curvilinear_grid():
    g = regional_grid("lcc", heights=np.linspace(0.0, 10000.0, 8))
    sp = splat_samples(dataset(g, cloud=1.0), "cloud", 0.0, ONE, exaggeration=EXAGGERATION, stride=2)
    assert len(sp) == 4 * 15 * 20 and np.all(sp.index % 2 == 0)
    k, j, i = sp.index.T
    np.testing.assert_allclose(sp.centers, g.points(1.0, EXAGGERATION, dtype=np.float64)[k, j, i], rtol=0, atol=1e-12)
    # The kernels span two cells: a strided neighbour lies at cell offset ~1.
    p = g.points(1.0, EXAGGERATION, dtype=np.float64)
    s = int(np.flatnonzero((sp.index == [2, 14, 20]).all(1))[0])
    for nb in [(2, 14, 22), (2, 16, 20), (4, 14, 20)]:
        assert 0.95 < np.linalg.norm(sp.cell_offsets(p[nb], s)[0]) < 1.05


def test_a_lambert_conformal_file_end_to_end(tmp_path):
    # A CF file as a regional model writes it (projection x/y, 2-D lat/lon, eastward/northward winds,
    # WRF's 6370 km sphere) through splat_samples and the renderer.
    xr = pytest.importorskip("xarray")
    from nephele.core.splats import render_splats, streak_maps

    radius = 6370000.0
    nx, ny, dx = 30, 24, 60e3
    x, y = (np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx
    X, Y = np.meshgrid(x, y)
    lon, lat = lcc_inverse(X * R / radius, Y * R / radius)  # Snyder's inverse on the file's sphere
    axis = lonlat_to_xyz(-100.0, 20.0)
    omega = 25.0 * 3600.0 / (radius * np.sin(np.deg2rad(25.0)))  # rad/h
    col = lonlat_to_xyz(lon, lat)
    vel = np.cross(axis, col) * (omega * radius / 3600.0)
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    u = np.sum(vel * np.stack([-np.sin(lam), np.cos(lam), 0 * lam], axis=-1), axis=-1)
    v = np.sum(vel * np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], axis=-1), axis=-1)
    z = np.array([1000.0, 3000.0, 6000.0, 9000.0])
    q = np.clip((lat - 38.0) / 14.0, 0.0, 1.0)[None] * np.array([0.2, 1.0, 0.6, 0.1])[:, None, None]  # a cloud band
    rep = lambda a: np.broadcast_to(a, (2, 4, ny, nx)).astype(np.float32)  # noqa: E731
    lcc = {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
           "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0, "earth_radius": radius}
    dims = ("time", "z", "y", "x")
    xr.Dataset(
        {"cloud": (dims, rep(q), {"units": "1", "grid_mapping": "lambert"}),
         "u": (dims, rep(u), {"units": "m s-1", "standard_name": "eastward_wind", "grid_mapping": "lambert"}),
         "v": (dims, rep(v), {"units": "m s-1", "standard_name": "northward_wind", "grid_mapping": "lambert"}),
         "lambert": ((), 0, lcc)},
        coords={"time": ("time", [0.0, 3.0], {"units": "hours since 2020-01-01", "standard_name": "time"}),
                "z": ("z", z, {"units": "m", "standard_name": "height", "positive": "up"}),
                "y": ("y", y, {"units": "m", "standard_name": "projection_y_coordinate"}),
                "x": ("x", x, {"units": "m", "standard_name": "projection_x_coordinate"}),
                "lat": (("y", "x"), lat, {"units": "degrees_north", "standard_name": "latitude"}),
                "lon": (("y", "x"), lon, {"units": "degrees_east", "standard_name": "longitude"})},
    ).to_netcdf(tmp_path / "lcc.nc")
    sp = splat_samples(str(tmp_path / "lcc.nc"), "cloud", 1.5, TransferFunction.ramp(0.05, 0.8), color_var="altitude",
                       exaggeration=EXAGGERATION)
    k, j, i = sp.index.T
    assert len(sp) > 1000 and np.all(np.isin(np.unique(k), np.arange(4)))
    np.testing.assert_allclose(sp.centers / np.linalg.norm(sp.centers, axis=1)[:, None], col[j, i], atol=1e-12)
    exact = omega * np.cross(axis, sp.centers)
    np.testing.assert_allclose(sp.wind, exact, rtol=0, atol=1e-6 * np.linalg.norm(exact, axis=1).max())
    centre = lonlat_to_xyz(-100.0, 45.0)
    cam = Camera.look_at(3.0 * centre, centre, fov=8.0)
    img = render_splats(sp, splat_kernel(), cam, 96, 96, streaks=streak_maps(4, 32), hours=1.5)
    alpha = img[..., 3]
    assert np.isfinite(img).all() and alpha.max() > 0.5 and (alpha > 0.01).mean() > 0.2


def test_factor_tiles_leave_the_partition_as_it_was(monkeypatch):
    # The per-sample factors are solved in tiles of columns with a halo; tiles of 12 columns
    # against the whole grid in one piece.  26 x 20 columns: the seams at i = 12 and j = 12 cross
    # the measured interior with a whole 8-column halo on both sides (measured 3.1e-4 and 3.0e-4;
    # 3.5e-4 and 3.2e-4 on the 38 x 28 grid this test used, at twice the cost: 10.5 CPU s).
    from nephele.core.splats import partition

    g = regional_grid("lcc", nx=26, ny=20)
    kernel = splat_kernel()
    nk, nj, ni = g.shape
    rng = np.random.default_rng(1)
    f = np.column_stack([rng.uniform(3, n - 4, 2000) for n in (nk, nj, ni)])
    x = trilinear(g.points(1.0, EXAGGERATION, dtype=np.float64), f)
    worst = {}
    for tile in (48, 12):
        monkeypatch.setattr(partition, "_TILE", tile)
        partition._curvilinear.cache_clear()
        sp = splat_samples(dataset(g, cloud=1.0), "cloud", 0.0, ONE, kernel=kernel, exaggeration=EXAGGERATION)
        worst[tile] = np.abs(brute_sum(sp, kernel, x) - 1).max()
    partition._curvilinear.cache_clear()
    print(f"tiles: worst |sum - 1| = {worst[12]:.2e} in 12-column tiles, {worst[48]:.2e} in one piece")
    assert worst[12] < 1e-3 and worst[48] < 1e-3
