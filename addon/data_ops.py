"""Which dataset a scene shows, and how frames map to model time.

The settings live in a JSON ID property ``scene["nephele_settings"]``, so a
saved .blend opened without the add-on (the farm) still knows them; the
PropertyGroup ``scene.nephele_data`` that the panel shows reads and writes
that same property.  Every layer
reads the radius and vertical exaggeration from here, so the globe, contours,
volumes and textures line up.
"""

import json

import bpy

from ..core.climate.grid import DEFAULT_EXAGGERATION
from .panel import SubPanel

MIRROR_KEY = "nephele_settings"

DEFAULTS = {
    "source": "demo",
    "hours_per_frame": 1.0,
    "frame_start": 1,
    "exaggeration": DEFAULT_EXAGGERATION,
    "radius": 1.0,
}
"""Defaults of the scene settings (radius 1, the grid module's exaggeration)."""


def settings(scene=None):
    """The scene's Nephele settings as a dict (defaults for anything unset)."""
    scene = scene or bpy.context.scene
    out = dict(DEFAULTS)
    raw = scene.get(MIRROR_KEY)
    if raw:
        try:
            out.update({k: v for k, v in json.loads(raw).items() if k in DEFAULTS})
        except (TypeError, ValueError):
            pass
    return out


def set_settings(scene=None, **values):
    """Change settings (written to the mirror, which ``scene.nephele_data`` reads too)."""
    scene = scene or bpy.context.scene
    unknown = set(values) - set(DEFAULTS)
    if unknown:
        raise KeyError(f"unknown Nephele settings {sorted(unknown)} (known: {sorted(DEFAULTS)})")
    cfg = settings(scene)
    cfg.update(values)
    cfg["source"] = str(cfg["source"])
    cfg["hours_per_frame"] = float(cfg["hours_per_frame"])
    cfg["frame_start"] = int(cfg["frame_start"])
    cfg["exaggeration"] = float(cfg["exaggeration"])
    cfg["radius"] = float(cfg["radius"])
    scene[MIRROR_KEY] = json.dumps(cfg, sort_keys=True)
    return cfg


def dataset(source=None, scene=None):
    """The dataset ``source`` (default: the scene's), opened once per process."""
    from ..core.pipeline.sources import open_source

    if source is None:
        source = settings(scene)["source"]
    return open_source(source)


def _mirrored(key):
    """Getter and setter that keep a panel property in the mirror: one source of truth,
    also for files saved without the add-on."""

    def get(self):
        return settings(self.id_data)[key]

    def set(self, value):
        set_settings(self.id_data, **{key: value})

    return {"get": get, "set": set}


class NephelePropsData(bpy.types.PropertyGroup):
    source: bpy.props.StringProperty(
        name="Source", **_mirrored("source"),
        description='"demo", "demo:small", or the path of a NetCDF (.nc) or GrADS (.ctl) file',
    )
    hours_per_frame: bpy.props.FloatProperty(
        name="Hours per frame", min=1e-3, **_mirrored("hours_per_frame"),
        description="Model hours advanced by one frame",
    )
    frame_start: bpy.props.IntProperty(
        name="First frame", **_mirrored("frame_start"),
        description="The frame showing the first time step",
    )
    exaggeration: bpy.props.FloatProperty(
        name="Vertical exaggeration", min=0.0, **_mirrored("exaggeration"),
        description="Heights are drawn this many times taller (globe and every layer)",
    )
    radius: bpy.props.FloatProperty(
        name="Globe radius", min=1e-3, **_mirrored("radius"),
        description="Radius of sea level in scene units",
    )


def frame_range_for(ds, cfg):
    """The frames ``(first, last)`` that cover the dataset's time axis."""
    last = cfg["frame_start"] + int(round(float(ds.hours[-1]) / cfg["hours_per_frame"]))
    return cfg["frame_start"], max(last, cfg["frame_start"])


class NEPHELE_OT_import_dataset(bpy.types.Operator):
    """Use a dataset: the built-in demo climate, a NetCDF file or a GrADS .ctl file"""

    bl_idname = "nephele.import_dataset"
    bl_label = "Import dataset"
    bl_options = {"REGISTER", "UNDO"}

    kind: bpy.props.EnumProperty(
        name="Data",
        items=[
            ("DEMO", "Demo climate", "The built-in synthetic climate (320×160×19, 10 days hourly)"),
            ("DEMO_SMALL", "Small demo", "A small, fast version of the demo"),
            ("FILE", "File", "A NetCDF (.nc) or GrADS (.ctl) file"),
        ],
        default="DEMO",
    )
    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH")
    filter_glob: bpy.props.StringProperty(default="*.nc;*.nc4;*.cdf;*.ctl", options={"HIDDEN"})
    hours_per_frame: bpy.props.FloatProperty(name="Hours per frame", default=1.0, min=1e-3)
    set_frame_range: bpy.props.BoolProperty(name="Set frame range", default=True)

    def invoke(self, context, event):
        if self.kind == "FILE" and not self.filepath:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        from ..core.errors import DataError

        source = {"DEMO": "demo", "DEMO_SMALL": "demo:small"}.get(self.kind, bpy.path.abspath(self.filepath))
        try:
            ds = dataset(source)
        except (DataError, OSError, ImportError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        cfg = set_settings(context.scene, source=source, hours_per_frame=self.hours_per_frame)
        if self.set_frame_range:
            context.scene.frame_start, context.scene.frame_end = frame_range_for(ds, cfg)
        nk, nj, ni = ds.grid.shape
        self.report({"INFO"}, f"{source}: {ni}×{nj}×{nk}, {ds.times.size} times, {', '.join(sorted(ds.variables))}")
        return {"FINISHED"}


class NEPHELE_PT_data(SubPanel, bpy.types.Panel):
    bl_label = "Dataset"
    bl_idname = "NEPHELE_PT_data"

    def draw(self, context):
        layout = self.layout
        row = layout.row(align=True)
        row.operator(NEPHELE_OT_import_dataset.bl_idname, text="Demo").kind = "DEMO"
        row.operator(NEPHELE_OT_import_dataset.bl_idname, text="File…").kind = "FILE"
        group = getattr(context.scene, "nephele_data", None)
        if group is None:
            return
        col = layout.column()
        col.prop(group, "source")
        col.prop(group, "hours_per_frame")
        col.prop(group, "frame_start")
        col.prop(group, "exaggeration")
        col.prop(group, "radius")


CLASSES = (NephelePropsData, NEPHELE_OT_import_dataset, NEPHELE_PT_data)
SCENE_PROPERTIES = {"nephele_data": NephelePropsData}
