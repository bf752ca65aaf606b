"""Add flow volume: generator circle facing the flow, smoke mesh equal to the core's surface, rebuild on move."""

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import flowvol_ops as fo  # noqa: E402
from nephele.core.climate.synthetic import SyntheticClimate  # noqa: E402
from nephele.core.flowvol import ClimateVelocity, flow_volume  # noqa: E402

_DS = SyntheticClimate(ni=64, nj=32, nk=4, days=1, seed=0)


@pytest.fixture
def flowvol_scene(empty_scene, monkeypatch):
    # The add-on (registered by the conftest's empty_scene) brings the classes and scene properties.
    monkeypatch.setattr(fo, "_velocity", lambda source, exaggeration: ClimateVelocity(_DS, exaggeration=exaggeration))
    p = empty_scene.nephele_flowvol
    p.hours, p.sides, p.steps, p.tolerance, p.live = 6.0, 12, 4, 0.03, False
    yield empty_scene


def test_operator_builds_the_core_surface_and_rebuilds_on_move(flowvol_scene):
    p = flowvol_scene.nephele_flowvol
    assert bpy.ops.nephele.add_flow_volume() == {"FINISHED"}
    gen, smoke = bpy.data.objects[fo.GENERATOR], bpy.data.objects[fo.SMOKE]
    vel = ClimateVelocity(_DS)
    centre = vel.point(p.lon, p.lat, p.height)
    fv = flow_volume(vel, centre, p.radius, p.hours, sides=p.sides, rings=1, tol=p.tolerance, steps=p.steps)
    assert len(smoke.data.polygons) == len(fv.surface.faces) > 0
    co = np.empty(len(smoke.data.vertices) * 3, np.float32)
    smoke.data.vertices.foreach_get("co", co)
    assert np.allclose(co.reshape(-1, 3), fv.surface.vertices, atol=1e-6)
    # The generator's z axis is the flow direction at its centre.
    z = np.array(gen.matrix_world.to_3x3().col[2])
    assert np.allclose(z / np.linalg.norm(z), fv.normal, atol=1e-5)
    assert smoke.data.materials[0].node_tree.nodes.get("Volume Absorption") is not None
    before = len(smoke.data.polygons)
    gen.location = vel.point(p.lon + 30.0, p.lat - 20.0, p.height)
    gen.scale = (2 * p.radius,) * 3
    bpy.context.view_layer.update()
    assert bpy.ops.nephele.update_flow_volume() == {"FINISHED"}
    co2 = np.empty(len(smoke.data.vertices) * 3, np.float32)
    smoke.data.vertices.foreach_get("co", co2)
    assert np.linalg.norm(co2.reshape(-1, 3).mean(axis=0)
                          - np.array(gen.location)) < np.linalg.norm(co.reshape(-1, 3).mean(axis=0)
                                                                     - np.array(gen.location))
    assert "tets" in p.status and len(smoke.data.polygons) != before


def test_smoke_flows_with_the_frames(flowvol_scene):
    """With "Flow with the frames" frame f shows the air released in the window moved on by (f - 1) h/frame."""
    scene, p = flowvol_scene, flowvol_scene.nephele_flowvol
    assert p.follow_frame
    assert bpy.ops.nephele.add_flow_volume() == {"FINISHED"}
    gen, smoke = bpy.data.objects[fo.GENERATOR], bpy.data.objects[fo.SMOKE]
    vel = ClimateVelocity(_DS)
    centre = np.array(gen.matrix_world.translation)

    def smoke_vertices():
        co = np.empty(len(smoke.data.vertices) * 3, np.float32)
        smoke.data.vertices.foreach_get("co", co)
        return co.reshape(-1, 3)

    first = smoke_vertices()
    scene.frame_set(7)  # 1 h per frame: the window [0, 6] h moves to [6, 12] h
    fv = flow_volume(vel, centre, p.radius, p.hours, sides=p.sides, rings=1, t0=6.0, tol=p.tolerance, steps=p.steps)
    assert np.allclose(smoke_vertices(), fv.surface.vertices, atol=1e-6)
    assert "released 6-12 h" in smoke["nephele_status"]
    scene.frame_set(1)
    assert np.allclose(smoke_vertices(), first, atol=1e-6)
    p.follow_frame = False
    assert bpy.ops.nephele.update_flow_volume() == {"FINISHED"}
    scene.frame_set(7)  # without it the smoke stays the release [start, start + hours]
    assert np.allclose(smoke_vertices(), first, atol=1e-6)


def test_update_without_generator_fails_cleanly(flowvol_scene):
    with pytest.raises(RuntimeError, match="no flow-volume generator"):
        bpy.ops.nephele.update_flow_volume()


def test_cycles_smoke_matches_the_core_compositor(empty_scene, tmp_path):
    """Orthographic Cycles render of a flow-volume tube vs C(1 - exp(-tau L)) on the same rays (mean within 2 %)."""
    from nephele.addon.mesh import new_object
    from nephele.core.flowvol.render import composite

    scene = empty_scene
    fv = flow_volume(lambda p, t: np.tile([0, 0, 1.0], (len(p), 1)), [0, 0, 0], 0.6, 1.5, sides=12)
    color, tau = (0.9, 0.7, 0.4), 1.5
    smoke = new_object("smoke", fv.surface, smooth=False)
    smoke.data.materials.append(fo.smoke_material(color, tau))
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 2.0
    cam.location = (-5.0, 0.0, 0.75)
    cam.rotation_euler = (np.pi / 2, 0.0, -np.pi / 2)  # looking along +x, up +z
    scene.camera = cam
    from nephele.addon.materials import enable_nodes

    scene.world = bpy.data.worlds.new("black")  # a new world renders 5 % grey: zero its background
    scene.world.color = (0.0, 0.0, 0.0)
    bg = enable_nodes(scene.world).nodes.get("Background")
    if bg is not None:
        bg.inputs["Strength"].default_value = 0.0
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 64
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = 0.01  # point-sampled pixels, as the reference rays
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "smoke.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "smoke.exr"))
    px = np.empty(48 * 48 * 4, np.float32)
    img.pixels.foreach_get(px)
    got = px.reshape(48, 48, 4)[..., :3]
    # The same rays: pixel centres of the 2 x 2 orthographic frame.
    c = (np.arange(48) + 0.5) / 48 * 2.0 - 1.0
    zz, yy = np.meshgrid(c + 0.75, -c, indexing="ij")
    origins = np.stack([np.full(zz.size, -5.0), yy.ravel(), zz.ravel()], axis=1)
    ref = composite(fv.vertices, fv.tets, origins, np.tile([1.0, 0, 0], (len(origins), 1)), color,
                    tau).reshape(48, 48, 3)
    assert ref.mean() > 0.05
    assert got.mean() == pytest.approx(ref.mean(), rel=0.02)


FIRE = str(Path(__file__).resolve().parents[1] / "data" / "flow" / "fire_ug.vtu")


def test_operator_on_the_fire_vtu_without_vtk(empty_scene):

    from nephele.core.flowvol import UnstructuredVelocity

    p = empty_scene.nephele_flowvol
    p.vtu_path, p.vtu_height, p.radius, p.hours = FIRE, 0.1, 0.1, 1.0
    p.sides, p.steps, p.tolerance, p.live = 16, 8, 0.05, False
    assert bpy.ops.nephele.add_flow_volume() == {"FINISHED"}, p.status
    gen, smoke = bpy.data.objects[fo.GENERATOR], bpy.data.objects[fo.SMOKE]
    fire = UnstructuredVelocity(FIRE)
    centre = fire.updraft(0.1)
    assert np.allclose(np.array(gen.location), centre, atol=1e-5)
    fv = flow_volume(fire, centre, 0.1, 1.0, sides=16, rings=1, tol=0.05, steps=8)
    assert len(smoke.data.polygons) == len(fv.surface.faces) > 0
    z = np.array(gen.matrix_world.to_3x3().col[2])
    assert np.allclose(z / np.linalg.norm(z), fv.normal, atol=1e-5) and fv.normal[2] > 0.5
    co = np.empty(len(smoke.data.vertices) * 3, np.float32)
    smoke.data.vertices.foreach_get("co", co)
    assert np.all(co.reshape(-1, 3) >= fire.bounds[:, 0]
                  - 1e-4) and np.all(co.reshape(-1, 3) <= fire.bounds[:, 1] + 1e-4)
