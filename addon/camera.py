"""Cameras in the scene: one way to make one and to aim it."""

import bpy


def look_at(obj, target=(0.0, 0.0, 0.0)):
    """Point a camera or light (its -Z) at ``target``, keeping +Z world up."""
    from mathutils import Vector

    direction = Vector(target) - obj.location
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = direction.to_track_quat("-Z", "Y")


def camera_object(scene, name, *, lens=None, angle=None, clip_start=0.01, clip_end=None):
    """The camera object ``name`` (made, or reused with its data), linked to ``scene`` and made its camera.

    ``lens`` in mm or ``angle`` (horizontal field of view, radians) sets the view;
    clip distances in scene units.
    """
    data = bpy.data.cameras.get(name) or bpy.data.cameras.new(name)
    if angle is not None:
        data.sensor_fit = "HORIZONTAL"
        data.angle = float(angle)
    if lens is not None:
        data.lens = float(lens)
    data.clip_start = clip_start
    if clip_end is not None:
        data.clip_end = clip_end
    obj = bpy.data.objects.get(name) or bpy.data.objects.new(name, data)
    if obj.name not in scene.collection.objects:
        scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


__all__ = ["camera_object", "look_at"]
