"""Never freeze (issue 20): frame jumps on an advected contour return at once and finish in the background.

The interface path is forced headless with ``frame.force_background_jobs``;
the timer loop is driven by ``frame.wait`` (what ``bpy.app.timers`` runs).
"""

import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import advect_ops, contour_ops, data_ops, frame  # noqa: E402
from nephele.core.flow import advect, advect_task  # noqa: E402

LAST = 241  # demo:small has 48 hourly steps: at 0.2 h per frame, frame 241 is hour 47 (the last)


@pytest.fixture
def advected(empty_scene, tmp_path, monkeypatch):
    """An advected contour of demo:small shown at frame 1, with its own empty cache."""
    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache")
    scene = empty_scene
    data_ops.set_settings(scene, source="demo:small", hours_per_frame=0.2)
    scene.frame_start, scene.frame_end = 1, LAST
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    advect_ops.add_advected_texture(obj, scene=scene)
    advect_task._STRATEGIES.clear()  # the jump starts from a fresh stream, like a new session
    yield scene, obj
    frame.cancel_all()
    frame.wait(120)
    frame.force_background_jobs(False)


def _mesh(obj):
    me = obj.data
    v = np.empty(3 * len(me.vertices), np.float32)
    me.attributes["position"].data.foreach_get("vector", v)
    start = np.empty(3 * len(me.vertices), np.float32)
    me.attributes[advect.START.format("a")].data.foreach_get("vector", start)
    return v.reshape(-1, 3), start.reshape(-1, 3)


def test_jump_returns_at_once_and_completes_in_background(advected, tmp_path, monkeypatch):
    scene, obj = advected
    before, _ = _mesh(obj)
    frame.force_background_jobs(True)
    t0 = time.perf_counter()
    scene.frame_set(LAST)
    returned = time.perf_counter() - t0
    # The call came back before the work was done, showing the last good result meanwhile.
    assert frame.busy()
    assert obj["nephele_hours"] == 0.0
    np.testing.assert_array_equal(_mesh(obj)[0], before)
    assert returned < 0.2, f"frame_set took {returned:.3f} s"
    assert frame.wait(300)
    done = time.perf_counter() - t0
    assert obj["nephele_hours"] == 47.0
    bg_v, bg_start = _mesh(obj)
    print(f"jump to frame {LAST}: returned in {returned * 1e3:.1f} ms, finished in {done:.2f} s")

    # The same frame on the synchronous path (headless, renders), from nothing cached.
    frame.force_background_jobs(False)
    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache_sync")
    advect_task._STRATEGIES.clear()
    obj.pop("nephele_shown")
    frame.update_scene(scene)
    assert not frame.busy()
    sync_v, sync_start = _mesh(obj)
    assert sync_v.shape == bg_v.shape and len(sync_v) > 100
    np.testing.assert_array_equal(sync_v, bg_v)
    np.testing.assert_allclose(sync_start, bg_start, rtol=0, atol=1e-6)


def test_headless_frame_change_is_synchronous(advected):
    scene, obj = advected
    scene.frame_set(25)
    assert not frame.busy()
    assert obj["nephele_hours"] == pytest.approx(4.8)


def test_cancel_keeps_the_last_result_and_a_later_request_completes(advected):
    scene, obj = advected
    frame.force_background_jobs(True)
    scene.frame_set(LAST)
    assert frame.cancel_all() >= 1
    assert frame.wait(300)
    assert obj["nephele_hours"] == 0.0  # cancelled: the old frame stays
    scene.frame_set(30)
    assert frame.wait(300)
    assert obj["nephele_hours"] == pytest.approx(5.8)


def test_newest_frame_wins(advected):
    scene, obj = advected
    frame.force_background_jobs(True)
    for f in (60, 120, 180, LAST):  # scrubbing: only the last request must end up shown
        scene.frame_set(f)
    assert frame.wait(300)
    assert obj["nephele_hours"] == 47.0
    # ... and it is exactly the last frame: planning it again finds nothing to do.
    assert frame.JOBS[advect_ops.KIND].plan(obj, frame.params(obj), scene, LAST) is None


def test_rendering_and_suspension(advected):
    scene, obj = advected
    frame.force_background_jobs(True)
    frame._on_render_init()
    try:
        assert frame.synchronous()
        scene.frame_set(13)  # while rendering: exact, at once
        assert not frame.busy() and obj["nephele_hours"] == pytest.approx(2.4)
    finally:
        frame._on_render_end()
    assert not frame.synchronous()
    scene.frame_set(LAST)
    assert frame.busy()
    frame._on_render_init(scene)  # a render started from the interface: the frame is finished first
    try:
        assert obj["nephele_hours"] == 47.0
    finally:
        frame._on_render_end()
    frame.wait(60)
    with frame.suspended():  # e.g. stepping frames only to move a camera: no layer work at all
        scene.frame_set(13)
    assert not frame.busy() and obj["nephele_hours"] == 47.0


def test_disable_removes_handlers_and_timer(advected):
    import nephele

    scene, obj = advected
    frame.force_background_jobs(True)
    scene.frame_set(LAST)
    nephele.unregister()
    try:
        names = {getattr(h, "__name__", "") for hs in (bpy.app.handlers.frame_change_pre, bpy.app.handlers.render_init,
                                                        bpy.app.handlers.render_complete) for h in hs}
        assert not names & {fn.__name__ for _, fn in frame._HANDLERS}
        assert not bpy.app.timers.is_registered(frame._poll)
        assert not hasattr(bpy.types.Object, "nephele_layer")
    finally:
        nephele.register()


def test_adding_a_layer_does_not_block_the_interface(empty_scene, tmp_path, monkeypatch, capfd):
    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache")
    scene = empty_scene
    data_ops.set_settings(scene, source="demo:small", hours_per_frame=1.0)
    scene.frame_set(13)
    frame.force_background_jobs(True)
    try:
        obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
        assert frame.pending(obj) and len(obj.data.vertices) == 0  # the mesh comes later
        assert frame.wait(120) and not frame.pending(obj) and len(obj.data.vertices) > 100
        # The operator (here without a window) reports on the finished result, not the empty placeholder.
        assert bpy.ops.nephele.add_contour(var="cloud", level=0.3) == {"FINISHED"}
        assert "Info: Contour cloud [0.3]: " in capfd.readouterr().out
        assert bpy.ops.nephele.add_contour(var="cloud", level=3.0) == {"FINISHED"}
        assert "Warning: Contour cloud [3]: no surface at cloud = 3 at 12 h; the data range is 0 to 1" in (
            capfd.readouterr().out)
    finally:
        frame.cancel_all()
        frame.wait(60)
        frame.force_background_jobs(False)
