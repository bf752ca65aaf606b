"""The fractal node group against the NumPy texture (a rendered flat patch), and the advected-texture operator."""

import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.core.flow import advect  # noqa: E402
from nephele.core.texture.fractal import Fractal, texture_xyz  # noqa: E402

SIZE = 48


def _render_exr(path, scene, samples=1):
    scene.render.engine = "CYCLES"
    scene.cycles.samples = samples
    scene.cycles.device = "CPU"
    scene.cycles.filter_width = 0.01  # sample at the pixel centre
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(path))
    px = np.array(img.pixels[:], dtype=np.float64).reshape(SIZE, SIZE, 4)  # rows bottom to top
    bpy.data.images.remove(img)
    return px


def _patch(scene, start, alt):
    """A 2x2 plane at z=0 filling an orthographic camera, with linear start/altitude attributes."""
    from nephele.addon.mesh import new_object

    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    attrs = {advect.START.format("a"): start(v[:, 0], v[:, 1]).astype(np.float32),
             advect.START_ALT.format("a"): alt(v[:, 0], v[:, 1]).astype(np.float32)}
    obj = new_object("patch", (v, f, attrs))
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 2.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (0, 0, 5)
    scene.collection.objects.link(cam)
    scene.camera = cam
    from nephele.addon.materials import enable_nodes

    world = bpy.data.worlds.new("black")
    enable_nodes(world)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world
    return obj


def test_node_group_matches_numpy_texture(tmp_path, empty_scene):
    from nephele.addon import advect_ops
    from nephele.addon.materials import enable_nodes

    scene = empty_scene
    fractal = Fractal()

    def start(x, y):  # linear in the plane, so Cycles' interpolation across the triangles is exact
        return np.stack([np.ones_like(x), 0.25 * x + 0.1, 0.2 * y + 0.3], axis=1)

    def alt(x, y):
        return 4000.0 + 3000.0 * x - 1000.0 * y

    obj = _patch(scene, start, alt)
    mat = bpy.data.materials.new("tex")
    enable_nodes(mat)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    vec = tree.nodes.new("ShaderNodeAttribute")
    vec.attribute_name = advect.START.format("a")
    a = tree.nodes.new("ShaderNodeAttribute")
    a.attribute_name = advect.START_ALT.format("a")
    g = tree.nodes.new("ShaderNodeGroup")
    g.node_tree = advect_ops.fractal_node_group(fractal)
    em = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(vec.outputs["Vector"], g.inputs["Vector"])
    tree.links.new(a.outputs["Fac"], g.inputs["Altitude"])
    tree.links.new(g.outputs["Texture"], em.inputs["Strength"])
    tree.links.new(em.outputs[0], out.inputs["Surface"])
    obj.data.materials.append(mat)

    px = _render_exr(tmp_path / "patch.exr", scene)
    c = -1 + (np.arange(SIZE) + 0.5) * 2.0 / SIZE
    x, y = np.meshgrid(c, c)  # row 0 = bottom = y -1
    want = texture_xyz(start(x.ravel(), y.ravel()), alt(x.ravel(), y.ravel()), fractal).reshape(SIZE, SIZE)
    got = px[..., 0]
    assert want.std() > 0.03  # the patch shows structure
    np.testing.assert_allclose(px[..., 1], got, atol=1e-6)  # grey
    assert np.abs(got - want).max() < 1e-4  # float32 shader maths
    # the same group is reused for the same parameters, rebuilt for others
    assert advect_ops.fractal_node_group(fractal) == g.node_tree
    assert advect_ops.fractal_node_group(Fractal(octaves=3)) != g.node_tree


def test_operator_on_contour_gives_per_frame_start_coordinates(empty_scene):
    from nephele.addon import advect_ops, contour_ops, data_ops, frame

    scene = empty_scene
    data_ops.set_settings(scene, source="demo:small")
    scene.frame_set(1)
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.nephele.add_advected_texture(strategy="restart", period=8) == {"FINISHED"}
    assert frame.params(obj)["kind"] == advect_ops.KIND
    me = obj.data
    assert len(me.vertices) > 100
    names = set(me.attributes.keys())
    for c in advect.COPIES:
        assert {advect.START.format(c), advect.START_ALT.format(c), advect.WEIGHT.format(c)} <= names

    def attr(name, width=1):
        a = np.zeros(len(me.vertices) * width, dtype=np.float32)
        me.attributes[name].data.foreach_get("vector" if width == 3 else "value", a)
        return a.reshape(-1, width) if width > 1 else a

    pos = np.zeros(len(me.vertices) * 3, dtype=np.float32)
    me.attributes["position"].data.foreach_get("vector", pos)
    pos = pos.reshape(-1, 3)
    # frame 1 is model time 0: the start of copy a is where each vertex is
    sa = attr(advect.START.format("a"), 3)
    np.testing.assert_allclose(sa / np.linalg.norm(sa, axis=1, keepdims=True),
                               pos / np.linalg.norm(pos, axis=1, keepdims=True), atol=2e-3)
    nv1 = len(me.vertices)
    scene.frame_set(6)  # 5 h later: a new mesh, start coordinates moved back along the wind
    assert frame.params(obj)["kind"] == advect_ops.KIND and json.loads(obj["nephele_shown"])["frame"] == 5
    pos = np.zeros(len(me.vertices) * 3, dtype=np.float32)
    me.attributes["position"].data.foreach_get("vector", pos)
    pos = pos.reshape(-1, 3)
    sa = attr(advect.START.format("a"), 3)
    moved = np.degrees(np.arccos(np.clip(np.sum(
        sa / np.linalg.norm(sa, axis=1, keepdims=True) * pos / np.linalg.norm(pos, axis=1, keepdims=True), axis=1), -1,
                                         1)))
    assert len(me.vertices) != nv1 or np.median(moved) > 0.05
    assert np.median(moved) < 10.0
    wa, wb = attr(advect.WEIGHT.format("a")), attr(advect.WEIGHT.format("b"))
    np.testing.assert_allclose(wa + wb, 1.0, atol=1e-6)
    assert wa[0] == pytest.approx(1 - abs(2 * (5 % 8) / 8 - 1))
    mat = obj.active_material
    assert mat.use_backface_culling
    assert any(n.bl_idname == "ShaderNodeGroup" and n.node_tree.name.startswith(advect_ops.GROUP_NAME)
               for n in mat.node_tree.nodes)


def test_operator_refuses_non_contour(empty_scene):
    me = bpy.data.meshes.new("m")
    obj = bpy.data.objects.new("plain", me)
    empty_scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    assert not bpy.ops.nephele.add_advected_texture.poll()
    from nephele.addon import advect_ops

    with pytest.raises(ValueError, match="not a Nephele contour"):
        advect_ops.add_advected_texture(obj)
