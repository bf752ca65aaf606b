"""Add scattering cloud: solve in steps, per-frame VDBs, Cycles renders what the core computes."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele import fileio  # noqa: E402
from nephele.addon import scatter_scene as ss  # noqa: E402
from nephele.addon.scatter_jobs import ScatterJob  # noqa: E402
from nephele.core.light import scatter  # noqa: E402


def _setup(scene, tmp_path, frames=2):
    p = scene.nephele_scatter
    p.resolution = (8, 8, 6)
    p.directory = str(tmp_path / "scatter")
    p.tolerance = 1e-2
    scene.frame_start, scene.frame_end = 1, frames
    return p


def test_panel_and_operator_registered(empty_scene):
    assert hasattr(bpy.types, "NEPHELE_PT_scatter")
    assert bpy.types.NEPHELE_PT_scatter.bl_parent_id == "NEPHELE_PT_main"
    assert hasattr(bpy.ops.nephele, "add_scattering_cloud")


def test_operator_writes_volume_sequence(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    scene = empty_scene
    _setup(scene, tmp_path, frames=2)
    assert bpy.ops.nephele.add_scattering_cloud() == {"FINISHED"}
    obj = bpy.data.objects[ss.OBJECT_NAME]
    vol = obj.data
    assert vol.is_sequence and vol.frame_start == 1 and vol.frame_duration == 2
    files = sorted((tmp_path / "scatter").glob("scatter_*.vdb"))
    assert [f.name for f in files] == ["scatter_0001.vdb", "scatter_0002.vdb"]
    vol.grids.load()
    assert {g.name for g in vol.grids} == {"density", "emission"}
    assert scene.camera is not None  # the orbit camera
    assert "converged" in scene.nephele_scatter.status
    sol = scatter.load_solution(tmp_path / "scatter" / "solution.npz")
    # the emission grid of frame 2 is the core's source toward frame 2's camera
    vdb = fileio.openvdb()
    grid = vdb.read(str(files[1]), "emission")
    arr = np.zeros(sol.sigma.shape[::-1], np.float32)
    grid.copyToArray(arr)
    scene.frame_set(2)
    cam = np.array(scene.camera.matrix_world.translation) - np.array(obj.location)
    np.testing.assert_allclose(arr.transpose(2, 1, 0), scatter.view_source(sol, cam), rtol=1e-5, atol=1e-9)
    # the farm's plan for the object is the solve the operator ran, already in the cache
    from nephele.addon import frame
    from nephele.core.pipeline import cache, tasks

    kind, params = tasks.plan(frame.params(obj), 2)[0]
    cached = cache.Cache(tmp_path / "cache").load(kind, params)
    np.testing.assert_array_equal(scatter.solution_from_arrays(cached).received, sol.received)


def test_job_runs_in_small_steps(empty_scene, tmp_path):
    import time

    scene = empty_scene
    p = _setup(scene, tmp_path, frames=3)
    job = ScatterJob(bpy.context, p)
    fractions, longest = [], 0.0
    for _ in range(10000):
        t = time.perf_counter()
        done = job.step(budget=0.0)  # one unit of work per call
        longest = max(longest, time.perf_counter() - t)
        fractions.append(job.fraction)
        if done:
            break
    assert done and job.obj is not None
    assert len(fractions) > 10  # many small steps: the interface gets control back often
    assert fractions[-1] >= max(fractions[:-1])
    assert fractions[-1] == pytest.approx(1.0)
    assert "passes" in job.status


def test_operator_solves_on_finer_bins(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    p = _setup(empty_scene, tmp_path, frames=1)
    p.bins_per_face = 6
    assert bpy.ops.nephele.add_scattering_cloud() == {"FINISHED"}
    sol = scatter.load_solution(tmp_path / "scatter" / "solution.npz")
    assert sol.bins_per_face == 6 and sol.received.shape[0] == 216
    p.bins_per_face = 5  # odd: refused before any work
    with pytest.raises(RuntimeError, match="even"):
        bpy.ops.nephele.add_scattering_cloud()


@pytest.mark.slow
def test_cycles_renders_the_emission_volume_like_the_core(empty_scene, tmp_path):
    """Cycles' emission-absorption render of the written grids = the core's ray march."""
    sigma = 30.0 * (np.indices((6, 8, 8)).sum(0) % 3 == 0) + 5.0
    sol = scatter.solve(sigma, (1, 1, 0.75), sun_dir=(0.3, -0.2, 1.0), tol=1e-2)
    cam = scatter.orbit_camera(0.7, (1, 1, 0.75), width=32, height=24, distance=1.4)
    src = scatter.view_source(sol, cam.position)
    ours = scatter.render(sigma, src, (1, 1, 0.75), cam, step=0.2)
    ss.add_camera(cam)
    ss.black_world()
    fileio.write_vdb(tmp_path / "ea.vdb", fileio.dense_grids({"density": sigma, "emission": src}, (1, 1, 0.75)))
    obj = ss._volume_object("ea", tmp_path / "ea.vdb")
    obj.data.materials.append(ss.emission_material())
    ss.cycles_settings(empty_scene, 64)
    img = ss.render_array(empty_scene, tmp_path / "ea.exr")
    assert img.mean() == pytest.approx(ours.mean(), rel=0.03)
