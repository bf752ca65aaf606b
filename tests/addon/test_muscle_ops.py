"""Add muscle film: operator, frame updater, tiling, camera, a tiny Cycles render and the Omnimax example."""

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import frame, muscle_ops  # noqa: E402
from nephele.addon.mesh import point_attribute  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def ops(empty_scene):
    # The add-on (registered by the conftest's empty_scene) brings the operator.
    yield


def test_operator_adds_film_that_follows_the_frame(ops, tmp_path):
    scene = bpy.context.scene
    assert bpy.ops.nephele.add_muscle_film(frames=3, spacing=1.5, tiles=(2, 1, 1)) == {"FINISHED"}
    obj = bpy.data.objects[muscle_ops.OBJECT_NAME]
    p = frame.params(obj)
    assert p["kind"] == "muscle" and p["film"]["frames"] == 3
    assert len(obj.data.polygons) > 1000 and obj.get("nephele_shown") == 0
    mol = point_attribute(obj.data, "molecule")
    assert set(np.unique(np.round(mol))) == {0, 1, 2, 3, 4}
    assert [m.type for m in obj.modifiers] == ["ARRAY"]
    assert scene.camera.name == muscle_ops.CAMERA_NAME
    assert (scene.frame_start, scene.frame_end) == (1, 3)
    before = np.array([v.co[:] for v in obj.data.vertices[:50]])
    frame.install()
    scene.frame_set(3)
    assert obj.get("nephele_shown") == 2
    after = np.array([v.co[:] for v in obj.data.vertices[:50]])
    assert not np.array_equal(before, after)
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", 2
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 48, 36, 100
    img = tmp_path / "muscle.png"
    scene.render.filepath = str(img)
    bpy.ops.render.render(write_still=True)
    px = np.array(bpy.data.images.load(str(img)).pixels[:]).reshape(36, 48, 4)[..., :3]
    assert px.std() > 0.02 and px.max() > 0.1


def test_bad_tiles_rejected():
    with pytest.raises(ValueError, match="tiles"):
        muscle_ops.add_muscle_film(frames=1, spacing=2.0, tiles=(0, 1, 1))


def test_example_renders_omnimax_stereo(tmp_path):
    sys.path.insert(0, str(EXAMPLES))
    try:
        import fig7_muscle
    finally:
        sys.path.remove(str(EXAMPLES))
    from nephele.addon import dome_ops

    fig7_muscle.build(film_frames=1, spacing=2.0, tiles=(1, 1, 1), dome="omnimax", stereo=True, size=(48, 36),
                      samples=2)
    paths = dome_ops.render_dome_frame(tmp_path / "omni.png")
    assert [p.name for p in paths] == ["omni_L.png", "omni_R.png"]
    eyes = [np.array(bpy.data.images.load(str(p)).pixels[:]).reshape(36, 48, 4)[..., :3] for p in paths]
    assert all(e.std() > 0.02 for e in eyes)
    assert not np.array_equal(eyes[0], eyes[1])


def test_example_main_denoises_and_writes_the_red_cyan_anaglyph(tmp_path):
    sys.path.insert(0, str(EXAMPLES))
    try:
        import fig7_muscle
    finally:
        sys.path.remove(str(EXAMPLES))
    from nephele.core.camera.anaglyph import grey
    from nephele.fileio import read_image

    with pytest.raises(SystemExit) as exc:
        fig7_muscle.main(["--out", str(tmp_path), "--anaglyph", "half"])  # no stereo pair to combine
    assert exc.value.code == 2
    assert fig7_muscle.main(["--out", str(tmp_path), "--dome", "--stereo", "--anaglyph", "grey", "--size", "48", "36",
                             "--spacing", "2.0", "--film-frames", "1", "--samples", "2", "--denoise",
                             "--bounces", "2"]) == 0
    c = bpy.context.scene.cycles
    assert c.use_denoising and c.denoiser == "OPENIMAGEDENOISE" and c.denoising_input_passes == "RGB_ALBEDO_NORMAL"
    assert (c.samples, c.max_bounces, c.diffuse_bounces, c.glossy_bounces, c.transmission_bounces) == (2, 2, 2, 2, 2)
    left, right, ana = (read_image(tmp_path / f"fig7_omnimax_0001_{s}.png")[..., :3] for s in ("L", "R", "anaglyph"))
    assert ana.shape == (36, 48, 3) and left.std() > 0.02 and not np.array_equal(left, right)
    # 8-bit files: the anaglyph's grey of each eye is within half a step of the grey of the eye's file
    np.testing.assert_allclose(ana[..., 0], grey(left), atol=0.51 / 255)
    np.testing.assert_allclose(ana[..., 1], grey(right), atol=0.51 / 255)
    assert np.array_equal(ana[..., 1], ana[..., 2])


def test_adding_the_film_in_the_interface_does_not_wait_for_the_simulation(ops, tmp_path, monkeypatch):
    """Issue 20 ("never freeze"): the first frame needs the simulation up to it; in the interface
    (forced headless with frame.force_background_jobs) it runs on the worker thread."""
    from nephele.core.muscle import film

    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache")
    film._SIMS.clear()
    scene = bpy.context.scene
    frame.force_background_jobs(True)
    try:
        obj = muscle_ops.add_muscle_film(frames=3, spacing=2.0, tiles=(1, 1, 1), scene=scene)
        assert len(obj.data.polygons) == 0 and frame.busy()  # returned before the simulation ran
        assert scene.camera.name == muscle_ops.CAMERA_NAME
        assert frame.wait(300)
        assert obj.get("nephele_shown") == 0 and len(obj.data.polygons) > 500
        background = np.array([v.co[:] for v in obj.data.vertices])
    finally:
        frame.cancel_all()
        frame.wait(120)
        frame.force_background_jobs(False)
    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache_sync")  # computed again, here
    obj = muscle_ops.add_muscle_film(frames=3, spacing=2.0, tiles=(1, 1, 1), scene=scene)
    np.testing.assert_array_equal(np.array([v.co[:] for v in obj.data.vertices]), background)
