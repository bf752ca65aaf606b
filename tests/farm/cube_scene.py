"""A tiny farm test scene: a cube turning with the frame, 32x24 px, Workbench.

Options: ``fail_frame`` makes a frame handler raise on that frame (a scene
that breaks on one frame); ``delay`` sleeps that many seconds per frame, so
tests can act in the middle of a run; ``hang_frame`` sleeps 60 s on that
frame (for the timeout); ``stereo`` renders both eyes (Blender's stereo 3D
multi-view, one file per eye).
"""

import time

import bpy


def build(fail_frame=None, delay=0.0, hang_frame=None, size=(32, 24), engine="BLENDER_WORKBENCH", stereo=False):
    scene = bpy.context.scene
    mesh = bpy.data.meshes.new("cube")
    verts = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(verts, [], faces)  # 8 vertices: the foreach_set rule is for big meshes
    cube = bpy.data.objects.new("cube", mesh)
    scene.collection.objects.link(cube)
    cube.rotation_mode = "XYZ"
    cube.keyframe_insert("rotation_euler", frame=1)
    cube.rotation_euler = (0.0, 0.0, 6.283)
    cube.keyframe_insert("rotation_euler", frame=241)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    cam.location = (5.0, -5.0, 4.0)
    cam.rotation_euler = (1.0, 0.0, 0.785)
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.rotation_euler = (0.6, 0.2, 0.3)
    scene.render.engine = engine
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.frame_start, scene.frame_end = 1, 240
    if stereo:
        scene.render.use_multiview = True
        scene.render.views_format = "STEREO_3D"
        scene.render.image_settings.views_format = "INDIVIDUAL"
        cam.data.stereo.interocular_distance = 0.6  # wide, so the eyes differ visibly at 32 px
    if engine == "CYCLES":
        scene.cycles.samples = 1
        scene.cycles.device = "CPU"

    def on_frame(scene, depsgraph=None):
        if delay:
            time.sleep(delay)
        if hang_frame is not None and scene.frame_current == hang_frame:
            time.sleep(60)
        if fail_frame is not None and scene.frame_current == fail_frame:
            raise RuntimeError(f"test scene breaks on frame {fail_frame}")

    bpy.app.handlers.frame_change_pre.append(on_frame)
