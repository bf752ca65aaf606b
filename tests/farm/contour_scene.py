"""A farm test scene with a Nephele object: a contour surface of demo:small cloud that follows the frame.

The object carries only its parameters (``obj["nephele"]``); the farm's worker
installs the frame handler, whose contour updater loads each frame's mesh
from the cache (or computes it).
"""

import bpy

from nephele.addon import frame


def build(level=0.15, size=(32, 24)):
    scene = bpy.context.scene
    me = bpy.data.meshes.new("cloud")
    obj = bpy.data.objects.new("cloud", me)
    scene.collection.objects.link(obj)
    frame.set_params(obj, {"kind": "contour", "source": "demo:small", "var": "cloud", "level": level,
                           "hours_per_frame": 6.0, "frame_start": 1})
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    cam.location = (0.0, -4.0, 0.0)
    cam.rotation_euler = (1.5708, 0.0, 0.0)
    scene.camera = cam
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
