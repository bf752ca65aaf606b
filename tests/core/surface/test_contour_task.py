"""The per-frame contour task: frame -> model time, interpolation in time, cache, planner."""

import numpy as np
import pytest

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, globe_radius
from nephele.core.errors import DataError
from nephele.core.pipeline import sources, tasks
from nephele.core.pipeline.cache import Cache
from nephele.core.surface import contour_task

H_SCALE = (10000.0, 20000.0, 40000.0)  # cloud = height / H_SCALE[t]


def layered_dataset(ni=36, nj=18, nk=8):
    """Fields that depend on height only: every contour is a sphere of known radius."""
    lon = np.arange(ni) * 360.0 / ni
    lat = np.linspace(-90.0, 90.0, nj)  # pole rows included: contours close there
    levels = np.linspace(0.0, 16000.0, nk)
    height = np.broadcast_to(levels[:, None, None], (nk, nj, ni)).copy()
    grid = GlobeGrid(lon, lat, height)
    cloud = np.stack([height / s for s in H_SCALE]).astype(np.float32)
    temperature = np.stack([288.0 - 0.0065 * height] * len(H_SCALE)).astype(np.float32)
    return ArrayDataset(grid, hourly("2000-01-01", len(H_SCALE)), {"cloud": cloud, "temperature": temperature},
                        source="layered")


@pytest.fixture()
def source():
    return sources.register_source("memory:layered", layered_dataset())


def obj_params(source, **kw):
    p = {"kind": "contour", "source": source, "var": "cloud", "level": 0.5, "exaggeration": 30.0,
         "hours_per_frame": 0.25, "frame_start": 1}
    p.update(kw)
    return p


def test_frame_hours():
    assert contour_task.frame_hours(1, 1, 1.0) == 0.0
    assert contour_task.frame_hours(13, 1, 1.0) == 12.0
    assert contour_task.frame_hours(5, 1, 0.25) == 1.0
    assert contour_task.frame_hours(2.5, 1, 2.0) == 3.0  # sub-frames too
    assert contour_task.frame_hours(-10, 1, 1.0) == 0.0  # before the data: first step
    assert contour_task.frame_hours(500, 1, 1.0, last_hour=239.0) == 239.0  # after: last step
    with pytest.raises(ValueError):
        contour_task.frame_hours(1, 1, 0.0)


def test_task_params(source):
    tp = contour_task.task_params(obj_params(source), 3)
    assert tp["hours"] == 0.5 and tp["level"] == 0.5 and tp["var"] == "cloud"
    assert tp["color_var"] == "altitude" and tp["method"] == "cubes" and tp["radius"] == 1.0
    # Clamped to the data's last hour (2 h).
    assert contour_task.task_params(obj_params(source), 1000)["hours"] == 2.0
    with pytest.raises(DataError):
        contour_task.task_params({"source": source, "var": "cloud"}, 1)


@pytest.mark.parametrize("hours, height",
                         [(0.0, 5000.0), (1.0, 10000.0), (0.5, 1.0 / (0.5 / 10000 + 0.5 / 20000) * 0.5)])
def test_contour_sits_at_the_analytic_height(source, hours, height):
    # cloud = h / H(t), linear in time between steps: the 0.5 surface is the
    # sphere h = 0.5 / ((1-w)/H0 + w/H1).
    tp = contour_task.task_params(obj_params(source, color_var="temperature"), 1 + hours / 0.25)
    assert tp["hours"] == hours
    out = contour_task.contour_mesh(tp)
    v = out["vertices"]
    r = np.linalg.norm(v.astype(np.float64), axis=1)
    expected_r = globe_radius(height, 1.0, 30.0)
    assert len(out["faces"]) > 100
    # Vertices on grid edges are exact; the contour's pole cells are fanned from
    # the mean of their loop, which lies inside the sphere: leave those out.
    on_edges = np.abs(v[:, 2]) < 0.99 * r
    assert on_edges.sum() > 0.9 * len(v)
    assert np.allclose(r[on_edges], expected_r, rtol=0, atol=1e-6)
    assert np.allclose(out["attr__altitude"], height, rtol=1e-5)
    assert np.allclose(out["attr__temperature"], 288.0 - 0.0065 * height, atol=1e-3)
    # Normals point out of the region above the level (the cloudy side); here
    # cloud grows with height, so they point down, toward the centre.
    radial = np.einsum("ij,ij->i", out["normals"], v / r[:, None])
    assert np.all(radial < -0.99)


def test_closed_shell_is_watertight(source):
    trimesh = pytest.importorskip("trimesh")
    out = contour_task.contour_mesh(contour_task.task_params(obj_params(source), 1))
    tm = trimesh.Trimesh(out["vertices"], out["faces"], process=False)
    assert tm.is_watertight and tm.is_winding_consistent


def test_radius_and_exaggeration_scale_the_surface(source):
    a = contour_task.contour_mesh(contour_task.task_params(obj_params(source, radius=2.0, exaggeration=10.0), 1))
    r = np.linalg.norm(a["vertices"].astype(np.float64), axis=1)
    on_edges = np.abs(a["vertices"][:, 2]) < 0.99 * r  # pole fan centres left out, as above
    assert np.allclose(r[on_edges], globe_radius(5000.0, 2.0, 10.0), atol=1e-6)


def test_empty_and_bad_requests(source):
    out = contour_task.contour_mesh(contour_task.task_params(obj_params(source, level=5.0), 1))
    assert out["faces"].shape == (0, 3) and out["vertices"].shape == (0, 3)
    with pytest.raises(DataError, match="no such variable"):
        contour_task.contour_mesh(contour_task.task_params(obj_params(source, var="ozone"), 1))
    with pytest.raises(DataError, match="colour"):
        contour_task.contour_mesh(contour_task.task_params(obj_params(source, color_var="ozone"), 1))
    with pytest.raises(DataError, match="not finite"):
        contour_task.contour_mesh(contour_task.task_params(obj_params(source, level=float("nan")), 1))


def test_run_cached_and_planner(source, tmp_path):
    cache = Cache(tmp_path)
    [(kind, tp)] = tasks.plan(obj_params(source), 3)
    assert kind == "contour" and tp == contour_task.task_params(obj_params(source), 3)
    first = tasks.run_cached(kind, tp, cache)
    assert (kind, tp) in cache
    second = tasks.run_cached(kind, tp, cache)
    assert set(first) == set(second)
    for k in first:
        np.testing.assert_array_equal(first[k], second[k])
    # A different frame is a different entry.
    [(_, tp2)] = tasks.plan(obj_params(source), 4)
    assert (kind, tp2) not in cache
