"""The volume's transfer function edited as Blender's colour-ramp widget (issue 20: "not JSON")."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import frame, tf_ramp, volume_ops, volume_panel  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402


@pytest.fixture
def demo(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "user_cache"))
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    return empty_scene


def _same(a, b, values):
    return np.abs(a(values) - b(values)).max()


def test_switching_to_the_ramp_shows_the_threshold_function(demo):
    s = demo.nephele_volume
    s.threshold, s.full, s.opacity = 0.3, 0.8, 0.9
    before = volume_panel.panel_tf(s)
    s.tf_edit = "RAMP"
    node = tf_ramp.ramp_node(s.tf_tree)
    assert node is not None and node.color_ramp.interpolation == "LINEAR"
    assert (s.tf_min, s.tf_max) == pytest.approx((0.0, 0.8))
    after = volume_panel.panel_tf(s)
    v = np.linspace(-1, 2, 3001)
    assert _same(before, after, v) < 1e-6
    # The ramp is the one saved with the scene's volume settings (a user of the node group).
    assert s.tf_tree.users >= 1


def test_ramp_edits_are_the_transfer_function(demo):
    s = demo.nephele_volume
    s.tf_edit = "RAMP"
    s.tf_min, s.tf_max = 0.0, 2.0
    node = tf_ramp.ramp_node(s.tf_tree)
    els = node.color_ramp.elements
    els[0].position, els[0].color = 0.25, (0, 0, 0, 1)  # value 0.5 transparent
    els[1].position, els[1].color = 0.75, (0.6, 0.6, 0.6, 1)  # value 1.5 opacity 0.6
    mid = els.new(0.5)
    mid.color = (0.2, 0.2, 0.2, 1)  # value 1.0 opacity 0.2
    tf = volume_panel.panel_tf(s)
    truth = TransferFunction(points=((0.5, 0.0), (1.0, 0.2), (1.5, 0.6)))
    v = np.linspace(-1, 3, 4001)
    assert _same(tf, truth, v) < 1e-6
    # Constant: each element's opacity holds up to the next element (steps).
    node.color_ramp.interpolation = "CONSTANT"
    steps = volume_panel.panel_tf(s)
    assert steps(np.array([0.4, 0.6, 0.99, 1.01, 1.49, 1.6])) == pytest.approx([0, 0, 0, 0.2, 0.2, 0.6], abs=1e-6)
    # A smooth ramp is sampled finely enough to follow Blender's own evaluation.
    node.color_ramp.interpolation = "EASE"
    smooth = volume_panel.panel_tf(s)
    x = np.linspace(0, 1, 501)
    blender = np.array([sum(node.color_ramp.evaluate(float(t))[:3]) / 3 for t in x])
    assert np.abs(smooth(x * 2.0) - blender).max() < 5e-3


def test_a_range_that_does_not_rise_is_one_clear_error(demo):
    s = demo.nephele_volume
    s.tf_edit = "RAMP"
    s.tf_min, s.tf_max = 1.0, 1.0
    with pytest.raises(RuntimeError) as err:
        bpy.ops.nephele.add_volume_clouds()
    assert "Opacity ramp" in str(err.value) and "must rise" in str(err.value)


def test_ramp_edit_reaches_an_exact_volume_live(demo, tmp_path):
    s = demo.nephele_volume
    s.mode = volume_ops.EXACT
    s.directory = str(tmp_path / "vol")
    s.tf_edit = "RAMP"  # 0.3 -> 1.0 over [0, 1]
    assert bpy.ops.nephele.add_volume_clouds() == {"FINISHED"}
    obj = demo.objects[volume_ops.OBJECT_NAME]
    assert frame.params(obj)["tf"]["points"][0] == pytest.approx([0.3, 0.0])
    assert not volume_panel.stale(bpy.context)
    els = tf_ramp.ramp_node(s.tf_tree).color_ramp.elements
    els[0].position = 0.5  # threshold 0.5: inside the baked support, so the material applies it
    bpy.context.view_layer.update()  # the depsgraph update a ramp drag causes in the UI
    assert frame.params(obj)["tf"]["points"][0] == pytest.approx([0.5, 0.0])
    assert not volume_panel.stale(bpy.context)
    els[0].position = 0.1  # below what was baked: the panel asks for a re-bake
    bpy.context.view_layer.update()
    assert frame.params(obj)["tf"]["points"][0] == pytest.approx([0.5, 0.0])
    assert volume_panel.stale(bpy.context)


def test_panel_draws_the_ramp_widget(demo):
    from types import SimpleNamespace

    log = []

    class Layout:
        def __getattr__(self, name):
            def call(*args, **kwargs):
                log.append((name, args))
                if name == "prop":
                    assert hasattr(args[0], args[1]), args[1]
                return Layout()

            return call

    s = demo.nephele_volume
    ctx = SimpleNamespace(scene=demo, view_layer=bpy.context.view_layer)
    volume_panel.NEPHELE_PT_volume.draw(SimpleNamespace(layout=Layout()), ctx)
    drawn = {a[1] for n, a in log if n == "prop"}
    assert {"tf_edit", "threshold", "full", "opacity"} <= drawn and "tf_points" not in drawn
    s.tf_edit = "RAMP"
    log.clear()
    volume_panel.NEPHELE_PT_volume.draw(SimpleNamespace(layout=Layout()), ctx)
    ramps = [a for n, a in log if n == "template_color_ramp"]
    assert ramps and ramps[0][0] == tf_ramp.ramp_node(s.tf_tree) and ramps[0][1] == "color_ramp"
    assert {"tf_min", "tf_max"} <= {a[1] for n, a in log if n == "prop"}
