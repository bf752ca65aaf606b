"""Layers you can edit: every Nephele object's parameters in a panel, a list of the scene's layers.

A layer's parameters stay where the frame updaters and the farm read them,
``obj["nephele"]`` (:func:`nephele.addon.frame.params`); the Object property
group ``obj.nephele_layer`` only reads and writes them there (custom get/set),
so there is one source of truth and a .blend saved without the add-on still
renders.  Changing the variable, level or colour variable of a contour
recomputes the current frame's surface at once (in the background in the
interface, see :mod:`nephele.addon.frame`); the colour ramp and its range,
and an advected texture's opacity range, edit the material only.  Layers
whose dataset settings (source, hours per frame, first frame, exaggeration,
radius) differ from the scene's are listed as stale, with one button to bring
them up to date.
"""

import threading

import bpy

from ..core.pipeline.sources import frame_hours
from . import contour_ops, data_ops, frame, materials
from .panel import SubPanel

CONTOUR_KINDS = ("contour", "advected_contour")
DATASET_KEYS = ("source", "hours_per_frame", "frame_start", "exaggeration", "radius")
"""Dataset settings a layer copies when added (and that make it stale when the scene's change)."""

BARS = "▁▂▃▄▅▆▇█"


def is_layer(obj):
    return obj is not None and bool(frame.params(obj).get("kind"))


def scene_layers(scene):
    """The Nephele objects of ``scene`` (those with parameters), in the scene's order."""
    return [o for o in scene.objects if is_layer(o)]


def stale_keys(obj, scene):
    """The dataset settings in which ``obj`` differs from ``scene``'s (empty when up to date)."""
    p = frame.params(obj)
    cfg = data_ops.settings(scene)
    out = []
    for k in DATASET_KEYS:
        if k not in p:
            continue
        a, b = p[k], cfg[k]
        same = a == b if isinstance(b, str) else abs(float(a) - float(b)) <= 1e-9 * max(1.0, abs(float(b)))
        if not same:
            out.append(k)
    return out


def refresh(obj, scene=None):
    """Recompute ``obj`` for the scene's frame after an edit (background in the interface)."""
    scene = scene or bpy.context.scene
    return frame.submit(obj, scene)


def edit(obj, scene=None, **values):
    """Change a layer's parameters and recompute its current frame; returns the new parameters.

    A contour whose name is still the automatic one follows its new level.
    """
    p = frame.params(obj)
    if not p.get("kind"):
        raise ValueError(f"{obj.name} is not a Nephele layer")
    old_auto = contour_ops.layer_name(p.get("var"), p.get("level", 0.0))
    p.update(values)
    frame.set_params(obj, p)
    if p["kind"] in CONTOUR_KINDS and ("var" in values or "level" in values) and obj.name.startswith(old_auto):
        obj.name = contour_ops.layer_name(p["var"], p["level"])
    refresh(obj, scene)
    return p


def sync_dataset(obj, scene=None):
    """Give ``obj`` the scene's dataset settings (those it keeps) and recompute it."""
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    keys = stale_keys(obj, scene)
    if keys:
        edit(obj, scene, **{k: cfg[k] for k in keys})
    return keys


def histogram_hint(stats):
    """``"▁▂█▅▃▁▁▁"``: the field's histogram over its range (counts on a square-root scale)."""
    hist = stats.get("hist") or []
    top = max(hist) if hist else 0
    if not top:
        return ""
    return "".join(BARS[min(len(BARS) - 1, int(round((h / top) ** 0.5 * (len(BARS) - 1))))] for h in hist)


def share_above(stats, level):
    """About what share of the field's finite values lies above ``level`` (from the histogram, linear within a bin)."""
    hist = stats.get("hist") or []
    total = sum(hist)
    lo, hi = stats["min"], stats["max"]
    if not total or not hi > lo:
        return float(level < lo)
    x = (float(level) - lo) / (hi - lo) * len(hist)
    if x <= 0:
        return 1.0
    if x >= len(hist):
        return 0.0
    i = int(x)
    return (sum(hist[i + 1:]) + hist[i] * (i + 1 - x)) / total


def range_line(stats, level=None):
    """``"data 0 … 0.98  ▁▂█▅▃▁▁▁"`` for the panel; says when ``level`` lies outside."""
    if stats is None:
        return "data range: not known yet", "NONE"
    if stats.get("error"):
        return f"data range: {stats['error']}", "ERROR"
    if not stats.get("finite"):
        return "no finite values at this time", "ERROR"
    text = f"data {stats['min']:.4g} … {stats['max']:.4g}  {histogram_hint(stats)}"
    if level is not None and not stats["min"] <= level <= stats["max"]:
        return text + "  (level outside)", "ERROR"
    if level is not None:
        text += f"  ~{100 * share_above(stats, level):.0f}% above"
    return text, "INFO"


_RANGES = {}  # (source, var, hours) -> stats, or None while a thread computes them


def range_for(source, var, hours):
    """The field's range for the panel without blocking it: the stats, or None while they are computed.

    The first call starts a thread (reading a field of the full demo takes
    about a second); a timer redraws the interface when it is done.
    """
    key = (str(source), str(var), round(float(hours), 6))
    if key in _RANGES:
        return _RANGES[key]
    _RANGES[key] = None

    def work():
        try:
            _RANGES[key] = contour_ops.field_stats(*key)
        except Exception as exc:  # noqa: BLE001 - shown in the panel instead of a range
            _RANGES[key] = {"error": (str(exc).strip().splitlines() or [type(exc).__name__])[0]}

    t = threading.Thread(target=work, name="nephele-range", daemon=True)
    t.start()

    def redraw():
        if t.is_alive():
            return 0.2
        frame._redraw()
        return None

    bpy.app.timers.register(redraw, first_interval=0.2)
    return None


# ---------------------------------------------------------------- the Object property group

_ITEMS = {}  # Blender needs Python to keep dynamic enum strings alive


def _names(context):
    return data_ops.dataset_names(context.scene)  # () when it does not open: the panel says why


def _var_items(self, context):
    names = set(_names(context)) | {str(frame.params(self.id_data).get("var", "cloud"))}
    names = tuple(sorted(names))
    return _ITEMS.setdefault(("var", names), [(n, n, "", i) for i, n in enumerate(names)])


def _color_items(self, context):
    names = set(_names(context)) | {str(frame.params(self.id_data).get("color_var", "altitude")), "altitude"}
    names = ("altitude",) + tuple(sorted(names - {"altitude"}))
    return _ITEMS.setdefault(("color", names), [(n, n, "", i) for i, n in enumerate(names)])


_RAMP_ITEMS = [(n, n.capitalize(), "", i) for i, n in enumerate(materials.RAMPS)] + [
    ("custom", "Custom", "A ramp given by the script that added the layer", len(materials.RAMPS))]


def _enum_get(key, items_fn, default):
    def get(self):
        value = frame.params(self.id_data).get(key, default)
        for item in items_fn(self, bpy.context):
            if item[0] == value:
                return item[3]
        return 0

    return get


def _enum_set(key, items_fn):
    def set(self, index):
        for item in items_fn(self, bpy.context):
            if item[3] == index:
                _set_param(self.id_data, key, item[0])
                return

    return set


def _material(obj):
    mats = [m for m in obj.data.materials if m is not None] if getattr(obj, "data", None) else []
    return mats[0] if mats else None


def _set_param(obj, key, value):
    p = frame.params(obj)
    if p.get(key) == value:
        return
    if key in ("var", "level", "color_var"):
        edit(obj, **{key: value})
        if key == "color_var":
            mat = _material(obj)
            vmin, vmax = contour_ops.COLOR_RANGES.get(value, (0.0, 1.0))
            if value not in contour_ops.COLOR_RANGES:
                st = contour_ops.stats_of(obj) if value == p.get("var") else None
                vmin, vmax = (st["min"], st["max"]) if st and st.get("finite") else (vmin, vmax)
            q = frame.params(obj)
            q["color_range"] = [float(vmin), float(vmax)]
            frame.set_params(obj, q)
            if mat is not None and "Nephele attribute" in mat.node_tree.nodes:
                materials.set_attribute_range(mat, attribute=value, vmin=vmin, vmax=vmax)
        return
    p[key] = value
    frame.set_params(obj, p)
    mat = _material(obj)
    if mat is None or mat.node_tree is None:
        return
    nodes = mat.node_tree.nodes
    if key == "ramp" and value != "custom" and "Nephele ramp" in nodes:
        materials.set_attribute_range(mat, ramp=value)
    elif key == "color_range" and "Nephele range" in nodes:
        materials.set_attribute_range(mat, vmin=value[0], vmax=value[1])


def _level_get(self):
    return float(frame.params(self.id_data).get("level", 0.0))


def _level_set(self, value):
    _set_param(self.id_data, "level", float(f"{value:.7g}"))  # the float32 property: 0.15, not 0.15000000596


def _range_get(self):
    p = frame.params(self.id_data)
    return tuple(p.get("color_range") or contour_ops.COLOR_RANGES.get(p.get("color_var"), (0.0, 1.0)))


def _range_set(self, value):
    _set_param(self.id_data, "color_range", [float(value[0]), float(value[1])])


def _opacity_node(obj):
    mat = _material(obj)
    if mat is None or mat.node_tree is None:
        return None
    return mat.node_tree.nodes.get("Nephele opacity")


def _opacity_get(self):
    node = _opacity_node(self.id_data)
    if node is None:
        return (0.0, 1.0)
    return (node.inputs["From Min"].default_value, node.inputs["From Max"].default_value)


def _opacity_set(self, value):
    node = _opacity_node(self.id_data)
    if node is not None:  # the texture's opacity range lives in the material: no recompute
        lo, hi = float(value[0]), max(float(value[1]), float(value[0]) + 1e-3)
        node.inputs["From Min"].default_value, node.inputs["From Max"].default_value = lo, hi


def _threshold_get(self):
    pts = frame.params(self.id_data).get("tf", {}).get("points") or [[0.0, 0.0]]
    return float(pts[0][0])


def _threshold_set(self, value):
    # The volume's transfer function: live only where the exact mode's baked support covers it
    # (the material applies it); otherwise the Volume panel re-bakes.
    from ..core.errors import DataError
    from ..core.volume.transfer import TransferFunction
    from . import volume_ops

    obj = self.id_data
    p = frame.params(obj)
    pts = [list(q) for q in p.get("tf", {}).get("points", [])]
    if len(pts) < 2:
        return
    if not value < pts[-1][0]:
        data_ops.note_problem(("tf", obj.name), f"threshold {value:g} not applied: it must lie below the transfer "
                                                f"function's last point ({pts[-1][0]:g})")
        return
    shift = float(value) - pts[0][0]
    new = [[pts[0][0] + shift, pts[0][1]]] + [q for q in pts[1:] if q[0] > value]
    try:
        tf = TransferFunction.from_dict({"points": new})
    except DataError as exc:
        data_ops.note_problem(("tf", obj.name), f"threshold {value:g} not applied: {exc}")
        return
    data_ops.note_problem(("tf", obj.name), None)
    if p.get("mode") == volume_ops.EXACT and volume_ops._within(tf, p.get("baked_tf", p["tf"])):
        p["tf"] = tf.to_dict()
        frame.set_params(obj, p)
        volume_ops.refresh_material(obj)
        obj.pop("nephele_needs_bake", None)
    else:
        obj["nephele_needs_bake"] = f"threshold {value:g} is outside what was baked: re-bake in the Volume panel"


class NepheleLayer(bpy.types.PropertyGroup):
    """A Nephele object's parameters, read from and written to ``obj["nephele"]``."""

    var: bpy.props.EnumProperty(name="Variable", items=_var_items, get=_enum_get("var", _var_items, "cloud"),
                                set=_enum_set("var", _var_items), description="Field the surface contours")
    level: bpy.props.FloatProperty(name="Level", get=_level_get, set=_level_set, precision=4, step=1,
                                   description="Contour level; the surface of the current frame is recomputed")
    color_var: bpy.props.EnumProperty(name="Colour by", items=_color_items,
                                      get=_enum_get("color_var", _color_items, "altitude"),
                                      set=_enum_set("color_var", _color_items),
                                      description="Field shown through the colour ramp")
    ramp: bpy.props.EnumProperty(name="Ramp", items=_RAMP_ITEMS,
                                 get=_enum_get("ramp", lambda s, c: _RAMP_ITEMS, "altitude"),
                                 set=_enum_set("ramp", lambda s, c: _RAMP_ITEMS))
    color_range: bpy.props.FloatVectorProperty(name="Colour range", size=2, get=_range_get, set=_range_set,
                                               description="Values at the ramp's ends")
    opacity_range: bpy.props.FloatVectorProperty(name="Texture clear, opaque", size=2, min=0.0, max=1.0,
                                                 get=_opacity_get, set=_opacity_set,
                                                 description="Texture values mapped to clear and to opaque")
    threshold: bpy.props.FloatProperty(name="Threshold", get=_threshold_get, set=_threshold_set, precision=4,
                                       description="Where the volume's opacity starts")


class NepheleLayersUI(bpy.types.PropertyGroup):
    """The layer list's active row: the active object (selecting a row selects the object)."""

    def _get(self):
        scene = self.id_data
        active = bpy.context.view_layer.objects.active if bpy.context.view_layer else None
        for i, o in enumerate(scene.objects):
            if o == active:
                return i
        return -1

    def _set(self, index):
        scene = self.id_data
        if not 0 <= index < len(scene.objects):
            return
        obj = scene.objects[index]
        view_layer = bpy.context.view_layer
        for o in list(view_layer.objects.selected):
            o.select_set(False)
        if obj.visible_get(view_layer=view_layer) or not obj.hide_get(view_layer=view_layer):
            obj.select_set(True)
        view_layer.objects.active = obj

    index: bpy.props.IntProperty(get=_get, set=_set)


class NEPHELE_UL_layers(bpy.types.UIList):
    """The scene's Nephele objects: name, kind, stale mark, visibility, delete."""

    def filter_items(self, context, data, propname):
        objs = getattr(data, propname)
        flags = [self.bitflag_filter_item if is_layer(o) else 0 for o in objs]
        return flags, []

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        p = frame.params(item)
        row = layout.row(align=True)
        icon = "ERROR" if stale_keys(item, context.scene) else {
            "contour": "MESH_ICOSPHERE", "advected_contour": "TEXTURE", "volume": "VOLUME_DATA"}.get(
            p.get("kind"), "OBJECT_DATA")
        row.prop(item, "name", text="", emboss=False, icon=icon)
        row.label(text=p.get("kind", ""))
        row.prop(item, "hide_viewport", text="", emboss=False)
        row.prop(item, "hide_render", text="", emboss=False)
        row.operator(NEPHELE_OT_delete_layer.bl_idname, text="", icon="X", emboss=False).name = item.name


class NEPHELE_OT_delete_layer(bpy.types.Operator):
    """Delete this Nephele layer (its object and, if unused elsewhere, its mesh)"""

    bl_idname = "nephele.delete_layer"
    bl_label = "Delete layer"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty()

    def execute(self, context):
        obj = bpy.data.objects.get(self.name)
        if obj is None or not is_layer(obj):
            self.report({"ERROR"}, f"no Nephele layer named {self.name!r}")
            return {"CANCELLED"}
        frame._drop(frame._uid(obj))
        data = obj.data
        bpy.data.objects.remove(obj)
        if isinstance(data, bpy.types.Mesh) and data.users == 0:
            bpy.data.meshes.remove(data)
        self.report({"INFO"}, f"deleted {self.name}")
        return {"FINISHED"}


class NEPHELE_OT_sync_layers(bpy.types.Operator):
    """Give stale layers the scene's dataset settings (hours per frame, first frame, ...) and recompute them"""

    bl_idname = "nephele.sync_layers"
    bl_label = "Update stale layers"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        done = []
        for obj in scene_layers(context.scene):
            if frame.params(obj).get("kind") in CONTOUR_KINDS and sync_dataset(obj, context.scene):
                done.append(obj.name)
        left = [o.name for o in scene_layers(context.scene) if stale_keys(o, context.scene)]
        msg = f"updated {len(done)} layer(s)" + (f"; re-add or re-bake: {', '.join(left)}" if left else "")
        self.report({"WARNING"} if left else {"INFO"}, msg)
        return {"FINISHED"}


class NEPHELE_PT_layers(SubPanel, bpy.types.Panel):
    bl_label = "Layers"
    bl_idname = "NEPHELE_PT_layers"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        ui = getattr(scene, "nephele_layers", None)
        if ui is not None:
            layout.template_list("NEPHELE_UL_layers", "", scene, "objects", ui, "index", rows=3)
        stale = [o for o in scene_layers(scene) if stale_keys(o, scene)]
        if stale:
            box = layout.box()
            for o in stale[:6]:
                box.label(text=f"{o.name}: stale {', '.join(stale_keys(o, scene))}", icon="ERROR")
            box.operator(NEPHELE_OT_sync_layers.bl_idname, icon="FILE_REFRESH")
        if frame.busy() or frame.STATUS["text"]:
            row = layout.row()
            row.label(text=frame.STATUS["text"] or "working…", icon="TIME")
            row.operator(frame.NEPHELE_OT_cancel_jobs.bl_idname, text="", icon="CANCEL")
        for msg in frame.STATUS["errors"][-2:]:
            layout.label(text=msg, icon="ERROR")
        obj = context.active_object
        if not is_layer(obj) or not hasattr(obj, "nephele_layer"):
            return
        self._draw_layer(layout, obj)

    @staticmethod
    def _draw_layer(layout, obj):
        p = frame.params(obj)
        lay = obj.nephele_layer
        box = layout.box()
        box.label(text=obj.name, icon="OBJECT_DATA")
        kind = p.get("kind")
        if kind in CONTOUR_KINDS:
            col = box.column(align=True)
            col.prop(lay, "var")
            col.prop(lay, "level")
            text, icon = range_line(contour_ops.stats_of(obj), p.get("level"))
            col.label(text=text, icon=icon)
            col = box.column(align=True)
            if kind == "contour":
                col.prop(lay, "color_var")
                col.prop(lay, "ramp")
                col.prop(lay, "color_range")
                _legend(col, p)
            else:
                col.prop(lay, "opacity_range")
                col.label(text=f"texture: {p.get('strategy')}, every {p.get('period')} frames")
            empty = contour_ops.empty_message(obj)
            if empty:
                box.label(text=empty, icon="ERROR")
            box.label(text=f"model time {obj.get('nephele_hours', 0.0):g} h, {len(obj.data.polygons)} triangles")
        elif kind == "volume":
            box.label(text=f"{p.get('var')}, {p.get('mode')} mode, frames {p.get('frames')}")
            box.prop(lay, "threshold")
            data_ops.draw_problem(box, ("tf", obj.name))
            if p.get("source") and p.get("var"):
                hours = _hours_shown(p, bpy.context.scene)
                if hours is None:
                    data_ops.draw_problem(box, ("dataset", p["source"]))
                else:
                    text, icon = range_line(range_for(p["source"], p["var"], hours), lay.threshold)
                    box.label(text=text.replace("above", "above the threshold"), icon=icon)
            pts = p.get("tf", {}).get("points", [])
            box.label(text="transfer: " + ", ".join(f"{v:g}→{a:g}" for v, a in pts[:4]))
            if obj.get("nephele_needs_bake"):
                box.label(text=obj["nephele_needs_bake"], icon="ERROR")
        else:
            box.label(text=f"{kind}: edit in its own panel")


def _hours_shown(p, scene):
    """Model time of ``scene``'s frame for a layer with parameters ``p``; None when its dataset does not open
    (the reason is noted for the panel)."""
    try:
        last = float(data_ops.dataset(p["source"]).hours[-1])
    except Exception as exc:  # noqa: BLE001 - shown in the panel instead of a model time of 0
        data_ops.note_problem(("dataset", p["source"]), exc)
        return None
    return frame_hours(scene.frame_current, p.get("frame_start", 1), p.get("hours_per_frame", 1.0), last)


def _legend(layout, p):
    """A text legend of the colour ramp: the value at each stop."""
    ramp = materials.RAMPS.get(p.get("ramp"))
    lo, hi = p.get("color_range") or (0.0, 1.0)
    if not ramp:
        return
    unit = " m" if p.get("color_var") == "altitude" else ""
    row = layout.row(align=True)
    for pos, rgb in ramp:
        cell = row.column(align=True)
        cell.label(text=f"{lo + pos * (hi - lo):.5g}{unit}")
        cell.label(text="■ " + "#%02x%02x%02x" % tuple(int(255 * c ** (1 / 2.2)) for c in rgb))


CLASSES = frame.CLASSES + (NepheleLayer, NepheleLayersUI, NEPHELE_UL_layers, NEPHELE_OT_delete_layer,
                           NEPHELE_OT_sync_layers, NEPHELE_PT_layers)
SCENE_PROPERTIES = {"nephele_layers": NepheleLayersUI}


def install():
    bpy.types.Object.nephele_layer = bpy.props.PointerProperty(type=NepheleLayer)


def uninstall():
    if hasattr(bpy.types.Object, "nephele_layer"):
        del bpy.types.Object.nephele_layer
