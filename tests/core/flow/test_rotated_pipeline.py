"""A rotated-pole grid (the UM file over Wales) through volumes and advection: everything lands at its true place."""

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("xarray")

from nephele.core.climate.grid import GlobeGrid, xyz_to_lonlat  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.volume.sparse import CurvilinearField, resample  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402

UM = Path(__file__).resolve().parents[2] / "data" / "um_hybrid_height.nc"
THETA = "air_potential_temperature"


@pytest.fixture(scope="module")
def um():
    return open_dataset(UM)


def test_field_on_rotated_grid_samples_its_values_at_the_true_vertices(um):
    g = um.grid
    values = um.read(THETA, 0)
    field = CurvilinearField.from_grid(g, {"value": values})
    rng = np.random.default_rng(3)
    k, j, i = (rng.integers(1, n - 1, 200) for n in g.shape)
    # Vertices placed on the true globe (GlobeGrid.points applies the rotation) give back their own values.
    pts = g.points(dtype=np.float64)[k, j, i]
    got = field.sample("value", pts)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, values[k, j, i], rtol=0, atol=2e-4)
    # The same field without the rotation is elsewhere: at the true points there is nothing.
    flat = CurvilinearField.from_grid(GlobeGrid(g.lon, g.lat, g.height), {"value": values})
    assert np.all(np.isnan(flat.sample("value", pts)))
    # Cell corners of the closed field are the grid's true points.
    np.testing.assert_allclose(field.cell_corner_points(), g.points(dtype=np.float64), atol=1e-12)


def test_voxel_volume_of_the_um_file_lies_over_wales(um):
    g = um.grid
    values = um.read(THETA, 0)
    lo, hi = float(np.percentile(values, 50)), float(values.max())
    tf = TransferFunction.ramp(lo, hi, 1.0)
    vox = 0.0002  # scene units: 1.3 km on the unit globe (the grid is ~10 km across, 30x exaggerated heights)
    vol = resample(g, values, tf, voxel_size=vox, workers=1)
    assert not vol.empty
    b = vol.block
    idx = np.argwhere(vol.density > 0)
    centres = (vol.blocks[idx[:, 0]].astype(np.float64) * b + idx[:, 1:]) * vox
    lon, lat, r = xyz_to_lonlat(centres)
    tlon, tlat = g.true_lonlat()
    pad = np.rad2deg(vox)  # one voxel of slack at the edges
    assert tlon.min() - pad <= lon.min() and lon.max() <= tlon.max() + pad
    assert tlat.min() - pad <= lat.min() and lat.max() <= tlat.max() + pad
    assert 52.3 < lat.mean() < 52.5 and -3.2 < lon.mean() < -3.0
    # Every opaque voxel centre is where the field itself is above the threshold (same located value).
    field = CurvilinearField.from_grid(g, {"value": values})
    v = field.sample("value", centres)
    ok = np.isfinite(v)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(vol.density[tuple(idx.T)][ok], np.asarray(tf(v[ok]), dtype=np.float32), atol=1e-4)


CAM_RADIUS = 6371220.0


def _rotated_rotation_dataset(radius):
    from nephele.core.climate.grid import rotated_pole_matrix
    from nephele.core.flow.flows import FlowDataset, SolidBodyRotation, sample_grid

    g = sample_grid(96, 48)
    # The UM file's pole (37.5 N, 177.5 E): winds in such a file are relative to the rotated grid.
    rotated = GlobeGrid(g.lon, g.lat, g.height, rotation=rotated_pole_matrix(177.5, 37.5))
    flow = SolidBodyRotation(alpha=0.3, radius=radius)
    return flow, FlowDataset(flow, hours=25, grid=rotated)


def test_advected_start_points_on_a_rotated_grid_are_true_positions():
    from nephele.core.climate.grid import lonlat_to_xyz
    from nephele.core.flow.advect import Copy, WindField, great_circle_km, start_coordinates, trace

    flow, ds = _rotated_rotation_dataset(CAM_RADIUS)
    wind = WindField(ds, read_ahead=False)
    assert wind.radius == CAM_RADIUS
    rng = np.random.default_rng(5)
    p = lonlat_to_xyz(rng.uniform(0, 360, 50), rng.uniform(-60, 60, 50))  # grid frame
    s = np.zeros(50)
    back, s1 = trace(wind, p, s, 24.0, 0.0)
    exact_grid = flow.exact_start(p, 24.0)  # solid-body rotation: the exact start, in the grid frame
    lon, lat, _ = start_coordinates(wind, Copy(back, s1, 1.0, 0.0))
    # True positions: the exact start turned by the grid's rotation (what GlobeGrid.points does to vertices).
    true = exact_grid @ ds.grid.rotation.T
    got = lonlat_to_xyz(lon, lat)
    err_km = great_circle_km(got, true, radius=CAM_RADIUS)
    assert err_km.max() < 5.0, err_km.max()  # 30 degrees of rotation in a day, grid-sampled winds
    # Without the rotation the start would be reported in the grid frame: thousands of km away.
    assert great_circle_km(back, true).min() > 500.0


def test_wind_radius_comes_from_the_dataset():
    """A flow made with CAM's radius, traced with the dataset's radius, closes on the exact answer;
    traced with the default 6371 km it lags by the 3.5e-5 relative radius error."""
    from nephele.core.climate.grid import lonlat_to_xyz
    from nephele.core.flow.advect import AnalyticWind, great_circle_km, trace
    from nephele.core.flow.flows import SolidBodyRotation

    flow = SolidBodyRotation(alpha=0.0, radius=CAM_RADIUS)
    p = lonlat_to_xyz(np.linspace(0, 300, 7), np.zeros(7))
    exact = flow.exact_start(p, 24.0)
    right, _ = trace(AnalyticWind(flow), p, np.zeros(7), 24.0, 0.0)  # radius from the flow
    wrong, _ = trace(AnalyticWind(flow, radius=6371000.0), p, np.zeros(7), 24.0, 0.0)
    e_right = great_circle_km(right, exact, radius=CAM_RADIUS).max()
    e_wrong = great_circle_km(wrong, exact, radius=CAM_RADIUS).max()
    # 30 degrees a day: the wrong radius is 30 deg * 3.45e-5 * 6371 km = 0.115 km off.
    assert e_right < 0.01 and 0.10 < e_wrong < 0.13, (e_right, e_wrong)


def test_advected_contour_on_the_um_grid_lands_over_wales_and_moves_with_grid_winds(um):
    from nephele.core.climate.dataset import ArrayDataset, hourly
    from nephele.core.flow import advect, advect_task
    from nephele.core.pipeline import tasks
    from nephele.core.pipeline.sources import register_source
    from nephele.core.surface.mesh import Mesh

    g = um.grid
    theta = um.read(THETA, 0)
    nt, speed = 3, 0.5  # m/s toward grid east: 1.8 km an hour, the grid is ~10 km across
    fields = {"theta": np.repeat(theta[None], nt, 0), "u": np.full((nt,) + g.shape, speed, np.float32),
              "v": np.zeros((nt,) + g.shape, np.float32), "w": np.zeros((nt,) + g.shape, np.float32)}
    ds = ArrayDataset(g, hourly("2009-09-09T17", nt), fields, source="<um winds>")
    ds.earth_radius = um.earth_radius
    source = register_source("um-rotated-winds", ds)
    obj = {"kind": "advected_contour", "source": source, "var": "theta", "level": 288.0, "hours_per_frame": 1.0,
           "frame_start": 1, "strategy": "full"}
    first = Mesh.from_arrays(tasks.run("advect_contour", advect_task.advect_task_params(obj, 1)))
    v = np.asarray(first.vertices, dtype=np.float64)
    lon, lat, _ = xyz_to_lonlat(v)
    assert len(v) > 1000 and 52.37 < lat.mean() < 52.46 and -3.19 < lon.mean() < -3.04
    unit = v / np.linalg.norm(v, axis=1, keepdims=True)
    for c in advect.COPIES:  # at model time 0 the texture starts where the (true) vertices are
        start = first.attributes[advect.START.format(c)].astype(np.float64)
        np.testing.assert_allclose(start / np.linalg.norm(start, axis=1, keepdims=True), unit, atol=1e-5)
    # Two hours later: each start point lies 2 h * 0.5 m/s = 3.6 km grid-west of its vertex.
    late = Mesh.from_arrays(tasks.run("advect_contour", advect_task.advect_task_params(obj, 3)))
    glon_v, glat_v, _ = xyz_to_lonlat(g.to_grid(np.asarray(late.vertices, dtype=np.float64)))
    w = late.attributes[advect.WEIGHT.format("b")][0] > 0.5 and "b" or "a"
    glon_s, glat_s, _ = xyz_to_lonlat(g.to_grid(late.attributes[advect.START.format(w)].astype(np.float64)))
    glon_v, glon_s = np.mod(glon_v, 360.0), np.mod(glon_s, 360.0)
    inside = glon_v > g.lon[0] + 0.05  # points whose start stays on the grid
    shift_km = np.deg2rad(glon_v - glon_s)[inside] * np.cos(np.deg2rad(glat_v[inside])) * um.earth_radius / 1000.0
    assert inside.sum() > 100
    np.testing.assert_allclose(shift_km, 3.6, atol=0.02)
    np.testing.assert_allclose(glat_s[inside], glat_v[inside], atol=1e-5)


def test_windfield_radius_argument_overrides_the_dataset():
    from nephele.core.flow.advect import WindField

    _, ds = _rotated_rotation_dataset(CAM_RADIUS)
    assert WindField(ds, read_ahead=False).radius == CAM_RADIUS
    w = WindField(ds, read_ahead=False, radius=6371000.0)
    assert w.radius == 6371000.0
    # Angular speed scales as 1/radius: the same wind, the smaller radius, the faster turn.
    p = np.array([[1.0, 0.0, 0.0]])
    fast = w.velocity(0.0, p, np.zeros(1))[0]
    slow = WindField(ds, read_ahead=False).velocity(0.0, p, np.zeros(1))[0]
    np.testing.assert_allclose(np.linalg.norm(fast) / np.linalg.norm(slow), CAM_RADIUS / 6371000.0, rtol=1e-6)
