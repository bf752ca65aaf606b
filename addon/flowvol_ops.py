"""Blender side of flow volumes (Fig. 5): smoke from a generator the user drags.

"Add flow volume" adds a circle object (the generator: move and scale it with
Blender's own tools; its orientation is set to face the flow) and the smoke:
the closed surface of :func:`..core.flowvol.flow_volume` with a constant
colour emission-absorption volume material (colour C, density τ: the
order-independent model of the paper, no sorting).  While "Live" is on, a
depsgraph handler rebuilds the smoke, debounced, when the generator moves.
With "Flow with the frames" the release window moves with the frame (a job of
:mod:`.frame`: in the background in the interface, at once in renders), so the
smoke flows on in a film while the generator keeps releasing.
With a ``.vtu`` file (e.g. the fire in a room) the velocity is that steady
3-D flow instead of the climate winds (read and interpolated without VTK,
which Blender does not ship) and the generator starts above the fastest
updraft.
"""

import json
import threading

import bpy
import numpy as np
from mathutils import Vector

from ..core.flowvol import ClimateVelocity, UnstructuredVelocity, flow_volume
from ..core.pipeline import sources
from ..core.surface.mesh import Mesh
from . import data_ops, frame
from .materials import enable_nodes
from .mesh import fill_mesh, new_object, select_only
from .panel import SubPanel

KIND = "flowvol"
GENERATOR = "Flow volume generator"
SMOKE = "Flow volume smoke"
_DEBOUNCE_S = 0.25
_state = {"matrix": None, "pending": False}


def generator_circle(sides):
    """A unit regular polygon in z = 0 (vertices and edges) for the generator object."""
    a = 2 * np.pi * np.arange(sides) / sides
    v = np.stack([np.cos(a), np.sin(a), np.zeros(sides)], axis=1)
    me = bpy.data.meshes.new(GENERATOR)
    me.vertices.add(sides)
    me.vertices.foreach_set("co", v.astype(np.float32).ravel())
    me.edges.add(sides)
    me.edges.foreach_set("vertices",
                         np.stack([np.arange(sides), (np.arange(sides) + 1) % sides], 1).astype(np.int32).ravel())
    me.update()
    return me


def smoke_material(color, density, name=SMOKE):
    """Emission C·τ plus absorption τ: a ray through length L gets C (1 - exp(-τ L)) over black."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    enable_nodes(mat)
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    absorb = nt.nodes.new("ShaderNodeVolumeAbsorption")
    emit = nt.nodes.new("ShaderNodeEmission")
    add = nt.nodes.new("ShaderNodeAddShader")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)  # grey absorption of every channel
    absorb.inputs["Density"].default_value = density
    emit.inputs["Color"].default_value = (*color, 1.0)
    emit.inputs["Strength"].default_value = density
    nt.links.new(absorb.outputs[0], add.inputs[0])
    nt.links.new(emit.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Volume"])
    return mat


_VELOCITIES = {}  # (source, exaggeration) -> velocity: keeps converted wind steps (or the read grid) between rebuilds
_VELOCITIES_LOCK = threading.Lock()


def is_vtu(source):
    """Whether ``source`` names a VTK XML unstructured grid (a steady 3-D flow) rather than a climate source."""
    return str(source).lower().endswith(".vtu")


def _velocity(source, exaggeration):
    key = (str(source), float(exaggeration))
    with _VELOCITIES_LOCK:
        if key not in _VELOCITIES:
            _VELOCITIES.clear()
            _VELOCITIES[key] = (UnstructuredVelocity(source) if is_vtu(source) else
                                ClimateVelocity(sources.open_source(source), exaggeration=exaggeration))
        return _VELOCITIES[key]


def release_window(params, frame_number):
    """``(t0, duration)`` in model hours: the air released during the window the smoke shows.

    Without ``follow``: ``[start_hour, start_hour + hours]``.  With it, the window
    keeps its length and ends ``frame_hours(frame)`` later, so at the first frame
    the smoke is the whole release and later frames show it flowing on while
    the generator keeps releasing (the end is clamped to the data's last hour).
    With ``grow`` the release starts at ``start_hour`` and lasts until the
    frame's time (at least one frame's hours, at most ``hours``): the smoke
    leaves the generator and is carried on, frame by frame.
    """
    t0, hours = float(params["start_hour"]), float(params["hours"])
    if params.get("grow") and not is_vtu(params["source"]):
        ds = sources.open_source(params["source"])
        step = float(params.get("hours_per_frame", 1.0))
        shift = sources.frame_hours(frame_number, params.get("frame_start", 1), step)
        return t0, max(min(shift + step, hours, float(ds.hours[-1]) - t0), 0.0)
    if params.get("follow") and not is_vtu(params["source"]):  # a steady flow: every window gives the same tube
        ds = sources.open_source(params["source"])
        shift = sources.frame_hours(frame_number, params.get("frame_start", 1), params.get("hours_per_frame", 1.0))
        t_end = min(t0 + hours + shift, float(ds.hours[-1]))
        t0 = max(t_end - hours, 0.0)
        hours = t_end - t0
    return t0, hours


def plan(obj, params, scene, frame_number):
    """The smoke's inputs at ``frame_number`` from the generator's place and size (None when shown)."""
    gen = bpy.data.objects.get(GENERATOR)
    if gen is None:
        return None
    t0, duration = release_window(params, frame_number)
    args = {**params, "center": [float(c) for c in gen.matrix_world.translation],
            "radius": float(max(gen.matrix_world.to_scale())), "t0": round(t0, 6), "duration": round(duration, 6)}
    key = json.dumps(args, sort_keys=True)
    if obj.get("nephele_shown") == key:
        return None
    return key, args, False


def compute(args, job=None):
    """Worker side (NumPy only): the flow volume of the planned window."""
    vel = _velocity(args["source"], args["exaggeration"])
    return flow_volume(vel, np.array(args["center"]), args["radius"], args["duration"], sides=args["sides"], rings=1,
                       t0=args["t0"], tol=args["tolerance"], steps=args["steps"])


def apply(obj, args, fv):
    """Main-thread side: refill the smoke, turn the generator to the flow, say what was built."""
    fill_mesh(obj.data, Mesh(fv.surface.vertices, fv.surface.faces, fv.surface.normals), smooth=False)
    gen = bpy.data.objects.get(GENERATOR)
    if gen is not None:  # keep the generator perpendicular to the local flow (its z axis along the normal)
        gen.rotation_mode = "QUATERNION"
        gen.rotation_quaternion = Vector(fv.normal).to_track_quat("Z", "Y")
        _state["matrix"] = [tuple(r) for r in gen.matrix_world]
    unit = "" if is_vtu(args["source"]) else " h"
    obj["nephele_status"] = (f"{len(fv.tets)} tets, volume {fv.volume:.3g}, released {args['t0']:g}-"
                             f"{args['t0'] + args['duration']:g}{unit}"
                             + ("" if fv.complete else " (front size limit reached)"))


update_smoke = frame.register_job(KIND, plan, compute, apply)


def layer_params(props, scene):
    """The smoke layer's parameters (stored on the object; the generator's place is read per frame)."""
    cfg = data_ops.settings(scene)
    source = bpy.path.abspath(props.vtu_path) if props.vtu_path else str(cfg["source"])
    return {"kind": KIND, "source": source, "exaggeration": float(props.exaggeration),
            "hours": float(props.hours), "start_hour": float(props.start_hour), "sides": int(props.sides),
            "steps": int(props.steps), "tolerance": float(props.tolerance), "follow": bool(props.follow_frame),
            "hours_per_frame": float(cfg["hours_per_frame"]), "frame_start": int(cfg["frame_start"])}


def build(context, props):
    """(Re)build the smoke for the scene's frame from the generator's place and size; returns the smoke object."""
    scene = context.scene
    smoke = bpy.data.objects.get(SMOKE)
    if smoke is None:
        smoke = new_object(SMOKE, Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3))), smooth=False)
        smoke.data.materials.append(smoke_material(tuple(props.color), props.density))
    frame.set_params(smoke, layer_params(props, scene))
    frame.submit(smoke, scene, force=True)  # at once headless; in the interface in the background
    err = frame.last_error(smoke)
    if err:
        raise ValueError(err)
    props.status = smoke.get("nephele_status", "computing...")
    return smoke


def _rebuild_later():
    _state["pending"] = False
    props = bpy.context.scene.nephele_flowvol
    if bpy.data.objects.get(GENERATOR) is not None:
        try:
            build(bpy.context, props)
        except ValueError as exc:  # DataError: show it, keep the last smoke
            props.status = str(exc)
    return None


def _on_depsgraph(scene, depsgraph=None):
    gen = bpy.data.objects.get(GENERATOR)
    if gen is None or not scene.nephele_flowvol.live or _state["pending"]:
        return
    m = [tuple(r) for r in gen.matrix_world]
    # Only a moved or scaled generator triggers a rebuild (our own rotation change is not a move).
    if _state["matrix"] is None or np.allclose(np.array(m)[:3, 3], np.array(_state["matrix"])[:3, 3]) and \
            np.isclose(max(gen.matrix_world.to_scale()),
                       max(np.linalg.norm(np.array(_state["matrix"])[:3, :3], axis=0))):
        return
    _state["pending"] = True
    bpy.app.timers.register(_rebuild_later, first_interval=_DEBOUNCE_S)


def install_handler():
    if _on_depsgraph not in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.append(_on_depsgraph)


def uninstall():
    """Remove the live-rebuild handler and a pending rebuild; called by the add-on's ``unregister()``."""
    handlers = bpy.app.handlers.depsgraph_update_post
    for h in [h for h in handlers if getattr(h, "__name__", "") == _on_depsgraph.__name__]:
        handlers.remove(h)
    if bpy.app.timers.is_registered(_rebuild_later):
        bpy.app.timers.unregister(_rebuild_later)
    _state["pending"] = False


class NEPHELE_OT_add_flow_volume(bpy.types.Operator):
    """Add a smoke generator in the winds and the air that flowed through it"""

    bl_idname = "nephele.add_flow_volume"
    bl_label = "Add flow volume"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.nephele_flowvol
        try:
            source = layer_params(props, context.scene)["source"]
            vel = _velocity(source, props.exaggeration)
            gen = bpy.data.objects.get(GENERATOR)
            if gen is None:
                gen = bpy.data.objects.new(GENERATOR, generator_circle(props.sides))
                context.scene.collection.objects.link(gen)
            gen.location = (vel.updraft(props.vtu_height) if is_vtu(source)
                            else vel.point(props.lon, props.lat, props.height))
            gen.scale = (props.radius,) * 3
            context.view_layer.update()
            build(context, props)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        install_handler()
        # The generator is what the artist moves next: leave it selected and active.
        select_only(context, gen)
        self.report({"INFO"}, props.status)
        return {"FINISHED"}


class NEPHELE_OT_update_flow_volume(bpy.types.Operator):
    """Rebuild the smoke from the generator's current place and size"""

    bl_idname = "nephele.update_flow_volume"
    bl_label = "Update flow volume"

    def execute(self, context):
        if bpy.data.objects.get(GENERATOR) is None:
            self.report({"ERROR"}, "no flow-volume generator: add one first")
            return {"CANCELLED"}
        try:
            build(context, context.scene.nephele_flowvol)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}


class NepheleFlowVolumeProps(bpy.types.PropertyGroup):
    lon: bpy.props.FloatProperty(name="Longitude", default=-40.0, min=-180.0, max=360.0)
    lat: bpy.props.FloatProperty(name="Latitude", default=35.0, min=-90.0, max=90.0)
    height: bpy.props.FloatProperty(name="Height (m)", default=2000.0, min=0.0)
    radius: bpy.props.FloatProperty(name="Radius", default=0.03, min=1e-4,
                                    description="Generator radius in scene units (globe radius 1)")
    hours: bpy.props.FloatProperty(name="Release hours", default=24.0, min=0.0)
    start_hour: bpy.props.FloatProperty(name="Start hour", default=0.0, min=0.0)
    sides: bpy.props.IntProperty(name="Sides", default=32, min=3, max=256)
    steps: bpy.props.IntProperty(name="RK4 steps", default=8, min=1, max=256)
    tolerance: bpy.props.FloatProperty(name="Tolerance", default=0.02, min=1e-5,
                                       description="Largest gap between front points")
    exaggeration: bpy.props.FloatProperty(name="Exaggeration", default=30.0, min=1.0)
    color: bpy.props.FloatVectorProperty(name="Smoke colour", subtype="COLOR", size=3, default=(0.9, 0.9, 1.0), min=0.0,
                                         max=1.0)
    # Optical depth ~1 across the default generator's diameter: translucent smoke.
    density: bpy.props.FloatProperty(name="Density τ", default=20.0, min=0.0)
    live: bpy.props.BoolProperty(name="Live", default=True, description="Rebuild when the generator moves")
    follow_frame: bpy.props.BoolProperty(
        name="Flow with the frames", default=True,
        description="The release window moves on with the frame (by the dataset's hours per frame): the smoke flows "
                    "in a film")
    vtu_path: bpy.props.StringProperty(
        name="3-D flow (.vtu)", default="", subtype="FILE_PATH",
        description="A VTK XML unstructured grid with point vectors 'uvw' (e.g. the fire in a room): used instead of "
                    "the climate winds; times in its units")
    vtu_height: bpy.props.FloatProperty(name="Above the updraft", default=0.1, min=0.0,
                                        description="The generator starts this far above the fastest updraft of the "
                                                    "3-D flow")
    status: bpy.props.StringProperty(name="Status", default="")


class NEPHELE_PT_flowvol(SubPanel, bpy.types.Panel):
    bl_label = "Flow volume (Fig. 5)"
    bl_idname = "NEPHELE_PT_flowvol"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        p = context.scene.nephele_flowvol
        col = self.layout.column()
        for name in ("vtu_path", "vtu_height", "lon", "lat", "height", "radius", "hours", "start_hour", "sides",
                     "steps", "tolerance", "exaggeration", "color", "density", "live", "follow_frame"):
            col.prop(p, name)
        col.operator(NEPHELE_OT_add_flow_volume.bl_idname)
        col.operator(NEPHELE_OT_update_flow_volume.bl_idname)
        col.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG5"
        if p.status:
            col.label(text=p.status)


CLASSES = (NepheleFlowVolumeProps, NEPHELE_OT_add_flow_volume, NEPHELE_OT_update_flow_volume, NEPHELE_PT_flowvol)
SCENE_PROPERTIES = {"nephele_flowvol": NepheleFlowVolumeProps}
