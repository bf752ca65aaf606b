"""The per-frame advected-contour task and the ``nephele advect`` precompute command."""

import numpy as np
import pytest

from nephele.core.climate.grid import xyz_to_lonlat
from nephele.core.flow import advect, advect_task
from nephele.core.pipeline import tasks
from nephele.core.pipeline.cache import Cache
from nephele.core.pipeline.sources import open_source
from nephele.core.surface.mesh import Mesh

OBJ = {"kind": "advected_contour", "source": "demo:small", "var": "cloud", "level": 0.15, "hours_per_frame": 1.0,
       "frame_start": 1, "strategy": "restart", "period": 8}


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def test_first_frame_starts_where_the_vertices_are():
    tp = advect_task.advect_task_params(OBJ, 1)
    assert tp["frame"] == 0 and tp["hours"] == 0.0
    m = Mesh.from_arrays(tasks.run("advect_contour", tp))
    assert len(m.vertices) > 100
    for c in advect.COPIES:
        start = m.attributes[advect.START.format(c)]
        assert start.shape == (len(m.vertices), 3)
        np.testing.assert_allclose(_unit(start), _unit(m.vertices), atol=2e-3)
        np.testing.assert_allclose(m.attributes[advect.START_ALT.format(c)], m.attributes["altitude"], rtol=1e-3,
                                   atol=1.0)
    assert m.attributes[advect.WEIGHT.format("a")][0] == 0.0


def test_same_mesh_as_the_contour_and_start_matches_a_direct_trace():
    frame = 7  # model time 6 h; copy A restarted at 0, copy B at 4 (period 8)
    tp = advect_task.advect_task_params(OBJ, frame)
    m = Mesh.from_arrays(tasks.run("advect_contour", tp))
    ref = Mesh.from_arrays(tasks.run("contour", {k: tp[k] for k in
                                                 ("source", "stamp", "var", "level", "hours", "exaggeration", "radius",
                                                  "color_var", "method")}))
    np.testing.assert_array_equal(m.vertices, ref.vertices)
    np.testing.assert_array_equal(m.faces, ref.faces)
    ds = open_source("demo:small")
    wind = advect.WindField(ds)
    # Interpolating the vertices' start coordinates along the contour's edges agrees with tracing
    # the surface points themselves, to a small fraction of a cell.
    rng = np.random.default_rng(0)
    pick = rng.choice(len(m.vertices), 300, replace=False)
    xyz = _unit(m.vertices[pick].astype(np.float64))
    lon, lat, r = xyz_to_lonlat(m.vertices[pick].astype(np.float64))
    nk = ds.grid.shape[0]
    # level coordinate of each surface point from its altitude in its column (nearest column is enough here)
    j = np.clip(np.searchsorted(ds.grid.lat, lat), 0, ds.grid.shape[1] - 1)
    i = np.clip(np.searchsorted(ds.grid.lon, np.mod(lon, 360)), 0, ds.grid.shape[2] - 1)
    alt = m.attributes["altitude"][pick]
    s = np.array([np.interp(a, ds.grid.height[:, jj, ii], np.arange(nk)) for a, jj, ii in zip(alt, j, i)])
    cell_km = 6371.0 * np.deg2rad(ds.grid.lat[1] - ds.grid.lat[0])
    for c, start_hours in zip(advect.COPIES, (0.0, 4.0)):
        direct, _ = advect.trace(wind, xyz, s, tp["hours"], start_hours)
        interp = _unit(m.attributes[advect.START.format(c)][pick].astype(np.float64))
        err = advect.great_circle_km(direct, interp)
        assert np.median(err) < 0.005 * cell_km
        assert err.max() < 0.05 * cell_km
    w = m.attributes[advect.WEIGHT.format("a")][0], m.attributes[advect.WEIGHT.format("b")][0]
    assert w == pytest.approx((1 - abs(2 * 6 / 8 - 1), abs(2 * 6 / 8 - 1)))


def test_planner_and_bad_strategy():
    plan = tasks.plan(OBJ, 3)
    assert plan[0][0] == "advect_contour" and plan[0][1]["frame"] == 2
    from nephele.core.errors import DataError

    with pytest.raises(DataError, match="unknown strategy"):
        advect_task.advect_task_params(dict(OBJ, strategy="magic"), 3)


def test_cli_precomputes_into_the_cache(tmp_path, capsys):
    from nephele.farm.cli import main

    rc = main(["advect", "demo:small", "--frames", "1-3", "--period", "8", "--cache", str(tmp_path)])
    assert rc == 0
    assert "3 frames" in capsys.readouterr().out
    cache = Cache(tmp_path)
    for f in (1, 2, 3):
        hit = cache.load("advect_contour", advect_task.advect_task_params(OBJ, f))
        assert hit is not None and len(hit["vertices"]) > 100
    assert main(["advect", "demo:small", "--frames", "3-1", "--cache", str(tmp_path)]) == 2
    assert main(["advect", "demo:small", "--frames", "1-2", "--period", "7", "--cache", str(tmp_path)]) == 2
    assert "even" in capsys.readouterr().err
