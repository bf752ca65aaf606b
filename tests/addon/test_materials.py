"""Colour from a mesh attribute through a colour ramp, checked in a Cycles render."""

import bpy
import numpy as np
import pytest

from nephele.addon import materials
from nephele.addon.mesh import new_object

RED, BLUE = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)


def strip(n=21):
    """A 2 x 0.5 strip in the xy-plane with attribute ``t`` = 0..10 from left to right."""
    x = np.linspace(-1.0, 1.0, n)
    v = np.concatenate([np.stack([x, np.full(n, -0.25), np.zeros(n)], 1),
                        np.stack([x, np.full(n, 0.25), np.zeros(n)], 1)])
    i = np.arange(n - 1)
    f = np.concatenate([np.stack([i, i + 1, n + i + 1], 1), np.stack([i, n + i + 1, n + i], 1)])
    t = np.concatenate([np.linspace(0.0, 10.0, n)] * 2)
    return v, f, {"t": t}


def render_row(scene, tmp_path, name):
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 2.0
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (0.0, 0.0, 3.0)
    scene.camera = cam
    scene.world = bpy.data.worlds.new("black")
    materials.enable_nodes(scene.world)
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 40, 10
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"  # linear values
    scene.render.filepath = str(tmp_path / f"{name}.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(scene.render.filepath)
    a = np.empty(40 * 10 * 4, np.float32)
    img.pixels.foreach_get(a)
    return a.reshape(10, 40, 4)[5, :, :3]


@pytest.mark.parametrize("vmin, vmax", [(0.0, 10.0), (2.5, 7.5)])
def test_ramp_colours_follow_the_attribute(empty_scene, tmp_path, vmin, vmax):
    obj = new_object("strip", strip())
    mat = materials.attribute_material("ramp", "t", vmin, vmax, [(0.0, RED), (1.0, BLUE)], emission=1.0)
    # Emission only: no lights, black world, so the pixel is the ramp colour.
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0, 0, 0, 1)
    mat.node_tree.links.remove(mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links[0])
    materials.assign(obj, mat)
    row = render_row(empty_scene, tmp_path, f"ramp{vmin}")
    t = (np.arange(40) + 0.5) / 40 * 10.0  # attribute at each pixel centre
    s = np.clip((t - vmin) / (vmax - vmin), 0, 1)
    # The strip ends at the frame's edges, where the pixel filter sees black: compare inside.
    np.testing.assert_allclose(row[1:-1, 0], (1 - s)[1:-1], atol=0.03)  # pixel filter and sampling noise
    np.testing.assert_allclose(row[1:-1, 2], s[1:-1], atol=0.03)
    assert np.abs(row[:, 1]).max() < 0.02


def test_change_range_and_ramp_in_place(empty_scene):
    mat = materials.attribute_material("m", "altitude", 0.0, 1.0, "altitude")
    materials.set_attribute_range(mat, attribute="temperature", vmin=220.0, vmax=300.0, ramp="temperature")
    nodes = mat.node_tree.nodes
    assert nodes["Nephele attribute"].attribute_name == "temperature"
    assert nodes["Nephele range"].inputs["From Min"].default_value == 220.0
    els = nodes["Nephele ramp"].color_ramp.elements
    assert len(els) == len(materials.RAMPS["temperature"])
    assert tuple(els[0].color)[:3] == pytest.approx(materials.RAMPS["temperature"][0][1])
