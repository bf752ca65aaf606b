"""Winds on curvilinear (2-D latitude/longitude, regional) grids through WindField, trace and the strategies.

Independent truth: the trajectories of a rigid rotation about any axis are
rotations (closed form), and those of the Nair & Lauritzen deformational flow
are integrated here with scipy's DOP853 at rtol 1e-11 straight from the
analytic winds.  Grids: a Lambert conformal conic grid over North America
(Snyder's spherical inverse written out here), the same grid centred on the
date line, and a polar stereographic grid with a column exactly at the north
pole.  The winds are stored as a file would hold them: east/north components
(m/s) at every column, computed from the analytic flow.
"""

import numpy as np
import pytest
from projections import lcc_inverse, polar_inverse
from scipy.integrate import solve_ivp

from nephele.core.climate.columns import ColumnLocator
from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, lonlat_to_xyz, xyz_to_lonlat
from nephele.core.errors import DataError
from nephele.core.flow import advect
from nephele.core.flow.flows import DeformationalFlow, rotate, tangent_velocity

R = 6_371_000.0
HOURS = 25


def regional_grid(kind, nx=40, ny=30, dx=50e3, heights=(0.0, 5000.0, 10000.0)):
    x, y = (np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx
    X, Y = np.meshgrid(x, y)
    lon, lat = {"lcc": lambda: lcc_inverse(X, Y), "dateline": lambda: lcc_inverse(X, Y, lon0=180.0),
                "polar": lambda: polar_inverse(X, Y)}[kind]()
    h = np.asarray(heights)[:, None, None] + np.zeros((len(heights), ny, nx))
    return GlobeGrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), h, lon2d=lon, lat2d=lat).validate()


def east_north(lon, lat):
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    e = np.stack([-np.sin(lam), np.cos(lam), np.zeros_like(lam)], axis=-1)
    n = np.stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)], axis=-1)
    return e, n


def wind_dataset(grid, uv_of_hour, nt=HOURS, w=None):
    """u, v (and w, default 0) from ``uv_of_hour(hours) -> (u, v)`` (nj, ni) at every hourly step."""
    nk = grid.shape[0]
    u, v = (np.stack([np.broadcast_to(uv_of_hour(float(t))[c], (nk,) + grid.shape[1:]) for t in range(nt)])
            for c in (0, 1))
    ds = ArrayDataset(grid, hourly("2000-01-01", nt), {"u": u, "v": v, "w": np.zeros_like(u) if w is None else w},
                      source="<regional test>", units={"u": "m/s", "v": "m/s", "w": "m/s"})
    ds.earth_radius = R
    return ds


def rotation_winds(grid, axis, omega):
    """East/north winds (m/s) of the rigid rotation ``omega`` (radians per hour) about ``axis`` at the columns."""
    p = lonlat_to_xyz(grid.lon2d, grid.lat2d)
    vel = np.cross(axis, p) * (omega * R / 3600.0)
    e, n = east_north(grid.lon2d, grid.lat2d)
    return np.sum(vel * e, axis=-1), np.sum(vel * n, axis=-1)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


# Axes: a vortex centred south of the LCC grid; for the polar grid an axis on the equator, so the flow crosses the pole.
CASES = {"lcc": (lonlat_to_xyz(-100.0, 20.0), 25.0), "dateline": (lonlat_to_xyz(180.0, 20.0), 25.0),
         "polar": (lonlat_to_xyz(-30.0, 0.0), 90.0)}


def inside_all_along(loc, paths):
    """Points whose positions ``paths`` (m, n, 3) all lie inside the grid."""
    return np.all([loc(p)[0] >= 0 for p in paths], axis=0)


@pytest.mark.parametrize("kind", ["lcc", "dateline", "polar"])
def test_rigid_rotation_traces_match_the_closed_form(kind):
    g = regional_grid(kind, nx=41, ny=31) if kind == "polar" else regional_grid(kind)  # odd sizes: a column at the pole
    axis, away = CASES[kind]
    axis = unit(axis)
    omega = 30.0 * 3600.0 / (R * np.sin(np.deg2rad(away)))  # 30 m/s at the grid's centre
    uv = rotation_winds(g, axis, omega)
    wind = advect.WindField(wind_dataset(g, lambda t: uv))
    if kind == "polar":  # the pole is a column of the grid, and crossed by the flow
        assert np.isclose(g.lat2d.max(), 90.0)
    loc = ColumnLocator(g.lon2d, g.lat2d)
    idx = np.random.default_rng(0).integers(0, np.prod(g.shape), 3000)
    xyz, s = advect.grid_vertices(g, idx), advect.vertex_levels(g, idx)
    np.testing.assert_allclose(xyz, g.points(exaggeration=0.0, dtype=np.float64).reshape(-1, 3)[idx], atol=1e-12)
    end, s_end = advect.trace(wind, xyz, s, 12.0, 0.0)
    exact = rotate(xyz, axis, -omega * 12.0)
    inside = inside_all_along(loc, [rotate(xyz, axis, -omega * t) for t in np.linspace(0.0, 12.0, 49)])
    assert inside.sum() > 400
    err = advect.great_circle_km(end[inside], exact[inside], R)
    print(f"rigid rotation ({kind}): max {err.max():.4f} km over {inside.sum()} points")
    # Measured: 0.023 km (lcc, dateline), 0.013 km (polar, across the pole); cells are 50 km.
    assert err.max() < 0.1
    np.testing.assert_array_equal(s_end, s)  # no vertical wind: levels kept
    if kind == "polar":  # some of the checked trajectories cross the pole itself
        crossed = np.max([rotate(xyz[inside], axis, -omega * t)[:, 2] for t in np.linspace(0.0, 12.0, 97)], axis=0)
        assert crossed.max() > np.cos(np.deg2rad(1.0))


def test_deformational_flow_against_dop853_and_the_same_lonlat_grid():
    """A non-rigid, time-varying flow: hourly winds on the LCC grid against the analytic trajectories."""
    g = regional_grid("lcc")
    flow = DeformationalFlow(period_hours=24 * 24.0, radius=R)
    wind = advect.WindField(wind_dataset(g, lambda t: flow.wind(g.lon2d, g.lat2d, t)))
    # The anchor: a longitude/latitude grid of the same spacing (0.45 degrees) over the same region.
    lon1, lat1 = np.arange(-125.0, -75.0, 0.45), np.arange(30.0, 60.0, 0.45)
    gl = GlobeGrid(lon1, lat1, np.asarray([0.0, 1.0])[:, None, None] + np.zeros((2, lat1.size, lon1.size)))
    L, P = np.meshgrid(lon1, lat1)
    anchor = advect.WindField(wind_dataset(gl, lambda t: flow.wind(L, P, t)))
    rng = np.random.default_rng(1)
    xyz = lonlat_to_xyz(rng.uniform(-112.0, -88.0, 400), rng.uniform(39.0, 51.0, 400))
    t_from, t_to = 9.0, 3.0

    def rhs(t, y):
        p = y.reshape(-1, 3) / np.linalg.norm(y.reshape(-1, 3), axis=1)[:, None]
        lon, lat = np.rad2deg(np.arctan2(p[:, 1], p[:, 0])), np.rad2deg(np.arcsin(p[:, 2]))
        return (tangent_velocity(lon, lat, *flow.wind(lon, lat, t)) * (3600.0 / R)).ravel()

    sol = solve_ivp(rhs, (t_from, t_to), xyz.ravel(), method="DOP853", rtol=1e-11, atol=1e-13, dense_output=True)
    path = [sol.sol(t).reshape(-1, 3) for t in np.linspace(t_from, t_to, 25)]
    truth = path[-1] / np.linalg.norm(path[-1], axis=1)[:, None]
    loc = ColumnLocator(g.lon2d, g.lat2d)
    keep = inside_all_along(loc, path)  # compare where the air stayed over the grid
    assert keep.sum() > 150
    xyz, truth = xyz[keep], truth[keep]
    moved = advect.great_circle_km(xyz, truth, R)
    assert moved.min() > 100.0  # real travel
    got = advect.trace(wind, xyz, np.zeros(len(xyz)), t_from, t_to)[0]
    ref = advect.trace(anchor, xyz, np.zeros(len(xyz)), t_from, t_to)[0]
    err, err_ref = advect.great_circle_km(got, truth, R), advect.great_circle_km(ref, truth, R)
    # Measured: 0.042 km max on the LCC grid, 0.037 km on the lon/lat grid (hourly winds, 50 km cells, ~900 km travel).
    print(f"deformational: max {err.max():.3f} km (lon/lat anchor {err_ref.max():.3f} km), travel "
          f"{moved.min():.0f}-{moved.max():.0f} km")
    assert err.max() < 0.2
    assert err.max() < 1.5 * err_ref.max()


def test_a_point_that_leaves_the_region_stops_just_beyond_its_edge():
    g = regional_grid("lcc")
    axis = unit(lonlat_to_xyz(-100.0, -45.0))  # a wide rotation: a nearly straight 30 m/s stream across the grid
    omega = 30.0 * 3600.0 / R
    wind = advect.WindField(wind_dataset(g, lambda t: rotation_winds(g, axis, omega)))
    loc = ColumnLocator(g.lon2d, g.lat2d)
    idx = np.arange(g.shape[1] * g.shape[2])
    xyz = advect.grid_vertices(g, idx)
    end = advect.trace(wind, xyz, np.zeros(len(xyz)), 24.0, 0.0)[0]  # 2600 km upstream: every point leaves
    assert np.all(loc(rotate(xyz, axis, -omega * 24.0))[0] < 0)
    # The exact exit: the first sample of the closed-form path (every 0.05 h) outside the grid, then bisection.
    # Paths along the curved south edge that leave and come back are left out: a step that ends inside again
    # goes on (the rule is "stopped at the first step end outside").
    times = np.arange(0.0, 24.0 + 1e-9, 0.05)
    outside = np.stack([loc(rotate(xyz, axis, -omega * t))[0] < 0 for t in times])
    first = np.argmax(outside, axis=0)
    once = np.array([outside[f:, n].all() for n, f in enumerate(first)])
    assert once.sum() > 1000
    xyz, end, outside, first = xyz[once], end[once], outside[:, once], first[once]
    lo, hi = times[np.maximum(first - 1, 0)], times[first]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        inside = loc(np.stack([rotate(p, axis, -omega * m) for p, m in zip(xyz, mid)]))[0] >= 0
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    exit_point = np.stack([rotate(p, axis, -omega * m) for p, m in zip(xyz, hi)])
    # Stopped at the first step end outside the grid: outside, and within two steps (the step: cfl 1 of the
    # 51 km cells at the fastest wind) of the exact exit, the last step end inside being at most one step
    # before it; tracing on from there moves nothing.
    assert np.all(loc(end)[0] < 0)
    step_km = wind.min_spacing * R / 1000.0
    d = advect.great_circle_km(end, exit_point, R)
    print(f"exit: {d.max():.1f} km at most from the exact exit point (step {step_km:.1f} km), median "
          f"{np.median(d):.1f} km")
    assert d.max() <= 2.0 * step_km
    np.testing.assert_allclose(advect.trace(wind, end, np.zeros(len(end)), 24.0, 0.0)[0], end, rtol=0, atol=1e-15)
    # Its height comes from the nearest column (no zeros from outside the grid).
    np.testing.assert_allclose(wind.start_height(end, np.full(len(end), 1.0)), 5000.0)


def test_zero_and_missing_winds():
    g = regional_grid("polar", nx=41, ny=31)
    zero = advect.WindField(wind_dataset(g, lambda t: (np.zeros(g.shape[1:]), np.zeros(g.shape[1:]))))
    xyz = advect.grid_vertices(g)
    s = np.repeat(np.arange(3.0), g.shape[1] * g.shape[2])
    end, s_end = advect.trace(zero, xyz, s, 10.0, 0.0)
    np.testing.assert_allclose(end, xyz, rtol=0, atol=1e-15)  # renormalised each step: rounding only
    np.testing.assert_array_equal(s_end, s)
    u = np.zeros(g.shape[1:])
    u[3, 4] = np.nan
    with pytest.raises(DataError, match="NaN") as e:
        advect.WindField(wind_dataset(g, lambda t: (u, np.zeros_like(u)))).velocity(0.0, xyz[:5], s[:5])
    assert "u" in str(e.value)
    calm = advect.WindField(wind_dataset(g, lambda t: (u, np.zeros_like(u))), nan="zero")
    v, rate = calm.velocity(0.0, xyz, s)
    assert np.all(np.isfinite(v)) and np.all(v == 0.0) and np.all(rate == 0.0)


def test_terrain_slopes_follow_the_chain_rule_through_the_columns():
    """``dh/dx``, ``dh/dy`` (m per m east/north) of h = 1000 + 800 sin(3 lambda) cos(2 phi) on the LCC grid."""
    g0 = regional_grid("lcc", nx=60, ny=45, dx=30e3)
    lam, phi = np.deg2rad(g0.lon2d), np.deg2rad(g0.lat2d)
    h0 = 1000.0 + 800.0 * np.sin(3 * lam) * np.cos(2 * phi)
    g = GlobeGrid(g0.lon, g0.lat, h0[None] + np.array([0.0, 4000.0, 9000.0])[:, None, None], lon2d=g0.lon2d,
                  lat2d=g0.lat2d)
    wind = advect.WindField(wind_dataset(g, lambda t: (np.zeros(lam.shape), np.zeros(lam.shape))))
    dx_true = 2400.0 * np.cos(3 * lam) * np.cos(2 * phi) / (R * np.cos(phi))
    dy_true = -1600.0 * np.sin(3 * lam) * np.sin(2 * phi) / R
    inner = (slice(None), slice(1, -1), slice(1, -1))  # central differences: second order inside
    scale = np.abs(dx_true).max()
    np.testing.assert_allclose(wind._dhdx[inner], np.broadcast_to(dx_true, g.shape)[inner], rtol=0, atol=0.01 * scale)
    np.testing.assert_allclose(wind._dhdy[inner], np.broadcast_to(dy_true, g.shape)[inner], rtol=0, atol=0.01 * scale)


@pytest.mark.parametrize("name", ["compose", "restart"])
def test_streamed_strategies_on_a_regional_grid(name):
    g = regional_grid("lcc", nx=30, ny=24, dx=60e3)
    axis = unit(lonlat_to_xyz(-100.0, 20.0))
    omega = 25.0 * 3600.0 / (R * np.sin(np.deg2rad(25.0)))
    wind = advect.WindField(wind_dataset(g, lambda t: rotation_winds(g, axis, omega)))
    frames = np.arange(7.0)
    st = advect.STRATEGIES[name](wind, frames, g, **({"period": 4} if name == "restart" else {}))
    loc = ColumnLocator(g.lon2d, g.lat2d)
    index = np.arange(np.prod(g.shape))
    xyz = advect.grid_vertices(g, index)
    for n in range(1, 7):
        copies = st.copies(n, index)
    for cp in copies:
        if cp.weight == 0:
            continue
        elapsed = frames[6] - cp.start_hours
        exact = rotate(xyz, axis, -omega * elapsed)
        # Air that stayed a cell in from the edge at every frame.  Near the inflow edge the composed map
        # would mix in air stopped at the edge (53 km off here before such foot points were traced directly).
        inner, deep = np.ones(len(xyz), bool), np.ones(len(xyz), bool)
        for t in np.arange(0.0, elapsed + 0.5, 1.0):
            fi, fj = loc(rotate(xyz, axis, -omega * t))
            inner &= (fi >= 1) & (fj >= 1) & (fi <= g.shape[2] - 2) & (fj <= g.shape[1] - 2)
            deep &= (fi >= 4) & (fj >= 4) & (fi <= g.shape[2] - 5) & (fj <= g.shape[1] - 5)
        assert deep.sum() > 300
        err = advect.great_circle_km(cp.xyz[inner], exact[inner], R)
        print(f"{name}: copy from {cp.start_hours:g} h: max {err.max():.3f} km over {inner.sum()} vertices")
        assert err.max() < 1.0  # measured 0.565 km (compose), 0.012 km (restart); cells are 60 km
        # Four cells in, as before the direct traces: measured 0.079 km (compose), 0.004 km (restart).
        assert advect.great_circle_km(cp.xyz[deep], exact[deep], R).max() < 0.3
        lon, lat, alt = advect.start_coordinates(wind, cp)
        np.testing.assert_allclose(lonlat_to_xyz(lon, lat)[inner], cp.xyz[inner], atol=1e-12)
        assert np.all(np.isfinite(alt))
    assert st.stream.fallbacks > 0  # foot points near air stopped at the edge were traced directly


def test_regional_lonlat_grid_across_the_date_line_follows_the_same_rule():
    """A regional grid with 1-D axes (160E..160W, no wrap): inside it traces as before, air leaving stops outside."""
    lon, lat = np.arange(160.0, 200.01, 0.5), np.arange(30.0, 60.01, 0.5)
    g = GlobeGrid(lon, lat, np.array([0.0, 5000.0])[:, None, None] + np.zeros((2, lat.size, lon.size)))
    assert not g.periodic_lon
    axis = unit(lonlat_to_xyz(180.0, -45.0))
    omega = 45.0 * 3600.0 / R  # 3900 km a day: every point's air of 24 h ago was outside the grid
    L, P = np.meshgrid(lon, lat)
    p = lonlat_to_xyz(L, P)
    e, n = east_north(L, P)
    vel = np.cross(axis, p) * (omega * R / 3600.0)
    uv = (np.sum(vel * e, axis=-1), np.sum(vel * n, axis=-1))
    wind = advect.WindField(wind_dataset(g, lambda t: uv))
    assert wind.index.bounded
    xyz = advect.grid_vertices(g, np.arange(lat.size * lon.size))
    end = advect.trace(wind, xyz, np.zeros(len(xyz)), 24.0, 0.0)[0]
    exact = lambda t: rotate(xyz, axis, -omega * t)  # noqa: E731

    def inside(q):
        qlon, qlat, _ = (np.mod(a, 360.0) if k == 0 else a for k, a in enumerate(xyz_to_lonlat(q)))
        return (qlon >= 160.0 - 1e-9) & (qlon <= 200.0 + 1e-9) & (qlat >= 30.0 - 1e-9) & (qlat <= 60.0 + 1e-9)

    times = np.arange(0.0, 24.0 + 1e-9, 0.05)
    out = np.stack([~inside(exact(t)) for t in times])
    first = np.argmax(out, axis=0)
    once = out[-1] & np.array([out[f:, k].all() for k, f in enumerate(first)])  # left once, for good
    assert once.sum() > 0.8 * len(xyz)
    assert not inside(end[once]).any()
    exit_point = np.stack([rotate(q, axis, -omega * times[f]) for q, f in zip(xyz[once], first[once])])
    step_km = wind.min_spacing * R / 1000.0
    d = advect.great_circle_km(end[once], exit_point, R)
    print(f"regional lon/lat exit: {d.max():.1f} km at most (step {step_km:.1f} km)")
    assert d.max() <= 2.0 * step_km + 0.05 * omega * R / 1000.0  # plus the 0.05 h sampling of the exit
    # Inside it traces the rotation as before (3 h, air that stayed inside).
    short = advect.trace(wind, xyz, np.zeros(len(xyz)), 3.0, 0.0)[0]
    stay = np.all([inside(exact(t)) for t in np.linspace(0.0, 3.0, 31)], axis=0)
    assert stay.sum() > 1000
    err = advect.great_circle_km(short[stay], exact(3.0)[stay], R)
    print(f"regional lon/lat inside: {err.max():.4f} km")
    assert err.max() < 0.05


def test_advected_contour_task_on_a_lambert_conformal_file(tmp_path):
    """A CF file as a regional model writes it (projection x/y, 2-D lat/lon, eastward/northward winds) through
    the per-frame advect_contour task: the mesh vertices' start points are the rotation's, up to the trace."""
    xr = pytest.importorskip("xarray")
    from nephele.core.flow import advect_task
    from nephele.core.pipeline import tasks
    from nephele.core.surface.mesh import Mesh

    nx, ny, dx, nt = 30, 24, 60e3, 13
    x, y = (np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx
    lon, lat = lcc_inverse(*np.meshgrid(x, y))
    g = GlobeGrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), np.zeros((2, ny, nx)) + [[[0.0]], [[1.0]]],
                  lon2d=lon, lat2d=lat)
    axis = unit(lonlat_to_xyz(-100.0, 20.0))
    omega = 25.0 * 3600.0 / (R * np.sin(np.deg2rad(25.0)))
    u, v = rotation_winds(g, axis, omega)
    z = np.array([1000.0, 3000.0, 6000.0])
    q = np.clip((lat - 38.0) / 14.0, 0.0, 1.0)[None] * np.array([0.2, 1.0, 0.2])[:, None, None]  # a cloud band
    rep = lambda a: np.repeat(a[None], nt, axis=0).astype(np.float32)  # noqa: E731
    lcc = {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
           "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0, "earth_radius": R}
    rep3 = lambda a: rep(np.broadcast_to(a, (3,) + a.shape[-2:]))  # noqa: E731
    xr.Dataset(
        {"cloud": (("time", "z", "y", "x"), rep3(q), {"units": "1", "grid_mapping": "lambert"}),
         "u": (("time", "z", "y", "x"), rep3(u),
               {"units": "m s-1", "standard_name": "eastward_wind", "grid_mapping": "lambert"}),
         "v": (("time", "z", "y", "x"), rep3(v),
               {"units": "m s-1", "standard_name": "northward_wind", "grid_mapping": "lambert"}),
         "lambert": ((), 0, lcc)},
        coords={"time": ("time", np.arange(nt, dtype=float),
                         {"units": "hours since 2020-01-01", "standard_name": "time"}),
                "z": ("z", z, {"units": "m", "standard_name": "height", "positive": "up"}),
                "y": ("y", y, {"units": "m", "standard_name": "projection_y_coordinate"}),
                "x": ("x", x, {"units": "m", "standard_name": "projection_x_coordinate"}),
                "lat": (("y", "x"), lat, {"units": "degrees_north", "standard_name": "latitude"}),
                "lon": (("y", "x"), lon, {"units": "degrees_east", "standard_name": "longitude"})},
    ).to_netcdf(tmp_path / "lcc_winds.nc")
    obj = {"kind": "advected_contour", "source": str(tmp_path / "lcc_winds.nc"), "var": "cloud", "level": 0.5,
           "hours_per_frame": 1.0, "frame_start": 1, "strategy": "restart", "period": 8}
    tp = advect_task.advect_task_params(obj, 7)  # model time 6 h: copy A from 0 h, copy B from 4 h
    m = Mesh.from_arrays(tasks.run("advect_contour", tp))
    assert len(m.vertices) > 200
    loc = ColumnLocator(lon, lat)
    vert = m.vertices.astype(np.float64)
    vert /= np.linalg.norm(vert, axis=1)[:, None]
    for c, start_hours in zip(advect.COPIES, (0.0, 4.0)):
        back = 6.0 - start_hours
        # Air two cells in from the edge at every frame.  In the outermost cells a mesh vertex interpolates
        # between grid vertices whose air stayed and whose air came from outside (stopped at the edge).
        stayed = np.ones(len(vert), bool)
        for t in np.arange(0.0, back + 0.5, 1.0):
            fi, fj = loc(rotate(vert, axis, -omega * t))
            stayed &= (fi >= 2) & (fj >= 2) & (fi <= nx - 3) & (fj <= ny - 3)
        assert stayed.sum() > 100
        start = m.attributes[advect.START.format(c)].astype(np.float64)
        start /= np.linalg.norm(start, axis=1)[:, None]
        # Float32 attributes and the streamed map: measured 0.50 km (copy a, 6 h), 0.004 km (copy b, 2 h).
        err = advect.great_circle_km(start[stayed], rotate(vert[stayed], axis, -omega * back), R)
        print(f"advect_contour copy {c}: max {err.max():.3f} km over {stayed.sum()} of {len(vert)} vertices")
        assert err.max() < 1.0
