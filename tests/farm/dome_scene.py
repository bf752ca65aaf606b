"""A tiny dome farm scene: emissive markers at known directions around a dome rig, under a dim grey sky.

Options: ``engine``, ``preset`` and ``size`` of the rig's frame, ``stereo``
(two eyes ``separation`` apart), ``face`` (cube face size of the EEVEE route).
:data:`MARKERS` gives each marker's (elevation, azimuth right of the front)
in degrees, seen from the rig at the origin.
"""

import math

import bmesh
import bpy

from nephele.addon import dome_ops, frame

COLOURS = {"red": (1, 0, 0), "green": (0, 1, 0), "blue": (0, 0, 1)}
MARKERS = {"red": (30, 0), "green": (45, 90), "blue": (60, -135)}
DISTANCE = 10.0


def direction(el, az):
    e, a = math.radians(el), math.radians(az)
    return (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))


def build(engine="BLENDER_EEVEE", preset="domemaster", size=(48, 48), stereo=False, separation=0.065, face=32,
          samples=1, sky=0.02):
    scene = bpy.context.scene
    # A dim uniform sky: inside the fisheye circle is grey, outside it the frame stays black.
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (sky, sky, sky, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    world.color = (sky, sky, sky)  # Workbench's background
    scene.world = world
    scene.display.shading.light = "FLAT"  # Workbench: markers in their plain colours
    scene.display.shading.color_type = "MATERIAL"
    scene.view_settings.view_transform = "Standard"
    for name, (el, az) in MARKERS.items():
        mesh = bpy.data.meshes.new(name)
        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=12, v_segments=6, radius=1.0)
        bm.to_mesh(mesh)
        bm.free()
        mat = bpy.data.materials.new(name)
        nt = mat.node_tree
        nt.nodes.clear()
        em = nt.nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = (*COLOURS[name], 1.0)
        em.inputs["Strength"].default_value = 4.0
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(em.outputs[0], out.inputs[0])
        mat.diffuse_color = (*COLOURS[name], 1.0)  # Workbench
        mesh.materials.append(mat)
        ob = bpy.data.objects.new(name, mesh)
        ob.location = tuple(DISTANCE * c for c in direction(el, az))
        scene.collection.objects.link(ob)
    rig = dome_ops.add_dome_camera(preset, width=size[0], height=size[1], stereo=stereo, separation=separation)
    p = frame.params(rig)
    p["face_size"] = face
    frame.set_params(rig, p)
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.samples = samples
        scene.cycles.device = "CPU"
    elif engine == "BLENDER_EEVEE":
        scene.eevee.taa_render_samples = samples
    scene.frame_start, scene.frame_end = 1, 10
