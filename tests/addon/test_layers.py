"""Editable layers (issue 20): parameters edited after adding, names, empty results, stale layers."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import contour_ops, data_ops, frame, layers  # noqa: E402


@pytest.fixture
def scene(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(frame, "results_dir", lambda: tmp_path / "cache")
    data_ops.set_settings(empty_scene, source="demo:small", hours_per_frame=1.0)
    empty_scene.frame_set(13)
    return empty_scene


def _verts(obj):
    v = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.attributes["position"].data.foreach_get("vector", v)
    return v.reshape(-1, 3)


def test_a_second_contour_at_015_keeps_its_level_in_the_name(scene):
    a = contour_ops.add_contour("cloud", 0.15, scene=scene)
    b = contour_ops.add_contour("cloud", 0.15, scene=scene)
    assert a.name == "Contour cloud [0.15]"
    assert b.name.startswith("Contour cloud [0.15]") and b.name != a.name
    assert "0.001" not in b.name.replace("[0.15].001", "")


def test_level_change_on_an_existing_contour_changes_its_mesh(scene):
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    before = _verts(obj)
    obj.nephele_layer.level = 0.5
    after = _verts(obj)
    assert frame.params(obj)["level"] == 0.5
    assert obj.name == "Contour cloud [0.5]"
    assert len(after) > 0 and len(after) != len(before)
    # The new mesh is the level-0.5 surface: the same as a fresh contour at 0.5.
    fresh = contour_ops.add_contour("cloud", 0.5, scene=scene)
    np.testing.assert_array_equal(after, _verts(fresh))
    # A renamed layer keeps the user's name.
    obj.name = "My clouds"
    obj.nephele_layer.level = 0.15
    assert obj.name == "My clouds"
    np.testing.assert_array_equal(_verts(obj), before)


def test_variable_colour_and_ramp_edits(scene):
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    lay = obj.nephele_layer
    assert lay.var == "cloud" and lay.color_var == "altitude" and lay.ramp == "altitude"
    lay.color_var = "temperature"
    mat = obj.data.materials[0]
    assert mat.node_tree.nodes["Nephele attribute"].attribute_name == "temperature"
    assert "temperature" in obj.data.attributes  # recomputed with the new colour field
    assert tuple(lay.color_range) == pytest.approx((220.0, 300.0))
    lay.color_range = (230.0, 290.0)
    rng = mat.node_tree.nodes["Nephele range"]
    assert rng.inputs["From Min"].default_value == pytest.approx(230.0)
    lay.ramp = "viridis"
    stops = mat.node_tree.nodes["Nephele ramp"].color_ramp.elements
    assert len(stops) == 5 and frame.params(obj)["ramp"] == "viridis"


def test_data_range_and_histogram_hint(scene):
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    st = contour_ops.stats_of(obj)
    assert st["min"] == pytest.approx(0.0, abs=1e-6) and 0.5 < st["max"] <= 1.0 + 1e-6
    assert sum(st["hist"]) == int(np.prod(data_ops.dataset(scene=scene).grid.shape))
    text, icon = layers.range_line(st, 0.15)
    assert icon == "INFO" and len(layers.histogram_hint(st)) == contour_ops.HIST_BINS
    assert layers.range_line(st, 7.0)[1] == "ERROR"
    # The share of cells above the level, from the histogram: close to the exact share.
    values = data_ops.dataset(scene=scene).read_at("cloud", obj["nephele_hours"])
    for level in (0.15, 0.5):
        exact = float(np.mean(values > level))
        assert abs(layers.share_above(st, level) - exact) < 0.05
    assert f"~{100 * layers.share_above(st, 0.15):.0f}% above" in text


def test_empty_result_is_a_warning_naming_the_range(scene, capfd):
    # Headless, Blender prints an operator's reports as "<Type>: <message>".
    assert bpy.ops.nephele.add_contour(var="cloud", level=5.0) == {"FINISHED"}
    out = capfd.readouterr().out
    assert "Warning: Contour cloud [5]: no surface at cloud = 5 at 12 h; the data range is 0 to 1" in out
    assert "Info:" not in out
    assert bpy.ops.nephele.add_contour(var="cloud", level=0.15) == {"FINISHED"}
    assert "Info: Contour cloud [0.15]: " in capfd.readouterr().out


def test_stale_layers_after_a_dataset_change_and_update(scene):
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    assert layers.stale_keys(obj, scene) == []
    data_ops.set_settings(scene, hours_per_frame=2.0)
    assert layers.stale_keys(obj, scene) == ["hours_per_frame"]
    assert bpy.ops.nephele.sync_layers() == {"FINISHED"}
    assert layers.stale_keys(obj, scene) == []
    assert obj["nephele_hours"] == pytest.approx(24.0)  # frame 13 at 2 h per frame


def test_layer_list_select_and_delete(scene):
    a = contour_ops.add_contour("cloud", 0.15, scene=scene)
    b = contour_ops.add_contour("cloud", 0.5, scene=scene)
    assert layers.scene_layers(scene) == [a, b]
    scene.nephele_layers.index = list(scene.objects).index(a)
    assert bpy.context.view_layer.objects.active == a and a.select_get() and not b.select_get()
    assert scene.nephele_layers.index == list(scene.objects).index(a)
    bpy.ops.mesh.primitive_cube_add()  # not a layer: the list leaves it out
    ul = layers.NEPHELE_UL_layers
    from types import SimpleNamespace

    flags, order = ul.filter_items(SimpleNamespace(bitflag_filter_item=1 << 30), bpy.context, scene, "objects")
    assert [o.name for o, f in zip(scene.objects, flags) if f] == [a.name, b.name] and order == []
    log = []
    ul.draw_item(ul, bpy.context, _Layout(log), scene, a, 0, None, "index", 0)
    assert {"name", "hide_viewport", "hide_render"} <= {x[1] for n, x, _ in log if n == "prop"}
    assert ("nephele.delete_layer",) in [x for n, x, _ in log if n == "operator"]
    mesh_name = b.data.name
    assert bpy.ops.nephele.delete_layer(name=b.name) == {"FINISHED"}
    assert layers.scene_layers(scene) == [a] and mesh_name not in bpy.data.meshes


class _Layout:
    """Stands in for a panel's layout headless: records every prop/label/operator drawn."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.log.append((name, args, kwargs))
            if name == "prop":  # the property must exist on the data it is drawn from
                assert hasattr(args[0], args[1]), args[1]
            return _Layout(self.log)

        return call


def _draw(panel, scene, obj):
    from types import SimpleNamespace

    log = []
    fake = SimpleNamespace(layout=_Layout(log), _draw_layer=layers.NEPHELE_PT_layers._draw_layer)
    panel.draw(fake, SimpleNamespace(scene=scene, active_object=obj, view_layer=bpy.context.view_layer))
    props = {a[1] for name, a, _ in log if name == "prop"}
    labels = " | ".join(k.get("text", "") for name, _, k in log if name == "label")
    return props, labels


def test_panels_draw_the_selected_layer(scene):
    from nephele.addon import advect_ops

    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    props, labels = _draw(layers.NEPHELE_PT_layers, scene, obj)
    assert {"var", "level", "color_var", "ramp", "color_range"} <= props
    assert "data 0 … 1" in labels and "stale" not in labels
    assert "12000 m" in labels  # the legend: the altitude ramp's top value
    props, labels = _draw(contour_ops.NEPHELE_PT_contour, scene, obj)
    assert {"var", "level"} <= props and "data 0 … 1" in labels
    data_ops.set_settings(scene, hours_per_frame=3.0)
    assert "stale hours_per_frame" in _draw(layers.NEPHELE_PT_layers, scene, obj)[1]
    advect_ops.add_advected_texture(obj, scene=scene)
    assert "opacity_range" in _draw(layers.NEPHELE_PT_layers, scene, obj)[0]
    obj.nephele_layer.opacity_range = (0.1, 0.5)
    node = obj.data.materials[0].node_tree.nodes["Nephele opacity"]
    assert node.inputs["From Min"].default_value == pytest.approx(0.1)
    assert node.inputs["From Max"].default_value == pytest.approx(0.5)


def test_volume_threshold_edits_live_within_the_baked_support(scene, tmp_path):
    from nephele.addon import volume_ops
    from nephele.core.volume.transfer import TransferFunction

    scene.frame_start, scene.frame_end = 13, 13
    obj, _ = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(0.3, 1.0), directory=str(tmp_path / "vol"),
                                          scene=scene, frames=(13, 13), mode=volume_ops.EXACT)
    lay = obj.nephele_layer
    assert lay.threshold == pytest.approx(0.3)
    lay.threshold = 0.5  # inside what was baked: the material applies it at once
    assert frame.params(obj)["tf"]["points"][0] == pytest.approx([0.5, 0.0])
    assert "nephele_needs_bake" not in obj and obj.data.materials[0] is not None
    props, labels = _draw(layers.NEPHELE_PT_layers, scene, obj)
    assert "threshold" in props and "0.5→0" in labels
    # The data range beside the threshold comes from a thread: the panel never waits for it.
    import time

    t_end = time.time() + 60
    while "data 0 … 1" not in labels and time.time() < t_end:
        time.sleep(0.05)
        labels = _draw(layers.NEPHELE_PT_layers, scene, obj)[1]
    assert "above the threshold" in labels
    lay.threshold = 0.1  # below the baked support: needs a new bake, and the panel says so
    assert frame.params(obj)["tf"]["points"][0] == pytest.approx([0.5, 0.0])
    assert "re-bake" in obj["nephele_needs_bake"]
    assert "re-bake" in _draw(layers.NEPHELE_PT_layers, scene, obj)[1]


def test_empty_variable_is_a_warning(scene, capfd):
    from nephele.core.climate.dataset import ArrayDataset
    from nephele.core.pipeline.sources import open_source, register_source

    ds = open_source("demo:small")
    fields = {"cloud": np.full((2,) + ds.grid.shape, np.nan, np.float32),
              "temperature": np.full((2,) + ds.grid.shape, 250.0, np.float32)}
    src = register_source("test_layers:empty", ArrayDataset(ds.grid, ds.times[:2], fields))
    data_ops.set_settings(scene, source=src)
    scene.frame_set(1)
    assert bpy.ops.nephele.add_contour(var="cloud", level=0.15) == {"FINISHED"}
    assert "Warning: Contour cloud [0.15]: cloud has no finite values at 0 h: the surface is empty" in (
        capfd.readouterr().out)
    obj = contour_ops.add_contour("temperature", 260.0, scene=scene)  # constant field, level above it
    assert contour_ops.empty_message(obj).endswith("the data range is 250 to 250")
