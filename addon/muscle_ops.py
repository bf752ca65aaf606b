"""The muscle film (Fig. 7) in Blender: the filament lattice with its cross-bridges, following the frame.

"Add muscle film" adds one object whose mesh is the current frame of the
film: the blobby surface of every actin subunit and myosin head of the
periodic box (one summed field, so a bound head and its actin meet in one
smooth surface) plus the tails and backbones as cylinders, with a per-vertex
``molecule`` attribute (0 actin, 1 motor domain, 2 lever arm, 3 tail,
4 backbone) that the material colours.  The object keeps only its parameters
(``obj["nephele"]``, kind ``"muscle"``); the frame updater gets the frame's
mesh from the cache or computes it with the ``"muscle_frame"`` task of
:mod:`nephele.core.muscle.film`, so a saved .blend renders headless and on
the farm with nothing but :func:`nephele.addon.frame.install`.  Array
modifiers repeat the box (the lattice is periodic, so the copies join
seamlessly) and a camera sits inside it looking along the fibre; the dome rig
of :mod:`.dome_ops` turns that into the paper's Omnimax stereo film.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 7.
"""

import math

import bpy
import numpy as np

from ..core.muscle import film
from ..core.muscle import lattice as lat
from ..core.pipeline.tasks import run_cached
from ..core.surface.mesh import Mesh
from . import frame, materials
from .mesh import fill_mesh, new_object, select_only
from .panel import SubPanel

OBJECT_NAME = "Muscle film"
CAMERA_NAME = "Muscle camera"
SCALE = 0.01
"""Scene units per nanometre (1 unit = 100 nm)."""

COLOURS = [
    (0.0, (0.95, 0.55, 0.12)),  # actin: warm orange
    (0.25, (0.22, 0.35, 0.95)),  # myosin motor domain: blue
    (0.5, (0.45, 0.75, 1.0)),  # lever arm with light chains: pale blue
    (0.75, (0.62, 0.35, 0.85)),  # tail (S2): violet
    (1.0, (0.45, 0.40, 0.55)),  # thick-filament backbone: grey violet
]
"""Molecule colours (linear RGB) at ``molecule / 4``, in the spirit of the Expo '90 film's saturated palette."""


def frame_mesh(arrays):
    """One :class:`Mesh` of the blobby surface and the cylinders of a ``"muscle_frame"`` result (nm)."""
    nv = len(arrays["vertices"])
    return Mesh(np.concatenate([arrays["vertices"], arrays["cyl_vertices"]]),
                np.concatenate([arrays["faces"], arrays["cyl_faces"] + nv]),
                np.concatenate([arrays["normals"], arrays["cyl_normals"]]),
                {"molecule": np.concatenate([arrays["molecule"], arrays["cyl_molecule"]]).astype(np.float32)})


def plan(obj, params, scene, frame_number):
    """Plan of the film layer for :func:`nephele.addon.frame.register_job` (None when the frame is shown).

    The first frame shown needs the whole simulation (tens of seconds): in the
    interface it runs on the worker thread like every other frame.  The film frame names the result."""
    return frame.plan_task(obj, params, scene, frame_number, lambda kind, tp: tp["frame"])


def compute(args, job=None):
    """Worker side (no ``bpy``): the frame's arrays from the cache or the simulation."""
    return run_cached(args["kind"], args["tp"], args["cache"])


def apply(obj, args, result):
    fill_mesh(obj.data, frame_mesh(result))


update_muscle = frame.register_job("muscle", plan, compute, apply)
"""Synchronous updater ``(obj, params, scene, frame)`` (headless, renders)."""


def _tile(obj, box, tiles):
    """Array modifiers repeating the periodic box ``tiles`` times along x, y, z, centred on the origin."""
    for m in [m for m in obj.modifiers if m.type == "ARRAY"]:
        obj.modifiers.remove(m)
    for axis, (n, length) in enumerate(zip(tiles, box)):
        if n <= 1:
            continue
        m = obj.modifiers.new(f"Lattice {'xyz'[axis]}", "ARRAY")
        m.count = int(n)
        m.use_relative_offset = False
        m.use_constant_offset = True
        off = [0.0, 0.0, 0.0]
        off[axis] = float(length)
        m.constant_offset_displace = off
    obj.location = tuple(-SCALE * length * (n - 1) / 2 - SCALE * length / 2 for n, length in zip(tiles, box))


def add_muscle_film(*, seed=0, frames=240, spacing=0.5, frame_time=0.1, tiles=(3, 3, 1), frame_start=1,
                    camera=True, scene=None):
    """Add (or replace) the muscle-film object, its material and a camera inside the lattice.

    Parameters
    ----------
    seed, frames, spacing, frame_time
        Film parameters (:func:`nephele.core.muscle.film.film_params`): random seed, film length in frames,
        blobby grid spacing (nm) and Brownian microseconds per frame.
    tiles : 3 ints
        Copies of the periodic box along x, y, z (Array modifiers).
    frame_start : int
        Scene frame showing the film's first frame.
    camera : bool
        Add a perspective camera inside the lattice, looking along the fibre, as the scene camera.
    scene : bpy.types.Scene, optional

    Returns
    -------
    The object.
    """
    scene = scene or bpy.context.scene
    p = film.film_params(seed=seed, frames=frames, spacing=spacing, frame_time=frame_time)
    tiles = tuple(int(t) for t in tiles)
    if len(tiles) != 3 or min(tiles) < 1:
        raise ValueError(f"tiles must be three counts >= 1, got {tiles}")
    old = bpy.data.objects.get(OBJECT_NAME)
    if old is not None:
        bpy.data.objects.remove(old, do_unlink=True)
    obj = new_object(OBJECT_NAME, Mesh.empty(["molecule"]), collection=scene.collection)
    obj.scale = (SCALE, SCALE, SCALE)
    frame.set_params(obj, {"kind": "muscle", "film": p, "frame_start": int(frame_start)})
    mat = materials.attribute_material("Muscle molecules", "molecule", 0.0, 4.0, COLOURS, roughness=0.4,
                                       emission=0.05)
    materials.assign(obj, mat)
    # In the interface the first frame (the whole simulation) computes in the background.
    frame.submit(obj, scene, scene.frame_current)
    cell = lat.unit_cell(d10=p["d10"])
    _tile(obj, cell.box, tiles)
    scene.frame_start, scene.frame_end = int(frame_start), int(frame_start) + p["frames"] - 1
    if camera:
        add_camera(scene, obj, cell, tiles)
    return obj


def add_camera(scene, obj, cell, tiles):
    """A perspective camera midway between two thick filaments of the middle tile, looking up the fibre (+z)."""
    cam = bpy.data.objects.get(CAMERA_NAME)
    if cam is not None:
        bpy.data.objects.remove(cam, do_unlink=True)
    data = bpy.data.cameras.new(CAMERA_NAME)
    data.lens = 14.0
    data.clip_start = 0.01
    cam = bpy.data.objects.new(CAMERA_NAME, data)
    mid = (cell.thick_xy[0] + cell.thick_xy[1]) / 2
    local = np.array([mid[0], mid[1], 0.1 * cell.length]) + np.array([t // 2 for t in tiles]) * cell.box
    cam.location = tuple(SCALE * local + np.array(obj.location))
    # Cameras look along their -z: turned to look up the fibre (+z), 25 degrees off its axis to see the
    # filaments recede.
    cam.rotation_euler = (math.pi - math.radians(25), 0.0, math.radians(15))
    scene.collection.objects.link(cam)
    scene.camera = cam
    world = scene.world or bpy.data.worlds.new("World")
    scene.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Color"].default_value = (0.01, 0.012, 0.03, 1.0)
        bg.inputs["Strength"].default_value = 1.0
    # Inside a crystal a distant sun is shadowed by the copies: a headlight on the camera lights what it sees,
    # and a faint emission keeps the far, unlit molecules readable.
    old = bpy.data.objects.get("Muscle light")
    if old is not None:
        bpy.data.objects.remove(old, do_unlink=True)
    ld = bpy.data.lights.new("Muscle light", "POINT")
    ld.energy = 3.0
    ld.shadow_soft_size = 0.02
    light = bpy.data.objects.new("Muscle light", ld)
    light.parent = cam
    light.location = (0.03, 0.03, 0.0)
    scene.collection.objects.link(light)
    return cam


class NEPHELE_OT_add_muscle_film(bpy.types.Operator):
    """Add the muscle cross-bridge film (Fig. 7): periodic actin/myosin lattice simulated frame by frame"""

    bl_idname = "nephele.add_muscle_film"
    bl_label = "Add muscle film"
    bl_options = {"REGISTER", "UNDO"}

    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    frames: bpy.props.IntProperty(name="Frames", default=240, min=1)
    spacing: bpy.props.FloatProperty(name="Grid spacing (nm)", default=0.5, min=0.1, max=5.0)
    tiles: bpy.props.IntVectorProperty(name="Tiles", size=3, default=(3, 3, 1), min=1, max=8)
    camera: bpy.props.BoolProperty(name="Camera inside the lattice", default=True)

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        from ..core.errors import DataError

        try:
            obj = add_muscle_film(seed=self.seed, frames=self.frames, spacing=self.spacing, tiles=tuple(self.tiles),
                                  camera=self.camera, scene=context.scene)
        except (DataError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.polygons)} triangles per box")
        select_only(context, obj)
        return {"FINISHED"}


class NEPHELE_PT_muscle(SubPanel, bpy.types.Panel):
    bl_label = "Muscle film"
    bl_idname = "NEPHELE_PT_muscle"

    def draw(self, context):
        col = self.layout.column(align=True)
        col.operator(NEPHELE_OT_add_muscle_film.bl_idname, icon="FORCE_BROWNIAN")
        col.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG7"
        obj = bpy.data.objects.get(OBJECT_NAME)
        p = frame.params(obj) if obj is not None else {}
        if p.get("kind") == "muscle":
            box = self.layout.box()
            f = p["film"]
            box.label(text=f"seed {f['seed']}, {f['frames']} frames, {f['frame_time']:g} us/frame")
            box.label(text=f"film frame {obj.get('nephele_shown', 0)}, {len(obj.data.polygons)} triangles")


CLASSES = (NEPHELE_OT_add_muscle_film, NEPHELE_PT_muscle)
