"""The artist's workflow (issue 20): bounds where values are set, memory checked before
allocating, clear messages, and a clean disable."""

import tracemalloc

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import data_ops, frame, volume_ops, volume_panel  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402
from nephele.core.memory import check_memory  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402


@pytest.fixture
def demo(empty_scene):
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    return empty_scene



@pytest.fixture(autouse=True)
def _own_cache(tmp_path, monkeypatch):
    # Unsaved scenes write into a session folder under the user cache: keep the tests' in tmp.
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "user_cache"))

def test_panel_values_are_bounded_where_they_are_set(demo):
    d = demo.nephele_data
    # The custom get/set bypassed min/max: -5, 0 h and 1e6 were stored as given.
    d.exaggeration = -5.0
    assert d.exaggeration == 0.0
    d.exaggeration = 1e6
    assert d.exaggeration == data_ops.BOUNDS["exaggeration"][1]
    d.hours_per_frame = 0.0
    assert d.hours_per_frame == pytest.approx(data_ops.BOUNDS["hours_per_frame"][0])
    d.hours_per_frame = -3.0
    assert d.hours_per_frame > 0
    d.radius = 0.0
    assert d.radius > 0
    # The mirror (what every layer reads) holds the bounded values too.
    cfg = data_ops.settings(demo)
    assert cfg["exaggeration"] == 500.0 and cfg["hours_per_frame"] > 0 and cfg["radius"] > 0
    # Scripts get a refusal naming the setting and its bounds, and nothing changes.
    before = data_ops.settings(demo)
    for key, bad in (("exaggeration", 1e6), ("exaggeration", -1.0), ("hours_per_frame", 0.0),
                     ("hours_per_frame", float("nan")), ("radius", -2.0)):
        with pytest.raises(DataError, match=f"'{key}'.*between"):
            data_ops.set_settings(demo, **{key: bad})
    assert data_ops.settings(demo) == before


def test_huge_exaggeration_refused_before_allocating(demo, tmp_path):
    # The issue: 1e6 was accepted and Add volume clouds then took 24 GB and was killed.
    tracemalloc.start()
    try:
        with pytest.raises(DataError, match="exaggeration"):
            volume_ops.add_volume_clouds("cloud", exaggeration=1e6, scene=demo, directory=str(tmp_path / "a"))
        # Within the bounds, a request beyond the machine's memory is refused by the
        # estimate, with the numbers and what to change.
        with pytest.raises(DataError, match="memory.*available") as err:
            volume_ops.add_volume_clouds("cloud", support_size=1e-5, scene=demo, directory=str(tmp_path / "b"))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "support voxel" in str(err.value)
    # Nothing beyond reading one step of the 64x32x8 demo (a few MB) was allocated, nothing written.
    assert peak < 50e6, peak
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert volume_ops.OBJECT_NAME not in bpy.data.objects
    # The same estimate at an injected small machine.
    ds = data_ops.dataset(scene=demo)
    est = volume_ops.bake_estimate(ds, "cloud", TransferFunction.ramp(0.3, 1.0), exaggeration=30.0)
    # demo:small, exact mode: measured 1.04 M support voxels, 61 MB peak, 0.9 MB on disk.
    assert 0.5e6 < est["voxels"] < 2e6 and 30e6 < est["memory"] < 130e6 and 0.4e6 < est["disk"] < 2e6
    with pytest.raises(DataError, match="memory"):
        check_memory(est["memory"], "test", available=est["memory"] / 2)
    # The scattering grid too, before the density is built.
    sc = demo.nephele_scatter
    sc.resolution = (512, 512, 512)
    with pytest.raises(RuntimeError, match="scattering solve.*memory"):
        bpy.ops.nephele.add_scattering_cloud()


def test_bake_defaults_to_the_current_frame_and_says_what_more_costs(demo, tmp_path):
    s = demo.nephele_volume
    assert s.current_only  # the issue: the default baked all 240 frames (204 s, 498 MB)
    demo.frame_set(5)
    assert volume_panel.bake_frames(bpy.context, s) == (5, 5)
    s.current_only = False
    s.frame_count = 10
    assert volume_panel.bake_frames(bpy.context, s) == (5, 14)
    frames, est = volume_panel.panel_estimate(bpy.context, s)
    text = volume_panel.estimate_text(frames, est)
    assert text.startswith("10 frames (5-14): about ") and "MB on disk" in text and "memory" in text
    s.frame_count = 100000  # clipped to the data's time span (48 hourly steps from frame 1)
    assert volume_panel.bake_frames(bpy.context, s) == (5, 48)


def test_bad_transfer_function_json_gets_a_clear_message(demo):
    s = demo.nephele_volume
    s.tf_edit = "POINTS"
    for text in ("[[0.3, 0], [1, 1", '{"a": 1}', "[[1, 2, 3]]"):
        s.tf_points = text
        with pytest.raises(RuntimeError) as err:
            bpy.ops.nephele.add_volume_clouds()
        msg = str(err.value)
        assert "TF points" in msg and "[value, opacity]" in msg
        assert "Expecting" not in msg and "delimiter" not in msg  # not the parser's own words


def test_empty_volume_warning_gives_the_data_range(demo, tmp_path):
    obj, _ = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(1.5, 2.0), scene=demo,
                                          directory=str(tmp_path), frames=(1, 1))
    p = frame.params(obj)
    lo, hi = p["value_range"]
    assert p["empty"] and 0.0 <= lo < hi < 1.5
    msg = volume_ops.empty_message(p)
    assert f"data range {lo:g} to {hi:g}" in msg and "threshold 1.5" in msg


def test_volume_hidden_in_a_contour_is_said(demo, tmp_path):
    assert bpy.ops.nephele.add_contour(var="cloud", level=0.15) == {"FINISHED"}
    obj, _ = volume_ops.add_volume_clouds("cloud", scene=demo, directory=str(tmp_path), frames=(1, 1), mode="voxels",
                                          voxel_size=0.02)
    lines = volume_ops.look_warnings(demo, obj)
    assert any("hides the clouds" in line and "0.15" in line for line in lines)


def _nephele_handlers():
    return [f"{h}: {f.__module__}.{f.__name__}" for h in dir(bpy.app.handlers) if not h.startswith("_")
            and isinstance(getattr(bpy.app.handlers, h), list) for f in getattr(bpy.app.handlers, h)
            if "nephele" in getattr(f, "__module__", "")]


def test_disable_leaves_no_handler_and_enable_works_again(empty_scene):
    import nephele

    assert any("save_pre" in h for h in _nephele_handlers())
    assert any("render_pre" in h for h in _nephele_handlers())
    nephele.unregister()
    try:
        assert _nephele_handlers() == []
        assert not hasattr(bpy.types, "NEPHELE_PT_main")
        assert not [p.identifier for p in bpy.types.Scene.bl_rna.properties if p.identifier.startswith("nephele")]
        assert not [n for n in dir(bpy.ops.nephele) if not n.startswith("_")]
        # bpy.app.timers: none of Nephele's left running.
        from nephele.addon import flowvol_ops

        assert not bpy.app.timers.is_registered(flowvol_ops._rebuild_later)
    finally:
        nephele.register()
    handlers = _nephele_handlers()
    assert len(handlers) == len(set(handlers))  # once each, not twice
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    assert np.isfinite(data_ops.settings(empty_scene)["exaggeration"])
