"""Flow volumes in the winds of a curvilinear (Lambert conformal, regional) grid.

Independent truth: a rigid rotation about an axis, whose flow map is a
rotation (closed form) and whose flow volume, with the axis in the generator's
plane, is given by Pappus's theorem.  The grid's 2-D latitude/longitude come
from Snyder's spherical Lambert conformal inverse written out here; the winds
are stored as a file holds them (east/north m/s at every column).  Air that
leaves the region stops at the region's edge (ClimateVelocity is NaN outside,
so flow_volume's bounded rule applies).
"""

import numpy as np
import pytest
from projections import lcc_inverse

from nephele.core.climate.columns import ColumnLocator
from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, lonlat_to_xyz
from nephele.core.errors import DataError
from nephele.core.flow.flows import rotate
from nephele.core.flowvol import ClimateVelocity, flow_volume
from nephele.core.flowvol.tets import face_use_counts, signed_volumes

R = 6_371_000.0
AXIS = lonlat_to_xyz(-100.0, 20.0)  # 25 degrees south of the grid's centre
OMEGA = 30.0 * 3600.0 / (R * np.sin(np.deg2rad(25.0)))  # radians per hour: 30 m/s at the centre


@pytest.fixture(scope="module")
def rotation_lcc():
    nx, ny, dx, nt = 40, 30, 50e3, 25
    X, Y = np.meshgrid((np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx)
    lon, lat = lcc_inverse(X, Y)
    h = np.array([0.0, 5000.0, 10000.0])[:, None, None] + np.zeros((3, ny, nx))
    g = GlobeGrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), h, lon2d=lon, lat2d=lat).validate()
    p = lonlat_to_xyz(lon, lat)
    vel = np.cross(AXIS, p) * (OMEGA * R / 3600.0)
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    u = vel[..., 0] * -np.sin(lam) + vel[..., 1] * np.cos(lam)
    v = -vel[..., 0] * np.sin(phi) * np.cos(lam) - vel[..., 1] * np.sin(phi) * np.sin(lam) + vel[..., 2] * np.cos(phi)
    f = lambda a: np.broadcast_to(a, (nt, 3) + a.shape).copy()  # noqa: E731
    ds = ArrayDataset(g, hourly("2000-01-01", nt), {"u": f(u), "v": f(v), "w": f(0 * u)}, source="<lcc rotation>")
    ds.earth_radius = R
    return ds


def test_velocity_matches_the_rotation_inside_and_is_nan_outside(rotation_lcc):
    vel = ClimateVelocity(rotation_lcc)
    assert vel.bounded
    g = rotation_lcc.grid
    rng = np.random.default_rng(0)
    cols = lonlat_to_xyz(g.lon2d, g.lat2d)
    j, i = rng.integers(0, g.shape[1] - 1, 500), rng.integers(0, g.shape[2] - 1, 500)
    a, b = rng.uniform(0.0, 1.0, (2, 500, 1))  # blends of each cell's four columns: inside the cell
    q = ((1 - a) * (1 - b) * cols[j, i] + a * (1 - b) * cols[j, i + 1]
         + (1 - a) * b * cols[j + 1, i] + a * b * cols[j + 1, i + 1])
    q /= np.linalg.norm(q, axis=1)[:, None]
    assert np.all(ColumnLocator(g.lon2d, g.lat2d)(q)[0] >= 0)
    pts = q * vel.point(0.0, 0.0, 5000.0)[0]
    got = vel(pts, rng.uniform(0.0, 24.0, len(pts)))
    exact = np.cross(AXIS, pts) * OMEGA  # scene units per hour
    err = np.linalg.norm(got - exact, axis=1) / np.linalg.norm(exact, axis=1)
    print(f"velocity: max relative error {err.max():.2e}")
    assert err.max() < 2e-4  # measured 2.0e-5: bilinear in index space of a field linear in position
    far = np.stack([vel.point(-60.0, 45.0, 5000.0), vel.point(-100.0, 10.0, 1000.0), vel.point(80.0, -45.0, 5000.0)])
    assert np.all(np.isnan(vel(far, np.zeros(3))))
    stacked, per_step = ClimateVelocity(rotation_lcc), ClimateVelocity(rotation_lcc, stack_mb=0)
    both = np.concatenate([pts[:20], far])
    np.testing.assert_allclose(stacked(both, np.full(len(both), 3.5)), per_step(both, np.full(len(both), 3.5)),
                               rtol=1e-6, atol=1e-12)


def test_flow_volume_inside_the_region_matches_rotation_and_pappus(rotation_lcc):
    vel = ClimateVelocity(rotation_lcc)
    centre = vel.point(-100.0, 45.0, 5000.0)
    c = rotate(centre, AXIS, -OMEGA * 3.0)  # upstream, so 6 hours of air stays over the grid
    T = 6.0
    fv = flow_volume(vel, c, 0.02, T, sides=12, rings=1, steps=12)
    assert not fv.exited.any()
    first = np.isclose(fv.release, 0.0)
    moved = np.linalg.norm(fv.vertices[first] - rotate(fv.generator, AXIS, OMEGA * T), axis=1)
    assert moved.max() < 1e-5  # scene units (64 m); measured 1.5e-6 (9 m) after 900 km
    d = np.linalg.norm(c - (c @ AXIS) * AXIS)
    pappus = 0.5 * 12 * 0.02**2 * np.sin(2 * np.pi / 12) * OMEGA * T * d
    assert fv.volume == pytest.approx(pappus, rel=1e-3)  # measured 9e-5
    vol = signed_volumes(fv.vertices, fv.tets)
    assert np.all(vol >= 0) and np.all(face_use_counts(fv.tets) <= 2)


def test_air_leaving_the_region_stops_at_its_edge(rotation_lcc):
    vel = ClimateVelocity(rotation_lcc)
    g = rotation_lcc.grid
    c = rotate(vel.point(-100.0, 45.0, 5000.0), AXIS, OMEGA * 6.0)  # downstream: 18 h of travel crosses the edge
    fv = flow_volume(vel, c, 0.02, 18.0, sides=12, rings=1, steps=12)
    assert fv.exited.any() and len(fv.tets)
    assert not np.isin(np.flatnonzero(fv.exited), fv.tets).any()  # the smoke ends where its air left
    loc = ColumnLocator(g.lon2d, g.lat2d)
    fi, fj = loc(fv.vertices[fv.exited])
    assert np.all(fi >= 0)  # the bisection keeps exit points inside
    edge = np.minimum.reduce([fi, fj, g.shape[2] - 1 - fi, g.shape[1] - 1 - fj])
    assert edge.max() < 1e-3  # within a thousandth of a cell of the region's edge (measured 4e-5)
    # Everything that did not leave sits where the rotation put it.
    kept = ~fv.exited
    age = fv.age[kept]
    start = fv.generator[np.arange(len(fv.vertices))[kept] % len(fv.generator)]
    exact = np.stack([rotate(p, AXIS, OMEGA * a) for p, a in zip(start, age)])
    assert np.linalg.norm(fv.vertices[kept] - exact, axis=1).max() < 5e-6  # measured 7e-7


def test_generator_outside_the_region_is_refused(rotation_lcc):
    vel = ClimateVelocity(rotation_lcc)
    with pytest.raises(DataError, match="NaN"):
        flow_volume(vel, vel.point(-40.0, 45.0, 5000.0), 0.02, 6.0, sides=6)


def test_regional_lonlat_grid_is_bounded_too():
    """1-D axes that do not close the circle: NaN beyond the edges, air that leaves stops there."""
    lon, lat = np.linspace(-120.0, -80.0, 81), np.linspace(30.0, 60.0, 61)
    g = GlobeGrid(lon, lat, np.array([0.0, 5000.0, 10000.0])[:, None, None] + np.zeros((3, lat.size, lon.size)))
    L, P = np.meshgrid(lon, lat)
    p = lonlat_to_xyz(L, P)
    vel = np.cross(AXIS, p) * (OMEGA * R / 3600.0)
    lam, phi = np.deg2rad(L), np.deg2rad(P)
    u = vel[..., 0] * -np.sin(lam) + vel[..., 1] * np.cos(lam)
    v = -vel[..., 0] * np.sin(phi) * np.cos(lam) - vel[..., 1] * np.sin(phi) * np.sin(lam) + vel[..., 2] * np.cos(phi)
    f = lambda a: np.broadcast_to(a, (25, 3) + a.shape).copy()  # noqa: E731
    ds = ArrayDataset(g, hourly("2000-01-01", 25), {"u": f(u), "v": f(v), "w": f(0 * u)}, source="<regional lon/lat>")
    ds.earth_radius = R
    cv = ClimateVelocity(ds)
    assert cv.bounded
    inside = np.stack([cv.point(-100.0, 45.0, 5000.0), cv.point(-80.0, 60.0, 5000.0)])  # the second on a corner
    np.testing.assert_allclose(cv(inside, np.zeros(2)), np.cross(AXIS, inside) * OMEGA, rtol=1e-3, atol=1e-9)
    assert np.all(np.isnan(cv(np.stack([cv.point(-79.9, 45.0, 5000.0), cv.point(-100.0, 60.1, 5000.0)]), np.zeros(2))))
    c = rotate(cv.point(-100.0, 45.0, 5000.0), AXIS, OMEGA * 6.0)
    fv = flow_volume(cv, c, 0.02, 18.0, sides=12, rings=1, steps=12)
    assert fv.exited.any() and not np.isin(np.flatnonzero(fv.exited), fv.tets).any()
    from nephele.core.climate.grid import xyz_to_lonlat

    elon, elat, _ = xyz_to_lonlat(fv.vertices[fv.exited])
    edge = np.minimum.reduce([elon - lon[0], lon[-1] - elon, elat - lat[0], lat[-1] - elat])
    assert edge.min() >= -1e-9 and edge.max() < 1e-3  # degrees: on the edge, from inside
