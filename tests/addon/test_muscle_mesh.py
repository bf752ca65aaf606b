"""Blobby molecules into Blender: geometry, integer ids and analytic normals survive, and Cycles renders it."""

import bpy
import numpy as np

from nephele.addon import mesh as bmesh_io
from nephele.addon import muscle_mesh
from nephele.core.muscle import Cylinders, cylinder_mesh, myosin_head


def test_head_into_blender_keeps_geometry_ids_and_normals():
    mesh = myosin_head().surface(0.25)
    obj = muscle_mesh.blobby_object("head", mesh)
    me = obj.data
    v, f = bmesh_io.mesh_arrays(me)
    np.testing.assert_allclose(v, mesh.vertices * np.float32(muscle_mesh.SCALE), rtol=1e-6)
    np.testing.assert_array_equal(f, mesh.faces)
    np.testing.assert_array_equal(muscle_mesh.int_attribute(me, "part"), mesh.attributes["part"])
    np.testing.assert_array_equal(muscle_mesh.int_attribute(me, "blob"), mesh.attributes["blob"])
    assert me.has_custom_normals
    corner = muscle_mesh.custom_normals(me)
    want = mesh.normals[mesh.faces.reshape(-1)]
    assert np.einsum("ij,ij->i", corner, want).min() > 0.999


def test_refill_and_empty():
    me = muscle_mesh.fill_blobby(bpy.data.meshes.new("m"), myosin_head().surface(0.3))
    n = len(me.vertices)
    assert n > 0
    empty = cylinder_mesh(Cylinders(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)))
    muscle_mesh.fill_blobby(me, empty)
    assert len(me.vertices) == 0 and len(me.polygons) == 0


def test_head_and_tail_render(tmp_path):
    scene = bpy.context.scene
    muscle_mesh.blobby_object("head", myosin_head().surface(0.3))
    tail = cylinder_mesh(Cylinders([[0, 0, 0]], [[-8, 0, 0]], 1.0, part=[3]))
    muscle_mesh.blobby_object("tail", tail)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.location = (0.4, -2.5, 0.3)
    cam.rotation_euler = (np.radians(85), 0, 0)
    scene.camera = cam
    light = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(light)
    light.rotation_euler = (np.radians(60), 0, np.radians(30))
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 48, 100
    scene.render.filepath = str(tmp_path / "head.png")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(scene.render.filepath)
    px = np.array(img.pixels[:]).reshape(48, 64, 4)
    lum = px[..., :3].mean(axis=2)
    # Something lit in the middle (the head), dark sky at the corners (no world light).
    assert lum[16:32, 16:48].max() > 0.1
    assert lum[0, 0] < 0.05
