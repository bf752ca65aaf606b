"""Backward trajectories against exact answers (solid-body rotation, Nair–Lauritzen case 4) and hard cases."""

import numpy as np
import pytest

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, lonlat_to_xyz, xyz_to_lonlat
from nephele.core.errors import DataError
from nephele.core.flow import advect, flows

TILT = np.pi / 2 - 0.05


def random_points(n=600, seed=0):
    rng = np.random.default_rng(seed)
    lon = rng.uniform(-180, 180, n)
    lat = np.rad2deg(np.arcsin(rng.uniform(-1, 1, n)))
    return lonlat_to_xyz(lon, lat)


def flat_grid(ni=16, nj=8, nk=4, top=10_000.0):
    lon = np.arange(ni) * 360.0 / ni
    lat = -90 + (np.arange(nj) + 0.5) * 180.0 / nj
    h = np.linspace(0, top, nk)[:, None, None] + np.zeros((nk, nj, ni))
    return GlobeGrid(lon, lat, h)


def wind_dataset(grid, nt=4, u=0.0, v=0.0, w=0.0):
    shape = (nt,) + grid.shape
    fields = {n: np.broadcast_to(np.asarray(val, dtype=np.float32), shape).copy()
              for n, val in (("u", u), ("v", v), ("w", w))}
    return ArrayDataset(grid, hourly("2000-01-01", nt), fields, source="test.nc")


@pytest.mark.parametrize("alpha", [0.0, TILT])
def test_solid_body_rotation_analytic_wind_is_exact(alpha):
    flow = flows.SolidBodyRotation(alpha)
    x = random_points()
    x0, _ = advect.trace(advect.AnalyticWind(flow), x, np.zeros(len(x)), 36.0, 0.0)
    err = advect.great_circle_km(x0, flow.exact_start(x, 36.0))
    assert err.max() < 1e-3


@pytest.mark.parametrize("alpha", [0.0, TILT, np.pi / 2])
def test_solid_body_rotation_sampled_wind_within_data_floor(alpha):
    # The same wind read hourly from the 320x160 grid: the error is the data
    # interpolation's, a small fraction of a 125 km cell (pole crossings included).
    flow = flows.SolidBodyRotation(alpha)
    ds = flows.FlowDataset(flow, hours=13)
    x = random_points(400)
    pole = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], lonlat_to_xyz(179.9, 0.0)])
    x = np.concatenate([x, pole])
    x0, _ = advect.trace(advect.WindField(ds), x, np.zeros(len(x)), 12.0, 0.0)
    err = advect.great_circle_km(x0, flow.exact_start(x, 12.0))
    assert np.all(np.isfinite(x0))
    assert err.max() < 12.5  # a tenth of a grid cell
    assert np.sqrt(np.mean(err**2)) < 3.0


def test_points_cross_the_seam_and_the_pole():
    # alpha = pi/2: the wind blows along meridians through both poles.
    flow = flows.SolidBodyRotation(np.pi / 2)
    ds = flows.FlowDataset(flow, hours=13)
    start = lonlat_to_xyz(np.array([-90.0, 179.0]), np.array([80.0, 0.0]))
    # Where these points are 12 h later (a quarter turn): over the pole, and across the seam.
    later = flow.exact_start(start, -12.0)
    lon_s, lat_s, _ = xyz_to_lonlat(start)
    lon_l, lat_l, _ = xyz_to_lonlat(later)
    assert abs(lon_l[0] - lon_s[0]) > 90  # went over the pole to the other side
    x0, _ = advect.trace(advect.WindField(ds), later, np.zeros(2), 12.0, 0.0)
    assert advect.great_circle_km(x0, start).max() < 12.5
    # across the seam with a zonal flow
    zonal = flows.SolidBodyRotation(0.0)
    p = lonlat_to_xyz(np.array([-179.0]), np.array([10.0]))
    x0, _ = advect.trace(advect.WindField(flows.FlowDataset(zonal, hours=4)), p, [0.0], 3.0, 0.0)
    lon0, _, _ = xyz_to_lonlat(x0)
    assert lon0[0] > 170  # started west of the seam, at +172.4
    assert advect.great_circle_km(x0, zonal.exact_start(p, 3.0)).max() < 12.5


def test_deformational_flow_returns_home_and_orders():
    flow = flows.DeformationalFlow()
    wind = advect.AnalyticWind(flow)
    x = random_points(300)
    errs = {}
    for m in advect.METHODS:
        x0, _ = advect.trace(wind, x, np.zeros(len(x)), flow.period_hours, 0.0, method=m)
        errs[m] = advect.great_circle_km(x0, flow.exact_start(x, flow.period_hours)).max()
    assert errs["rk4"] < 0.01
    assert errs["rk2"] < errs["euler"] / 20
    assert errs["rk4"] < errs["rk2"] / 20


def test_zero_wind_keeps_points_and_texture_fixed():
    from nephele.core.texture.fractal import texture

    g = flat_grid()
    wind = advect.WindField(wind_dataset(g, nt=6))
    x = random_points(50)
    s = np.linspace(0, 3, 50)
    x0, s0 = advect.trace(wind, x, s, 5.0, 0.0)
    np.testing.assert_allclose(x0, x, atol=1e-14)
    np.testing.assert_allclose(s0, s)
    lon, lat, _ = xyz_to_lonlat(x)
    lon0, lat0, _ = xyz_to_lonlat(x0)
    np.testing.assert_allclose(texture(lon0, lat0, 1000.0), texture(lon, lat, 1000.0), atol=1e-12)


@pytest.mark.parametrize("w,bound", [(5.0, 0.0), (-5.0, 3.0)])
def test_vertical_wind_leaving_the_domain_is_clamped(w, bound):
    # 5 m/s for 3 h is 54 km: far beyond a 10 km column.  Backwards, rising air came from below.
    g = flat_grid(nk=4)
    wind = advect.WindField(wind_dataset(g, w=w))
    x = random_points(20)
    _, s0 = advect.trace(wind, x, np.full(20, 1.5), 3.0, 0.0)
    np.testing.assert_allclose(s0, bound)
    # a moderate wind moves points by the expected number of levels: 0.1 m/s * 3 h = 1080 m, levels 3333 m apart
    wind = advect.WindField(wind_dataset(g, w=0.1))
    _, s1 = advect.trace(wind, x, np.full(20, 1.5), 3.0, 0.0)
    np.testing.assert_allclose(s1, 1.5 - 1080.0 / (10_000.0 / 3), rtol=1e-6)


def test_terrain_following_levels_rate():
    # Level heights rise eastward: horizontal wind at constant height must climb down the levels.
    g0 = flat_grid(ni=32, nj=8, nk=3)
    lam = np.deg2rad(g0.lon)
    h = g0.height + 1000.0 * (1 + np.sin(lam))[None, None, :] * np.array([1.0, 0.5, 0.0])[:, None, None]
    g = GlobeGrid(g0.lon, g0.lat, h)
    wind = advect.WindField(wind_dataset(g, u=10.0))
    xyz = lonlat_to_xyz(np.array([0.0]), np.array([0.0]))
    v, sdot = wind.velocity(0.0, xyz, np.array([1.0]))
    # at lon 0, level 1: dh/dx = 0.5*1000*cos(0)/R, dh/ds = (10000 - 0)/2 - ... computed from the grid
    dhds = (h[2] - h[0])[4, 0] / 2
    expect = -10.0 * 0.5 * 1000.0 / 6_371_000.0 * 3600 / dhds
    assert sdot[0] == pytest.approx(expect, rel=0.05)


def test_time_outside_data_range_is_a_data_error():
    g = flat_grid()
    wind = advect.WindField(wind_dataset(g, nt=4))
    x = random_points(3)
    with pytest.raises(DataError, match="outside the data range"):
        advect.trace(wind, x, np.zeros(3), 5.0, 0.0)
    with pytest.raises(DataError, match="outside"):
        advect.trace(wind, x, np.zeros(3), 2.0, -1.0)


def test_nan_wind_is_an_error_or_calm():
    g = flat_grid()
    ds = wind_dataset(g, u=10.0)
    ds._fields["u"][1, 0, 0, 0] = np.nan
    with pytest.raises(DataError, match=r"test.nc: field 'u': has 1 NaN.*step 1"):
        advect.trace(advect.WindField(ds), random_points(5), np.zeros(5), 2.0, 0.0)
    x0, _ = advect.trace(advect.WindField(ds, nan="zero"), random_points(5), np.zeros(5), 2.0, 0.0)
    assert np.all(np.isfinite(x0))


def test_huge_winds_take_cfl_substeps():
    # A 6-hour solid-body period: ~1850 m/s at the equator, 15 grid cells per hour.
    flow = flows.SolidBodyRotation(0.3, period_hours=6.0)
    ds = flows.FlowDataset(flow, hours=7, grid=flows.sample_grid(64, 32))
    x = random_points(100)
    x0, _ = advect.trace(advect.WindField(ds), x, np.zeros(100), 6.0, 0.0)
    err = advect.great_circle_km(x0, flow.exact_start(x, 6.0))
    # a whole turn (40 000 km) on 625 km cells: data interpolation error only; hourly steps (60° each) are 3x worse
    assert err.max() < 100
    x1, _ = advect.trace(advect.WindField(ds), x, np.zeros(100), 6.0, 0.0, cfl=100.0)
    assert advect.great_circle_km(x1, flow.exact_start(x, 6.0)).max() > 2 * err.max()  # 60° per RK4 step


def test_active_vertices_match_brute_force():
    rng = np.random.default_rng(1)
    v = rng.uniform(0, 1, (3, 5, 6))
    v[1, 2, 3] = np.nan
    v[0, 0, 0] = 0.5
    for periodic in (False, True):
        got = set(advect.active_vertices(v, 0.5, periodic_lon=periodic))
        want = set()
        nk, nj, ni = v.shape
        for k in range(nk - 1):
            for j in range(nj - 1):
                for i in range(ni if periodic else ni - 1):
                    corners = [(k + a, j + b, (i + c) % ni) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
                    vals = np.array([v[p] for p in corners])
                    if np.all(np.isfinite(vals)) and vals.min() <= 0.5 <= vals.max():
                        want.update(np.ravel_multi_index(p, v.shape) for p in corners)
        assert got == want


def test_strategies_agree_on_solid_body_rotation():
    flow = flows.SolidBodyRotation(TILT)
    grid = flows.sample_grid(64, 32)
    wind = advect.WindField(flows.FlowDataset(flow, hours=9, grid=grid))
    fh = np.arange(9.0)
    idx = np.arange(0, 64 * 32, 7)
    xyz = advect.grid_vertices(grid, idx)
    exact = flow.exact_start(xyz, 8.0)
    full = advect.FullTrace(wind, fh, grid).copies(8, idx)
    assert len(full) == 1 and full[0].weight == 1.0 and full[0].start_hours == 0.0
    e_full = advect.great_circle_km(full[0].xyz, exact)
    assert e_full.max() < 60  # coarse 64x32 grid (625 km cells)
    for band in (None, 4):
        comp = advect.ComposedTrace(wind, fh, grid, band=band)
        for n in range(9):  # streamed in order
            c = comp.copies(n, idx)
        e_comp = advect.great_circle_km(c[0].xyz, exact)
        assert e_comp.max() < e_full.max() + 30
    # asked for an earlier frame, the composed strategy restarts from frame 0 and agrees with a direct trace
    back = comp.copies(1, idx)[0]
    np.testing.assert_allclose(back.xyz, advect.FullTrace(wind, fh, grid).copies(1, idx)[0].xyz, atol=1e-6)


def test_composed_bilinear_smears_more_than_cubic():
    flow = flows.DeformationalFlow(period_hours=24.0)
    grid = flows.sample_grid(64, 32)
    wind = advect.AnalyticWind(flow, min_spacing=np.deg2rad(5.625))
    fh = np.arange(25.0)
    idx = np.arange(64 * 32)
    xyz = advect.grid_vertices(grid, idx)
    errs = {}
    for order in (1, 3):
        comp = advect.ComposedTrace(wind, fh, grid, order=order, band="all")
        for n in range(25):
            c = comp.copies(n, idx)[0]
        errs[order] = advect.great_circle_km(c.xyz, xyz).max()  # back home at T
    assert errs[3] < errs[1] / 3


def test_band_falls_back_to_direct_trace_outside_the_band():
    # Ask for a different patch each frame: its stencil is never in the band, so
    # every vertex is traced directly, and the answer equals the full trace.
    flow = flows.SolidBodyRotation(0.0)
    grid = flows.sample_grid(64, 32)
    wind = advect.WindField(flows.FlowDataset(flow, hours=5, grid=grid))
    fh = np.arange(5.0)
    comp = advect.ComposedTrace(wind, fh, grid, band=1)
    for n in range(5):
        idx = np.array([n * 10 + 16 * 64])
        c = comp.copies(n, idx)[0]
    assert comp.stream.fallbacks >= 1
    np.testing.assert_allclose(c.xyz, advect.FullTrace(wind, fh, grid).copies(4, idx)[0].xyz, atol=1e-6)


@pytest.mark.parametrize("incremental", [False, True])
def test_restart_weights_and_restarts(incremental):
    g = flat_grid()
    wind = advect.WindField(wind_dataset(g, nt=30, u=20.0))
    r = advect.RestartTrace(wind, np.arange(30.0), g, period=8, incremental=incremental)
    for n in range(30):
        wa, wb = r.weights(n)
        assert wa + wb == pytest.approx(1.0) and 0 <= wa <= 1
        a, b = r.restarts(n)
        assert 0 <= n - a < 8 and 0 <= n - b < 8 and a % 8 == 0
    assert r.weights(8) == (0.0, 1.0) and r.weights(4) == (1.0, 0.0)
    idx = np.arange(0, g.shape[0] * 16 * 8, 5)
    for n in range(9):
        copies = r.copies(n, idx)
    x = advect.grid_vertices(g, idx)
    np.testing.assert_allclose(copies[0].xyz, x, atol=1e-6)  # copy A restarts at frame 8: start = here, weight 0
    assert copies[0].weight == 0.0 and copies[1].start_hours == 4.0
    # copy B started at frame 4: 4 h of 20 m/s eastward wind
    direct, _ = advect.trace(wind, x, advect.vertex_levels(g, idx), 8.0, 4.0)
    np.testing.assert_allclose(copies[1].xyz, direct, atol=2e-3)
    with pytest.raises(ValueError):
        advect.RestartTrace(wind, np.arange(30.0), g, period=7)


def test_start_height_and_bad_inputs():
    g = flat_grid(nk=4)
    wind = advect.WindField(wind_dataset(g))
    x = random_points(5)
    c = advect.Copy(x, np.full(5, 1.5), 1.0, 0.0)
    lon, lat, alt = advect.start_coordinates(wind, c)
    np.testing.assert_allclose(alt, 5000.0)
    with pytest.raises(ValueError):
        advect.trace(wind, x, np.zeros(4), 1.0, 0.0)
    with pytest.raises(ValueError):
        advect.trace(wind, x, np.zeros(5), 1.0, 0.0, method="rk5")
    with pytest.raises(DataError, match="field 'v'"):
        advect.WindField(ArrayDataset(g, hourly("2000-01-01", 2), {"u": np.zeros((2,) + g.shape)}, source="x.nc"))


def test_vertical_levels_mode_keeps_levels():
    g = flat_grid(nk=4)
    x = random_points(10)
    wind = advect.WindField(wind_dataset(g, u=5.0, w=0.3), vertical="levels")
    _, s0 = advect.trace(wind, x, np.full(10, 1.5), 3.0, 0.0)
    np.testing.assert_allclose(s0, 1.5)
    with pytest.raises(ValueError):
        advect.WindField(wind_dataset(g), vertical="up")


def test_vertical_auto_follows_the_dataset():
    from nephele.core.climate.synthetic import demo_dataset

    g = flat_grid(nk=4)
    assert advect.WindField(wind_dataset(g, u=5.0, w=0.3)).vertical == "w"
    assert advect.WindField(demo_dataset("small")).vertical == "levels"  # the demo's air rides its levels
    assert advect.WindField(demo_dataset("small"), vertical="w").vertical == "w"


def test_read_ahead_gives_the_same_traces_and_reads_the_next_step():
    from nephele.core.climate.synthetic import demo_dataset

    def run(read_ahead):
        ds = demo_dataset("small")
        wind = advect.WindField(ds, vertical="w", read_ahead=read_ahead, cache_steps=12)
        st = advect.RestartTrace(wind, ds.hours, ds.grid, period=4, cfl=2.0)
        out = []
        for n in range(1, 7):
            idx = advect.active_vertices(ds.read("cloud", n), 0.15, True)
            out.append([c.xyz.copy() for c in st.copies(n, idx)])
            if read_ahead:
                # The step after the newest one used is read in the background.
                assert set(wind._pending) | set(wind._steps) >= {n + 1}
        return out

    with_thread, without = run(True), run(False)
    for a, b in zip(with_thread, without):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


def test_dataset_reads_from_two_threads_match_serial_reads():
    from concurrent.futures import ThreadPoolExecutor

    from nephele.core.climate.synthetic import demo_dataset

    keys = [(name, t) for t in range(6) for name in ("u", "w", "cloud")]
    serial = [demo_dataset("small", seed=3).read(*k).copy() for k in keys]
    ds = demo_dataset("small", seed=3)
    ds._cache_steps = 2  # evictions while the other thread reads
    with ThreadPoolExecutor(2) as ex:
        threaded = list(ex.map(lambda k: ds.read(*k).copy(), keys))
    for a, b in zip(serial, threaded):
        np.testing.assert_array_equal(a, b)
