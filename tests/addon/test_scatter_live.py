"""The scattering cloud re-solved in the background when the panel's albedo, g, sun or density
change (addon/scatter_jobs.py), and an evolving cloud solved frame by frame."""

import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele import fileio  # noqa: E402
from nephele.addon import frame  # noqa: E402
from nephele.addon import scatter_scene as ss  # noqa: E402
from nephele.core.light import scatter  # noqa: E402


def _cloud(scene, tmp_path, frames=2, **props):
    p = scene.nephele_scatter
    p.resolution = (8, 8, 6)
    p.directory = str(tmp_path / "scatter")
    p.tolerance = 1e-2
    for k, v in props.items():
        setattr(p, k, v)
    scene.frame_start, scene.frame_end = 1, frames
    assert bpy.ops.nephele.add_scattering_cloud() == {"FINISHED"}
    return p, bpy.data.objects[ss.OBJECT_NAME]


def _emission(path, shape):
    arr = np.zeros(shape[::-1], np.float32)
    fileio.openvdb().read(str(path), "emission").copyToArray(arr)
    return arr.transpose(2, 1, 0)


def test_changes_resolve_in_the_background_from_the_last_solution(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    scene = empty_scene
    p, obj = _cloud(scene, tmp_path)
    before = scatter.load_solution(tmp_path / "scatter" / "solution.npz")
    vdb = tmp_path / "scatter" / "scatter_0002.vdb"
    old = _emission(vdb, before.sigma.shape)
    frame.force_background_jobs(True)
    try:
        t0 = time.perf_counter()
        p.albedo = 0.9  # the interface path: the edit returns, the solve runs on the worker
        returned = time.perf_counter() - t0
        assert returned < 0.5, returned
        assert frame.pending(obj) and "background" in p.status
        assert frame.wait(300)
    finally:
        frame.force_background_jobs(False)
    after = scatter.load_solution(tmp_path / "scatter" / "solution.npz")
    assert after.albedo == pytest.approx(0.9) and after.warm and "from the previous frame" in after.report
    new = _emission(vdb, after.sigma.shape)
    assert new.sum() < 0.95 * old.sum()  # less light scattered at a lower albedo
    # the new grid is the core's source toward frame 2's camera
    scene.frame_set(2)
    cam = np.array(scene.camera.matrix_world.translation) - np.array(obj.location)
    np.testing.assert_allclose(new, scatter.view_source(after, cam), rtol=1e-5, atol=1e-9)
    # and a warm solve of the new settings is a cold solve's (both to the panel's tolerance 1e-2)
    cold = scatter.solve(after.sigma, after.size, albedo=0.9, g=p.anisotropy, sun_dir=after.sun_dir,
                         sun_irradiance=after.sun_irradiance, sky_radiance=after.sky_radiance, tol=1e-2)
    assert abs(after.received.sum() / cold.received.sum() - 1) < 0.02


def test_live_update_off_and_headless(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    scene = empty_scene
    p, obj = _cloud(scene, tmp_path)
    p.live_update = False
    p.anisotropy = 0.5
    assert not frame.pending(obj) and frame.params(obj)["solve_task"]["solve"]["g"] == pytest.approx(0.8)
    p.live_update = True
    p.sun_elevation = 60.0  # headless: re-solved before the assignment returns
    assert frame.params(obj)["solve_task"]["solve"]["g"] == pytest.approx(0.5)
    sol = scatter.load_solution(tmp_path / "scatter" / "solution.npz")
    assert sol.sun_dir[2] == pytest.approx(np.sin(np.radians(60.0)), rel=1e-6) and sol.warm


def test_drifting_cloud_has_a_density_a_frame(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    p, obj = _cloud(empty_scene, tmp_path, frames=3, evolve="DRIFT")
    params = frame.params(obj)
    assert params["evolve"]["frames"] == 3 and "solve_task" not in params
    vdb = fileio.openvdb()
    dens = []
    for i in (1, 2, 3):
        arr = np.zeros((8, 8, 6), np.float32)
        vdb.read(str(tmp_path / "scatter" / f"scatter_{i:04d}.vdb"), "density").copyToArray(arr)
        dens.append(arr)
    assert np.abs(dens[1] - dens[0]).max() > 0 and np.abs(dens[2] - dens[1]).max() > 0
    assert "from the previous frame" in p.status
