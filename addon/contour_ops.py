"""Contour surfaces that follow the frame (Fig. 1: 15% cloudiness).

The object keeps only parameters (``obj["nephele"]``); on every frame change
the updater maps the frame to model time, gets the mesh from the cache (or
computes it with the ``"contour"`` task of :mod:`nephele.core.surface.contour_task`)
and refills the object's mesh in place.  It uses only ``bpy.data`` and the
scene it is given, so it works in a headless render of a saved .blend with
nothing but :func:`nephele.addon.frame.install` (no add-on, no window).
"""

import json
import threading
from collections import OrderedDict

import bpy
import numpy as np

from ..core.pipeline import sources
from ..core.pipeline.cache import source_stamp
from ..core.pipeline.tasks import run_cached
from ..core.surface import contour_task
from ..core.surface.mesh import Mesh
from . import data_ops, frame, materials
from .mesh import fill_mesh, select_only
from .panel import SubPanel

COLOR_RANGES = {"altitude": (0.0, 12000.0), "temperature": (220.0, 300.0), "cloud": (0.0, 1.0)}
"""Default colour-ramp ranges per attribute (others: the level's field range is unknown, 0..1)."""

HIST_BINS = 8
_STATS = OrderedDict()
_STATS_LOCK = threading.Lock()  # filled by the frame worker, read by the main thread


def layer_name(var, level, prefix="Contour"):
    """``"Contour cloud [0.15]"``: the bracket keeps Blender from reading ``.15`` as a duplicate counter.

    (Blender renames a second ``"Contour cloud 0.15"`` to ``"Contour cloud 0.001"``.)
    """
    return f"{prefix} {var} [{float(level):g}]"


def field_stats(source, var, hours):
    """Range and histogram of field ``var`` at model time ``hours``: ``{"min", "max", "hist", "finite"}``.

    ``hist`` counts the finite values in :data:`HIST_BINS` equal bins over
    ``[min, max]``; ``finite`` is their share of the grid.  Kept for the last
    few fields asked (the panel shows it next to the level).
    """
    ds = sources.open_source(source)
    key = (source_stamp(source), str(var), round(float(hours), 6))
    with _STATS_LOCK:
        hit = _STATS.get(key)
    if hit is not None:
        return hit
    if var not in ds:
        raise KeyError(var)
    v = np.asarray(ds.read_at(var, hours), dtype=np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if v.size:
        lo, hi = float(v.min()), float(v.max())
        hist = np.histogram(v, bins=HIST_BINS, range=(lo, hi if hi > lo else lo + 1.0))[0]
        out = {"min": lo, "max": hi, "hist": [int(h) for h in hist], "finite": v.size / float(np.prod(ds.grid.shape))}
    else:
        out = {"min": float("nan"), "max": float("nan"), "hist": [0] * HIST_BINS, "finite": 0.0}
    with _STATS_LOCK:
        _STATS[key] = out
        while len(_STATS) > 16:
            _STATS.popitem(last=False)
    return out


def stats_of(obj):
    """The data range stored on ``obj`` by its last update (None if unknown)."""
    raw = obj.get("nephele_range")
    return json.loads(raw) if raw else None


def empty_message(obj):
    """One line for an empty contour, naming the data's range; None when the surface is not empty."""
    if len(obj.data.polygons):
        return None
    p = frame.params(obj)
    st = stats_of(obj)
    hours = obj.get("nephele_hours", 0.0)
    if st is None or st["finite"] == 0.0:
        return f"{obj.name}: {p.get('var')} has no finite values at {hours:g} h: the surface is empty"
    return (f"{obj.name}: no surface at {p.get('var')} = {p.get('level'):g} at {hours:g} h; "
            f"the data range is {st['min']:.4g} to {st['max']:.4g}")


def compute(args, job=None):
    """Worker side: the mesh arrays (cache or computed) and the field's range; no ``bpy``."""
    tp = args["tp"]
    arrays = run_cached(args["kind"], tp, args["cache"])
    try:
        stats = field_stats(tp["source"], tp["var"], tp["hours"])
    except KeyError:
        stats = None
    return {"arrays": arrays, "stats": stats}


def apply(obj, args, result):
    """Main-thread side: refill the mesh, remember the model time and the data range."""
    fill_mesh(obj.data, Mesh.from_arrays(result["arrays"]))
    obj["nephele_hours"] = args["tp"]["hours"]
    if result["stats"] is not None:
        obj["nephele_range"] = json.dumps(result["stats"])


update_contour = frame.register_job("contour", frame.plan_task, compute, apply)
"""Synchronous updater ``(obj, params, scene, frame)`` (headless, renders, and the add dialog)."""


def add_contour(var="cloud", level=0.15, *, source=None, exaggeration=None, radius=None, color_var="altitude",
                method="cubes", ramp=None, color_range=None, scene=None, collection=None, name=None):
    """Add a contour-surface object that follows the frame.

    Parameters
    ----------
    var : str
        Field to contour.
    level : float
        Contour level (e.g. 0.15 for 15% cloudiness).
    source : str, optional
        Dataset; default: the scene's.
    exaggeration, radius : float, optional
        Default: the scene's settings (the globe's).
    color_var : str
        ``"altitude"`` (metres) or another field of the dataset, shown through a colour ramp.
    method : {"cubes", "tetra5"}
        Contouring method (``tetra5`` is the paper's 5-tetrahedra split).
    ramp : str or list, optional
        Colour ramp (see :data:`nephele.addon.materials.RAMPS`); default by ``color_var``.
    color_range : (float, float), optional
        Attribute values at the ramp's ends.

    Returns
    -------
    bpy.types.Object
    """
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    params = {
        "kind": "contour",
        "source": str(source or cfg["source"]),
        "var": str(var),
        "level": float(level),
        "exaggeration": float(cfg["exaggeration"] if exaggeration is None else exaggeration),
        "radius": float(cfg["radius"] if radius is None else radius),
        "color_var": str(color_var or contour_task.ALTITUDE),
        "method": str(method),
        "hours_per_frame": float(cfg["hours_per_frame"]),
        "frame_start": int(cfg["frame_start"]),
    }
    name = name or layer_name(var, level)
    me = bpy.data.meshes.new(name)
    obj = bpy.data.objects.new(name, me)
    (collection or scene.collection).objects.link(obj)
    vmin, vmax = color_range or COLOR_RANGES.get(params["color_var"], (0.0, 1.0))
    if ramp is None:
        ramp = "temperature" if params["color_var"] == "temperature" else (
            "altitude" if params["color_var"] == "altitude" else "viridis")
    mat = materials.attribute_material(f"{name} colour", params["color_var"], vmin, vmax, ramp)
    materials.assign(obj, mat)
    params["ramp"] = ramp if isinstance(ramp, str) else "custom"
    params["color_range"] = [float(vmin), float(vmax)]
    frame.set_params(obj, params)
    frame.submit(obj, scene)  # at once headless; in the interface in the background
    return obj


_ENUM_ITEMS = {}  # Blender needs Python to keep dynamic enum strings alive


def _variables(self, context):
    # A dataset that does not open still offers the standard name; why it does not open is in the panel.
    names = list(data_ops.dataset_names(context.scene)) or ["cloud"]
    return _ENUM_ITEMS.setdefault(("var", tuple(names)), [(n, n, "") for n in names])


def _color_variables(self, context):
    names = tuple(item[0] for item in _variables(self, context) if item[0] != "altitude")
    return _ENUM_ITEMS.setdefault(("color", names), [("altitude", "altitude", "Height above sea level")]
                                  + [(n, n, "") for n in names])


def report_result(op, obj):
    """Report a layer's new result from operator ``op``: ERROR (object removed), WARNING if empty, else INFO."""
    err = frame.last_error(obj)
    if err:
        op.report({"ERROR"}, err)
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.meshes.remove(data)
        return {"CANCELLED"}
    if "nephele_shown" not in obj:  # cancelled before its first result
        op.report({"WARNING"}, f"{obj.name}: cancelled before its first result; 'Update to frame' computes it")
        return {"FINISHED"}
    empty = empty_message(obj)
    if empty:
        op.report({"WARNING"}, empty)
    else:
        op.report({"INFO"}, f"{obj.name}: {len(obj.data.polygons)} triangles")
    return {"FINISHED"}


class NEPHELE_OT_add_contour(frame.BackgroundAdd, bpy.types.Operator):
    """Add a contour surface of a field that follows the frame through model time"""

    bl_idname = "nephele.add_contour"
    bl_label = "Add contour surface"
    bl_options = {"REGISTER", "UNDO"}

    var: bpy.props.EnumProperty(name="Variable", items=_variables)
    level: bpy.props.FloatProperty(name="Level", default=0.15)
    exaggeration: bpy.props.FloatProperty(name="Vertical exaggeration", default=-1.0,
                                          description="Negative: the scene's setting (same as the globe)")
    color_var: bpy.props.EnumProperty(name="Colour by", items=_color_variables)
    method: bpy.props.EnumProperty(name="Method", items=[
        ("cubes", "Marching cubes", "Cells contoured as cubes"),
        ("tetra5", "5 tetrahedra", "The paper's split of each cell into 5 tetrahedra"),
    ])

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        from ..core.errors import DataError

        try:
            obj = add_contour(self.var, self.level, scene=context.scene, color_var=self.color_var,
                              exaggeration=None if self.exaggeration < 0 else self.exaggeration,
                              method=self.method)
        except (DataError, OSError, ImportError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        select_only(context, obj)
        return self.wait_for(context, obj)

    def done(self, context, obj):
        return report_result(self, obj)


class NEPHELE_OT_update_contours(bpy.types.Operator):
    """Recompute every Nephele object for the current frame"""

    bl_idname = "nephele.update_frame"
    bl_label = "Update to frame"

    def execute(self, context):
        frame.update_scene(context.scene)
        return {"FINISHED"}


class NEPHELE_PT_contour(SubPanel, bpy.types.Panel):
    bl_label = "Contour surfaces"
    bl_idname = "NEPHELE_PT_contour"

    def draw(self, context):
        col = self.layout.column(align=True)
        col.operator(NEPHELE_OT_add_contour.bl_idname, icon="MESH_ICOSPHERE")
        col.operator(NEPHELE_OT_update_contours.bl_idname, icon="FILE_REFRESH")
        col.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG1"
        data_ops.draw_problem(self.layout, ("dataset", data_ops.settings(context.scene)["source"]))
        obj = context.active_object
        p = frame.params(obj) if obj is not None else {}
        if p.get("kind") == "contour" and hasattr(obj, "nephele_layer"):
            box = self.layout.box()  # the layer's own fields (the Layers panel has them all)
            col = box.column(align=True)
            col.prop(obj.nephele_layer, "var")
            col.prop(obj.nephele_layer, "level")
            st = stats_of(obj)
            if st is not None and st.get("finite"):
                col.label(text=f"data {st['min']:.4g} … {st['max']:.4g}")
            empty = empty_message(obj)
            if empty:
                box.label(text=empty, icon="ERROR")
            box.label(text=f"model time {obj.get('nephele_hours', 0.0):.2f} h, {len(obj.data.polygons)} triangles")


CLASSES = (NEPHELE_OT_add_contour, NEPHELE_OT_update_contours, NEPHELE_PT_contour)
