"""The volume clouds' panel (Fig. 2): the settings, the transfer-function editors, the bake estimate,
"Add volume clouds" and the edits that apply live.

The layer itself (object, material, bake and frame updater) is :mod:`.volume_ops`.
"""

import json

import bpy

from ..core.errors import DataError
from ..core.memory import format_bytes
from ..core.volume.sparse import ALTITUDE, DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE, EXACT, VOXELS
from ..core.volume.transfer import ColorMap, TransferFunction
from ..core.volume.volume_atlas import DEFAULT_SUPPORT_SIZE
from . import data_ops, frame, tf_ramp
from .mesh import select_only
from .panel import SubPanel
from .volume_ops import (
    _obj_params,
    _within,
    add_volume_clouds,
    bake_estimate,
    default_color_map,
    empty_message,
    look_warnings,
    refresh_material,
    volume_look,
)


def _settings(scene):
    return getattr(scene, "nephele_volume", None)


TF_THRESHOLD, TF_RAMP, TF_POINTS = "THRESHOLD", "RAMP", "POINTS"
TF_POINTS_HELP = "a JSON list of [value, opacity] pairs with ascending values, e.g. [[0.3, 0], [1, 1]]"


def panel_tf(s):
    """The transfer function the panel describes: the threshold ramp, the
    colour-ramp widget (:mod:`.tf_ramp`) or the typed points, by ``tf_edit``.

    Raises :class:`DataError` naming the field and the expected form when the
    points are not such a list (never the JSON parser's own words) or the
    ramp's range does not rise.
    """
    if s.tf_edit == TF_RAMP and tf_ramp.ramp_node(s.tf_tree) is not None:
        try:
            return tf_ramp.ramp_tf(tf_ramp.ramp_node(s.tf_tree), s.tf_min, s.tf_max)
        except ValueError as exc:
            raise DataError(str(exc), field="Opacity ramp") from None
    text = s.tf_points.strip()
    if s.tf_edit == TF_POINTS and text:
        try:
            pts = json.loads(text)
            return TransferFunction(points=tuple((float(v), float(o)) for v, o in pts))
        except (ValueError, TypeError) as exc:
            why = "is not valid JSON" if isinstance(exc, json.JSONDecodeError) else "is not such a list"
            raise DataError(f"{text[:40]!r} {why}: give {TF_POINTS_HELP}", field="TF points") from None
    return TransferFunction.ramp(s.threshold, s.full, s.opacity)


def panel_cmap(s):
    base = default_color_map(s.color_var)
    if s.use_color_range:
        lo, hi = base.range
        span = hi - lo if hi > lo else 1.0
        return ColorMap(points=tuple((s.color_min + (v - lo) / span * (s.color_max - s.color_min), c)
                                     for v, c in base.points))
    return base


def _active_volumes(context):
    return [o for o in context.scene.objects if o.type == "VOLUME" and _obj_params(o) is not None]


def _on_material_change(self, context):
    # Extinction and colours live in the material: edit without re-baking.
    for obj in _active_volumes(context):
        p = _obj_params(obj)
        p["extinction"] = float(self.extinction)
        if p.get("color_var", "") == self.color_var:
            p["cmap"] = panel_cmap(self).to_dict()
        frame.set_params(obj, p)
        refresh_material(obj)


def stale(context):
    """True when the panel's transfer function or grids differ from the baked ones.

    In the exact mode the material applies the transfer function itself: a
    change that keeps its non-zero range within the baked support is live
    (see :func:`_on_tf_change`); only a wider range needs a new bake.
    """
    s = _settings(context.scene)
    objs = _active_volumes(context)
    if s is None or not objs:
        return False
    p = _obj_params(objs[0])
    try:
        tf = panel_tf(s)
    except (ValueError, TypeError, DataError):
        return True
    mode = p.get("mode", VOXELS)
    if s.mode != mode or s.var != p["var"] or s.color_var != p.get("color_var", ""):
        return True
    if mode == EXACT:
        return not _within(tf, p["baked_tf"]) or abs(s.support_size - p["support_size"]) > 1e-12
    return tf.to_dict() != p["tf"] or abs(s.voxel_size - p["voxel_size"]) > 1e-12


def _on_tf_change(self, context):
    # Exact mode: the transfer function lives in the material; apply it at
    # once where the baked support still covers it.
    try:
        tf = panel_tf(self)
    except (ValueError, TypeError, DataError):
        return
    for obj in _active_volumes(context):
        p = _obj_params(obj)
        if p.get("mode") == EXACT and p["tf"] != tf.to_dict() and _within(tf, p["baked_tf"]):
            p["tf"] = tf.to_dict()
            frame.set_params(obj, p)
            refresh_material(obj)


def _on_tf_edit(self, context):
    # The ramp starts as the transfer function the panel showed, over 0 .. its last point.
    if self.tf_edit == TF_RAMP and tf_ramp.ramp_node(self.tf_tree) is None:
        try:
            tf = TransferFunction.ramp(self.threshold, self.full, self.opacity)
        except DataError:
            tf = TransferFunction.ramp(0.3)
        lo = min(0.0, tf.points[0][0])
        hi = max(tf.points[-1][0], lo + 1e-6)
        self.tf_min, self.tf_max = lo, hi
        self.tf_tree = tf_ramp.new_tree(f"Nephele opacity ({context.scene.name})", tf, lo, hi)
    _on_tf_change(self, context)


@bpy.app.handlers.persistent
def _ramp_edited(scene, depsgraph):
    # A ramp edit is a node-tree update, which calls no property callback: apply it here.
    if not depsgraph.id_type_updated("NODETREE"):
        return
    trees = {u.id.original for u in depsgraph.updates if isinstance(u.id, bpy.types.NodeTree)}
    for sc in bpy.data.scenes:
        s = _settings(sc)
        if s is not None and s.tf_edit == TF_RAMP and s.tf_tree is not None and s.tf_tree in trees:
            _on_tf_change(s, _SceneContext(sc))


class _SceneContext:
    def __init__(self, scene):
        self.scene = scene


def install():
    handlers = bpy.app.handlers.depsgraph_update_post
    if not any(getattr(h, "__name__", "") == "_ramp_edited" for h in handlers):
        handlers.append(_ramp_edited)


def uninstall():
    for h in [h for h in bpy.app.handlers.depsgraph_update_post if getattr(h, "__name__", "") == "_ramp_edited"]:
        bpy.app.handlers.depsgraph_update_post.remove(h)


class NephelePropsVolume(bpy.types.PropertyGroup):
    var: bpy.props.StringProperty(name="Variable", default="cloud", description="Field behind the opacity",
                                  search=data_ops.variable_search)
    mode: bpy.props.EnumProperty(
        name="Mode", default=EXACT,
        items=[(EXACT, "Exact", "The material evaluates the curvilinear field at every sample from atlas images: "
                "opacity exact along every ray"),
               (VOXELS, "Voxels", "Opacity resampled into a VDB of cubic voxels (grazing rays can be far off; "
                "use it for EEVEE, which renders the exact mode striped)")],
    )
    threshold: bpy.props.FloatProperty(name="Threshold", default=0.3, update=_on_tf_change,
                                       description="Opacity is zero up to this value")
    full: bpy.props.FloatProperty(name="Full at", default=1.0, update=_on_tf_change,
                                  description="Value where the opacity reaches its maximum")
    opacity: bpy.props.FloatProperty(name="Opacity", default=1.0, min=0.0, max=1.0, update=_on_tf_change,
                                     description="Opacity at the full value")
    tf_edit: bpy.props.EnumProperty(
        name="Transfer function", default=TF_THRESHOLD, update=_on_tf_edit,
        items=[(TF_THRESHOLD, "Threshold", "Opacity rises linearly from the threshold to its full value"),
               (TF_RAMP, "Ramp", "Opacity drawn as a ramp over a value range (black transparent, white opaque)"),
               (TF_POINTS, "Points", "Opacity typed as [value, opacity] points")],
    )
    tf_tree: bpy.props.PointerProperty(type=bpy.types.NodeTree, name="Opacity ramp",
                                       description="Node group holding the opacity ramp")
    tf_min: bpy.props.FloatProperty(name="Ramp from", default=0.0, update=_on_tf_change,
                                    description="Value at the ramp's left end")
    tf_max: bpy.props.FloatProperty(name="Ramp to", default=1.0, update=_on_tf_change,
                                    description="Value at the ramp's right end")
    tf_points: bpy.props.StringProperty(
        name="TF points", default="", update=_on_tf_change,
        description="Transfer function as JSON [[value, opacity], ...]",
    )
    support_size: bpy.props.FloatProperty(
        name="Support voxel", default=DEFAULT_SUPPORT_SIZE, min=1e-3, max=1.0, precision=4,
        description="Exact mode: scene units between the voxels of the grid that bounds where the renderer looks",
    )
    color_var: bpy.props.StringProperty(name="Colour by", default=ALTITUDE,
                                        description='"altitude", a field such as "temperature", or empty')
    use_color_range: bpy.props.BoolProperty(name="Own colour range", default=False, update=_on_material_change)
    color_min: bpy.props.FloatProperty(name="Colour min", default=0.0, update=_on_material_change)
    color_max: bpy.props.FloatProperty(name="Colour max", default=12000.0, update=_on_material_change)
    voxel_size: bpy.props.FloatProperty(name="Voxel size", default=DEFAULT_VOXEL_SIZE, min=1e-4, max=1.0, precision=4,
                                        description="Scene units between voxels (globe radius 1)")
    extinction: bpy.props.FloatProperty(name="Extinction", default=DEFAULT_EXTINCTION, min=0.0, max=1e6,
                                        update=_on_material_change,
                                        description="Extinction per scene unit at opacity 1")
    directory: bpy.props.StringProperty(name="Directory", default="", subtype="DIR_PATH",
                                        description="Where the .vdb sequence goes (empty: beside the .blend)")
    current_only: bpy.props.BoolProperty(
        name="Current frame only", default=True,
        description="Bake only the current frame (a quick look); off: the number of frames below",
    )
    frame_count: bpy.props.IntProperty(
        name="Frames", default=24, min=1, max=100000,
        description="Frames to bake from the current frame on (clipped to the data's time span)",
    )


def bake_frames(context, s):
    """The frames the panel bakes: the current one, or ``frame_count`` from it on
    (clipped to the data's time span)."""
    cur = context.scene.frame_current
    if s.current_only:
        return cur, cur
    try:
        ds = data_ops.dataset(scene=context.scene)
        last = data_ops.frame_range_for(ds, data_ops.settings(context.scene))[1]
    except (DataError, OSError, ImportError):
        last = cur + s.frame_count - 1
    return cur, max(cur, min(cur + s.frame_count - 1, last))


def panel_estimate(context, s):
    """``(frames, estimate dict)`` of what the panel's bake would take, or raises DataError."""
    cfg = data_ops.settings(context.scene)
    ds = data_ops.dataset(scene=context.scene)
    if s.var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", field=s.var)
    var = ds.resolve(s.var)
    f0, f1 = bake_frames(context, s)
    from ..core.pipeline.sources import frame_hours

    hours = frame_hours(f0, cfg["frame_start"], cfg["hours_per_frame"], last_hour=float(ds.hours[-1]))
    tf = panel_tf(s)
    mode = s.mode
    size = s.support_size if mode == EXACT else s.voxel_size
    # The panel redraws often: one field read per distinct question.
    key = (cfg["source"], var, json.dumps(tf.to_dict()), hours, mode, size, cfg["exaggeration"], cfg["radius"])
    est = _ESTIMATES.get(key)
    if est is None:
        est = bake_estimate(ds, var, tf, hours=hours, mode=mode, size=size,
                            exaggeration=cfg["exaggeration"], radius=cfg["radius"])
        if len(_ESTIMATES) > 32:
            _ESTIMATES.clear()
        _ESTIMATES[key] = est
    return (f0, f1), est


_ESTIMATES = {}


def estimate_text(frames, est):
    n = frames[1] - frames[0] + 1
    return (f"{n} frame{'s' if n > 1 else ''} ({frames[0]}-{frames[1]}): about {format_bytes(n * est['disk'])} "
            f"on disk, {n * est['seconds']:.0f} s, {format_bytes(est['memory'])} of memory")


class NEPHELE_OT_add_volume_clouds(bpy.types.Operator):
    """Resample the field into a VDB sequence (one file per frame) and show it as a volume"""

    bl_idname = "nephele.add_volume_clouds"
    bl_label = "Add volume clouds"
    bl_options = {"REGISTER", "UNDO"}

    def invoke(self, context, event):
        # Several frames: say what they will cost before starting.
        s = _settings(context.scene)
        if s.current_only:
            return self.execute(context)
        return context.window_manager.invoke_confirm(self, event, title="Bake volume clouds",
                                                     message=self._estimate(context), confirm_text="Bake")

    def _estimate(self, context):
        try:
            frames, est = panel_estimate(context, _settings(context.scene))
        except (ValueError, OSError, ImportError) as exc:
            return str(exc)
        return estimate_text(frames, est)

    def execute(self, context):
        s = _settings(context.scene)
        wm = context.window_manager
        frames = bake_frames(context, s)
        # Several frames in the interface: the layer is added at once and its frames bake in the background.
        background = context.window is not None and frames[1] > frames[0]

        def progress(i, n, info):
            wm.progress_update(int(100 * i / max(n, 1)))

        wm.progress_begin(0, 100)
        try:
            tf = panel_tf(s)
            obj, infos = add_volume_clouds(
                s.var, tf, color_var=s.color_var, cmap=panel_cmap(s), voxel_size=s.voxel_size,
                extinction=s.extinction, directory=s.directory or None, scene=context.scene, frames=frames,
                progress=progress, mode=s.mode, support_size=s.support_size, bake="lazy" if background else "all",
            )
        except (DataError, ValueError, OSError, ImportError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        p = frame.params(obj)
        msg = empty_message(p)
        if background:
            bpy.ops.nephele.bake_volume("INVOKE_DEFAULT", name=obj.name)
        elif msg:
            self.report({"WARNING"}, msg)
        else:
            voxels = sum(i["active_voxels"] for i in infos)
            what = "support voxels" if p.get("mode") == EXACT else "active voxels"
            self.report({"INFO"}, f"{len(infos)} VDB frames in {data_ops.layer_dir(p)}, {voxels} {what}")
        # What the clouds' look needs from the scene (Fig. 2's settings), said aloud.
        for attr, old, new in volume_look(context.scene):
            self.report({"INFO"}, f"Cycles {attr.replace('_', ' ')} raised from {old} to {new} for lit clouds")
        for line in look_warnings(context.scene, obj):
            self.report({"WARNING"}, line)
        select_only(context, obj)
        return {"FINISHED"}


def draw_tf(layout, s):
    """The transfer-function editor: threshold fields, the ramp widget or the points."""
    layout.row().prop(s, "tf_edit", expand=True)
    node = tf_ramp.ramp_node(s.tf_tree)
    if s.tf_edit == TF_RAMP and node is not None:
        layout.template_color_ramp(node, "color_ramp", expand=True)
        row = layout.row(align=True)
        row.prop(s, "tf_min")
        row.prop(s, "tf_max")
    elif s.tf_edit == TF_POINTS:
        layout.prop(s, "tf_points")
    else:
        layout.prop(s, "threshold")
        layout.prop(s, "full")
        layout.prop(s, "opacity")
    try:
        panel_tf(s)
    except (ValueError, TypeError) as exc:  # DataError is a ValueError: say why the edit is not applied
        layout.label(text=f"Not applied: {exc}", icon="ERROR")


class NEPHELE_PT_volume(SubPanel, bpy.types.Panel):
    bl_label = "Volume clouds"
    bl_idname = "NEPHELE_PT_volume"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        s = _settings(context.scene)
        layout.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG2"
        if s is None:
            return
        col = layout.column()
        col.prop(s, "var")
        col.prop(s, "mode")
        draw_tf(col, s)
        col.prop(s, "color_var")
        col.prop(s, "use_color_range")
        if s.use_color_range:
            row = col.row(align=True)
            row.prop(s, "color_min")
            row.prop(s, "color_max")
        col.prop(s, "support_size" if s.mode == EXACT else "voxel_size")
        col.prop(s, "extinction")
        col.prop(s, "directory")
        col.prop(s, "current_only")
        if not s.current_only:
            col.prop(s, "frame_count")
        try:
            frames, est = panel_estimate(context, s)
            layout.label(text=estimate_text(frames, est), icon="INFO")
        except (ValueError, OSError, ImportError) as exc:  # DataError is a ValueError
            layout.label(text=str(exc), icon="ERROR")
        objs = _active_volumes(context)
        for line in look_warnings(context.scene, objs[0]) if objs else ():
            layout.label(text=line, icon="ERROR")
        if objs:
            msg = empty_message(frame.params(objs[0]))
            if msg:
                layout.label(text="Volume is empty: lower the threshold", icon="ERROR")
            if frame.params(objs[0]).get("lazy"):
                layout.operator("nephele.bake_volume", text="Bake all frames now", icon="RENDER_ANIMATION")
            if stale(context):
                layout.label(text="Transfer function changed", icon="INFO")
                layout.operator(NEPHELE_OT_add_volume_clouds.bl_idname, text="Re-bake volume")
                return
        layout.operator(NEPHELE_OT_add_volume_clouds.bl_idname)


CLASSES = (NephelePropsVolume, NEPHELE_OT_add_volume_clouds, NEPHELE_PT_volume)
SCENE_PROPERTIES = {"nephele_volume": NephelePropsVolume}
