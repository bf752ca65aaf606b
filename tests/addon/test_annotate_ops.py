"""The annotation layer: the model time of each frame in the data's calendar, the layers' legend, the compositor."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import annotate_ops, contour_ops, data_ops, frame  # noqa: E402
from nephele.core.annotate import time_label  # noqa: E402
from nephele.core.climate.synthetic import demo_dataset  # noqa: E402
from nephele.core.pipeline.sources import frame_hours, register_source  # noqa: E402
from nephele.fileio import read_image  # noqa: E402


def _scene_with_contour(source, hours_per_frame=3.0, frame_start=1):
    scene = bpy.context.scene
    data_ops.set_settings(scene, source=source, hours_per_frame=hours_per_frame, frame_start=frame_start)
    scene.frame_start, scene.frame_end = frame_start, frame_start + 15
    scene.frame_set(frame_start)
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    return scene, obj


def test_time_is_the_datasets_time_at_each_frame():
    scene, _ = _scene_with_contour("demo:small", hours_per_frame=3.0, frame_start=5)
    ds = data_ops.dataset("demo:small")
    ann = annotate_ops.add_annotations(scene, figure="fig1")
    for f in (5, 6, 9, 13, 20, 40):  # 40: past the data's 47 h, held at the last step like the layers
        scene.frame_set(f)
        hours = frame_hours(f, 5, 3.0, last_hour=float(ds.hours[-1]))
        step = int(round(hours))
        assert ann["nephele_annotation_time"] == str(np.datetime64(ds.times[step], "m")).replace("T", " ")
    assert ann["nephele_annotation_time"] == "1987-01-02 23:00"


def test_time_in_a_360_day_calendar():
    cftime = pytest.importorskip("cftime")
    ds = demo_dataset("small")
    # A model calendar: elapsed time from 58 days before the first step, labelled in 360-day months.
    ds.calendar, ds.time_origin = "360_day", ds.times[0] - np.timedelta64(58 * 86400, "s")
    register_source("memory:cal360", ds)
    scene, _ = _scene_with_contour("memory:cal360", hours_per_frame=6.0)
    ann = annotate_ops.add_annotations(scene, figure="fig4")
    units = "hours since 1986-11-04 00:00:00"  # the origin, 1987-01-01 less 58 days
    assert str(ds.time_origin) == "1986-11-04T00:00:00"
    seen = []
    for f in range(1, 9):
        scene.frame_set(f)
        truth = cftime.num2date(58 * 24 + (f - 1) * 6.0, units, "360_day").strftime("%Y-%m-%d %H:%M")
        assert ann["nephele_annotation_time"] == truth == time_label(ds, (f - 1) * 6.0)
        seen.append(truth)
    assert seen[0] == "1987-01-02 00:00"  # 58 days after 4 November in 30-day months


def test_legend_colours_are_the_materials_ramp():
    scene, obj = _scene_with_contour("demo:small")
    entries = annotate_ops.legend_entries(scene)
    assert len(entries) == 1
    bar = entries[0]
    ramp = obj.active_material.node_tree.nodes["Nephele ramp"].color_ramp
    rng = obj.active_material.node_tree.nodes["Nephele range"]
    lo, hi = rng.inputs["From Min"].default_value, rng.inputs["From Max"].default_value
    assert bar.range == pytest.approx((lo, hi))
    values = np.linspace(lo, hi, 41)
    truth = np.array([ramp.evaluate(float((v - lo) / (hi - lo)))[:3] for v in values])
    np.testing.assert_allclose(bar.colors(values), truth, atol=2e-3)  # Blender's own ramp evaluation


def test_volume_and_splat_layers_list_their_transfer_functions():
    from nephele.core.volume.transfer import ALTITUDE_COLORS, ColorMap, TransferFunction

    scene = bpy.context.scene
    tf = TransferFunction.ramp(0.3, 0.7)
    for kind in ("volume", "splats"):
        obj = bpy.data.objects.new(kind, None)
        scene.collection.objects.link(obj)
        p = {"kind": kind, "var": "cloud", "tf": tf.to_dict(), "color_var": "altitude"}
        if kind == "volume":
            p["cmap"] = ColorMap(points=((0.0, (1.0, 0.0, 0.0)), (10.0, (0.0, 0.0, 1.0)))).to_dict()
        frame.set_params(obj, p)
    opacity, volume_colours, splat_colours = annotate_ops.legend_entries(scene)  # the shared opacity once
    assert opacity.points == tf.points
    assert volume_colours.stops[-1] == (10.0, (0.0, 0.0, 1.0))
    assert splat_colours.stops == ALTITUDE_COLORS.points


def test_layer_reaches_the_render_and_toggles(tmp_path):
    from nephele.addon import globe_ops

    scene, _ = _scene_with_contour("demo:small")
    globe_ops.add_camera(scene, lon=-40.0, lat=20.0, distance=4.0)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 320, 180, 100
    ann = annotate_ops.add_annotations(scene, heading="Test heading")
    tree = scene.compositing_node_group

    def render(name):
        scene.render.filepath = str(tmp_path / name)
        bpy.ops.render.render(write_still=True)
        return read_image(tmp_path / name)[..., :3]

    on = render("on.png")
    scene.nephele_annotations.enabled = False
    assert tree.nodes[annotate_ops.OVER].mute and not frame.params(ann)["enabled"]
    off = render("off.png")
    changed = np.abs(on - off).max(axis=2) > 0.02
    assert changed[:14, :60].any()  # the heading, top left
    assert changed[:20, -80:].any()  # the time, top right
    assert changed[-30:, :60].any()  # the legend, bottom left
    assert not changed[50:130, 120:300].any()  # the picture itself untouched
    scene.nephele_annotations.enabled = True
    scene.nephele_annotations.heading = "Other"
    assert frame.params(ann)["heading"] == "Other" and not tree.nodes[annotate_ops.OVER].mute


def test_colour_space_follows_the_view_transform():
    scene, _ = _scene_with_contour("demo:small")
    annotate_ops.add_annotations(scene)
    img = bpy.data.images[annotate_ops.IMAGE]
    for view, space in (("Standard", "sRGB"), ("AgX", "AgX Base sRGB")):
        scene.view_settings.view_transform = view
        scene.frame_set(2)
        assert img.colorspace_settings.name == space
    assert tuple(img.size) == annotate_ops.render_size(scene)
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    scene.render.resolution_percentage = 25  # a new size: the layer follows
    scene.frame_set(3)
    assert tuple(img.size) == annotate_ops.render_size(scene) == (480, 270)


def test_remove_restores_the_compositor():
    scene, _ = _scene_with_contour("demo:small")
    annotate_ops.add_annotations(scene)
    tree = scene.compositing_node_group
    out = next(n for n in tree.nodes if n.bl_idname == "NodeGroupOutput")
    assert out.inputs[0].links[0].from_node.name == annotate_ops.OVER
    annotate_ops.remove_annotations(scene)
    assert annotate_ops.annotations_object(scene) is None
    assert out.inputs[0].links[0].from_node.bl_idname == "CompositorNodeRLayers"


def test_growing_smoke_release_and_its_time():
    """A growing release (the reel's Fig. 5) lasts until the frame's time; the annotation shows its end."""
    from nephele.addon.flowvol_ops import release_window

    p = {"source": "demo:small", "start_hour": 0.0, "hours": 12.0, "grow": True, "hours_per_frame": 3.0,
         "frame_start": 1}
    assert [release_window(p, f) for f in (1, 2, 4, 10)] == [(0.0, 3.0), (0.0, 6.0), (0.0, 12.0), (0.0, 12.0)]
    assert release_window({**p, "hours": 100.0}, 30) == (0.0, 47.0)  # demo:small ends at 47 h
    scene = bpy.context.scene
    smoke = bpy.data.objects.new("smoke", None)
    scene.collection.objects.link(smoke)
    frame.set_params(smoke, {"kind": "flowvol", **p})
    label, note = annotate_ops.frame_time(scene, 3)
    assert label == "1987-01-01 09:00" and note == ""
