"""Which dataset a scene shows, and how frames map to model time.

The settings live in a JSON ID property ``scene["nephele_settings"]``, so a
saved .blend opened without the add-on (the farm) still knows them; the
PropertyGroup ``scene.nephele_data`` that the panel shows reads and writes
that same property.  Every layer
reads the radius and vertical exaggeration from here, so the globe, contours,
volumes and textures line up.
"""

import json
import os
import shutil
import sys
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

from ..core.climate.grid import DEFAULT_EXAGGERATION
from ..core.climate.readers import VERTICAL_CHOICES, check_overrides
from ..core.errors import DataError
from ..core.memory import format_bytes
from ..core.pipeline.cache import default_cache_dir, session_cache_dir, tree_size
from ..core.pipeline.sources import open_with_overrides
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

BOUNDS = {
    "hours_per_frame": (1e-3, 8760.0),
    "frame_start": (-1048574, 1048574),
    "exaggeration": (0.0, 500.0),
    "radius": (1e-3, 1e3),
}
"""Allowed ``(lowest, highest)`` of each numeric setting.  Exaggeration 500
already lifts a 20 km atmosphere 1.6 globe radii; beyond it every layer's
memory grows without showing more (the issue's 1e6 took 24 GB and was killed).
Frames: Blender's own limits."""


def check_setting(key, value):
    """``value`` as the setting's type, or :class:`DataError` naming the setting and its bounds."""
    if key == "source":
        return str(value)
    kind = int if key == "frame_start" else float
    try:
        v = kind(value)
    except (TypeError, ValueError):
        raise DataError(f"must be a number, got {value!r}", field=key) from None
    lo, hi = BOUNDS[key]
    if not lo <= v <= hi:  # also refuses NaN
        raise DataError(f"must be between {lo:g} and {hi:g}, got {v:g}", field=key)
    return v


PROBLEMS = {}
"""One line per thing a panel shows where its value is edited: ``("dataset", source)`` a dataset that does
not open, ``"settings"`` scene settings that could not be read, ``("tf", object name)`` a refused
transfer-function edit, ``"save"`` a layer's files that could not be copied beside the saved .blend (full
disk).  Each is also printed once on the console."""


def note_problem(key, problem):
    """Remember ``problem`` (an exception or text; None clears it) for the panel showing ``key``."""
    if problem is None:
        PROBLEMS.pop(key, None)
        return
    text = (str(problem).strip().splitlines() or [type(problem).__name__])[0]
    if PROBLEMS.get(key) != text:
        print(f"Nephele: {text}", file=sys.stderr)
    PROBLEMS[key] = text


def draw_problem(layout, key):
    """An error line in ``layout`` when ``key`` has a problem; True if it had."""
    text = PROBLEMS.get(key)
    if text:
        layout.label(text=text, icon="ERROR")
    return bool(text)


def dataset_names(scene=None):
    """The scene's dataset's variable names, or ``()`` when it does not open (the reason goes to the panels)."""
    source = settings(scene)["source"]
    try:
        names = tuple(sorted(dataset(source).variables))
    except Exception as exc:  # noqa: BLE001 - any failure to open is shown, not raised, in a panel's menu
        note_problem(("dataset", source), exc)
        return ()
    note_problem(("dataset", source), None)
    return names


def settings(scene=None):
    """The scene's Nephele settings as a dict (defaults for anything unset).

    Settings that cannot be read (damaged text, a value out of bounds) are
    reported (the Dataset panel, the console) and read as their defaults; the
    stored text is kept in ``scene["nephele_settings_bad"]`` when a setting
    is next changed.
    """
    scene = scene or bpy.context.scene
    out = dict(DEFAULTS)
    raw = scene.get(MIRROR_KEY)
    bad = []
    if raw:
        try:
            stored = json.loads(raw)
            if not isinstance(stored, dict):
                raise ValueError(f"expected a JSON object, got {type(stored).__name__}")
        except (TypeError, ValueError) as exc:
            note_problem("settings", f"scene settings ({MIRROR_KEY}) cannot be read ({exc}); the defaults are used "
                                     "until a setting is changed (the old text is then kept as nephele_settings_bad)")
            return out
        for k, v in stored.items():
            if k not in DEFAULTS:
                continue
            try:
                out[k] = check_setting(k, v)
            except DataError as exc:
                bad.append(f"{k} {exc.problem}")
    note_problem("settings", f"scene settings out of range, defaults used: {'; '.join(bad)}" if bad else None)
    return out


def set_settings(scene=None, **values):
    """Change settings (written to the mirror, which ``scene.nephele_data`` reads too)."""
    scene = scene or bpy.context.scene
    unknown = set(values) - set(DEFAULTS)
    if unknown:
        raise KeyError(f"unknown Nephele settings {sorted(unknown)} (known: {sorted(DEFAULTS)})")
    cfg = settings(scene)
    # Checked before anything is stored: a bad value never reaches the layers.
    cfg.update({k: check_setting(k, v) for k, v in values.items()})
    if PROBLEMS.get("settings") and scene.get(MIRROR_KEY):  # what is about to be reset stays readable
        scene["nephele_settings_bad"] = str(scene[MIRROR_KEY])
        note_problem("settings", None)
    scene[MIRROR_KEY] = json.dumps(cfg, sort_keys=True)
    return cfg


def dataset(source=None, scene=None):
    """The dataset ``source`` (default: the scene's), opened once per process."""
    from ..core.pipeline.sources import open_source

    if source is None:
        source = settings(scene)["source"]
    return open_source(source)


def variable_search(self, context, edit_text):
    """Field names for a panel's "Variable" box: the scene dataset's fields (cloud_water, cloud_ice, cloud, rh,
    u, v, w... as the reader names them) with what they are; any of their other names (the file's own, a GRIB
    shortName such as clwmr, a CF standard name) is also accepted when typed."""
    try:
        ds = dataset(scene=context.scene)
    except Exception:  # noqa: BLE001 - no usable dataset: nothing to offer
        return []
    text = str(edit_text or "").lower()
    out = []
    for name, var in sorted(ds.variables.items()):
        raw = getattr(ds, "file_names", {}).get(name, name)
        about = var.long_name + (f" ('{raw}' in the file)" if raw != name else "")
        if text in name.lower() or text in raw.lower():
            out.append((name, about))
    return out


def _mirrored(key):
    """Getter and setter that keep a panel property in the mirror: one source of truth,
    also for files saved without the add-on."""

    def get(self):
        return settings(self.id_data)[key]

    def set(self, value):
        # A custom setter bypasses the property's min/max: clamp here, as
        # Blender does for hard limits (set_settings refuses instead).
        if key in BOUNDS:
            lo, hi = BOUNDS[key]
            value = min(max(value, lo), hi) if value == value else settings(self.id_data)[key]
        set_settings(self.id_data, **{key: value})

    return {"get": get, "set": set}


class NephelePropsData(bpy.types.PropertyGroup):
    source: bpy.props.StringProperty(
        name="Source", **_mirrored("source"),
        description='"demo", "demo:small", or the path of a NetCDF (.nc) or GrADS (.ctl) file',
    )
    hours_per_frame: bpy.props.FloatProperty(
        name="Hours per frame", min=1e-3, max=8760.0, **_mirrored("hours_per_frame"),
        description="Model hours advanced by one frame",
    )
    frame_start: bpy.props.IntProperty(
        name="First frame", min=-1048574, max=1048574, **_mirrored("frame_start"),
        description="The frame showing the first time step",
    )
    exaggeration: bpy.props.FloatProperty(
        name="Vertical exaggeration", min=0.0, max=500.0, **_mirrored("exaggeration"),
        description="Heights are drawn this many times taller (globe and every layer)",
    )
    radius: bpy.props.FloatProperty(
        name="Globe radius", min=1e-3, max=1e3, **_mirrored("radius"),
        description="Radius of sea level in scene units",
    )
    # File overrides: what the next "File…" import tells the reader (the CLI's reader options).
    # Their result is kept in the source name (path?key=value&...), so it survives saving.
    read_vertical: bpy.props.EnumProperty(
        name="Vertical coordinate",
        items=[("FILE", "From the file", "What the file's level coordinate says")]
        + [(k, k, f"The level coordinate is {k.replace('_', ' ')}") for k in VERTICAL_CHOICES],
        default="FILE",
        description="What the level coordinate is when the file does not say (--vertical-coord)",
    )
    read_p0: bpy.props.FloatProperty(
        name="P0 (Pa)", default=0.0, min=0.0, soft_max=200000.0,
        description="Reference pressure of hybrid levels in Pa; 0: the file's, else 100000 (--p0)",
    )
    read_time_units: bpy.props.StringProperty(
        name="Time units",
        description='CF time units replacing the file\'s, e.g. "days since 1988-01-01"; empty: the file\'s '
                    '(--time-units)',
    )
    read_earth_radius: bpy.props.FloatProperty(
        name="Earth radius (m)", default=0.0, min=0.0, soft_max=1e8,
        description="Planet radius in metres; 0: the file's grid mapping or model convention, else 6371000 "
                    "(--earth-radius)",
    )
    read_var_map: bpy.props.StringProperty(
        name="Variable map",
        description="Read the file's variable NAME as the standard field STD: STD=NAME, comma separated "
                    "(e.g. temperature=T2, rh=RH) (--var-map)",
    )
    read_level_type: bpy.props.StringProperty(
        name="GRIB level type",
        description="The kind of level to read from a GRIB file, e.g. isobaricInhPa or hybrid; empty: the one with "
                    "the most 3-D fields (--level-type)",
    )
    read_member: bpy.props.IntProperty(
        name="Ensemble member", default=-1, min=-1,
        description="The ensemble member to read; -1: the control (0) or the first (--member)",
    )


def overrides(group, path=None):
    """The reader overrides the panel's "File overrides" ask for, checked as the CLI checks its options
    (:func:`~nephele.core.climate.readers.check_overrides`; :class:`DataError` names the file and field)."""
    return check_overrides(
        path,
        vertical=None if group.read_vertical == "FILE" else group.read_vertical,
        p0=group.read_p0 or None,
        time_units=group.read_time_units,
        radius=group.read_earth_radius or None,
        variables=group.read_var_map,
        level_type=group.read_level_type or None,
        member=None if group.read_member < 0 else group.read_member,
    )


def frame_range_for(ds, cfg):
    """The frames ``(first, last)`` that cover the dataset's time axis."""
    last = cfg["frame_start"] + int(round(float(ds.hours[-1]) / cfg["hours_per_frame"]))
    return cfg["frame_start"], max(last, cfg["frame_start"])


# ------------------------------------------------------------ files of the scene


def cache_dir():
    """Where this file's Nephele files go: ``<blend dir>/<stem>_nephele_cache``
    beside a saved .blend, else a folder of this session alone
    (:func:`~nephele.core.pipeline.cache.session_cache_dir`) that saving moves beside the .blend."""
    if bpy.data.filepath:
        return default_cache_dir(bpy.data.filepath)
    return session_cache_dir()


def owned_dir(*parts):
    """A folder Nephele chooses for a layer's files: ``cache_dir() / parts``."""
    return cache_dir().joinpath(*(bpy.path.clean_name(str(p)) for p in parts))


def stored_dir(path):
    """How a layer records its folder: relative to a saved .blend (``//…``), else absolute."""
    path = str(path)
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(path)
        except ValueError:  # another drive
            return path
    return path


def layer_dir(params):
    """The absolute folder a layer's ``params["directory"]`` names."""
    return Path(bpy.path.abspath(params["directory"]))


def _owned_layers():
    from . import frame

    for obj in bpy.data.objects:
        p = frame.params(obj)
        if p.get("owned") and p.get("directory"):
            yield obj, p


def _inside(path, root):
    try:
        Path(path).resolve().relative_to(Path(root).resolve())
        return True
    except ValueError:
        return False


def _repoint(old, new):
    """Volumes and images whose files lie under ``old`` now read them under ``new`` (absolute paths;
    a save with relative paths on stores them relative)."""
    old = Path(old).resolve()
    for block in (*bpy.data.volumes, *bpy.data.images):
        fp = getattr(block, "filepath", "")
        if fp and (moved := rebased(Path(bpy.path.abspath(fp)).resolve(), old, Path(new))) is not None:
            block.filepath = str(moved)


def rebased(path, old, new):
    """``path`` moved from under folder ``old`` to ``new``, or None when it lies elsewhere.  Compared
    as the system does: a Windows path in another letter case is the same file."""
    try:
        return new / path.relative_to(old)
    except ValueError:
        return None


def _link_or_copy(src, dst):
    try:
        os.link(src, dst)  # same disk: no second copy of the frames
    except OSError:
        shutil.copy2(src, dst)


_PENDING = []
"""What the running save changed: ``(obj name, old params, old dir, new dir, from this session)``."""


def adopt_files(blend_path):
    """Give the file being saved as ``blend_path`` its own copy of every folder Nephele
    chose for a layer, in ``<blend dir>/<stem>_nephele_cache``, and point the layers there.

    Files are hard-linked where the disk allows (else copied), so nothing is
    written twice; :func:`finish_save` then removes this session's originals
    once the file is really the one being edited (a "save copy" instead
    gets the layers pointed back).  Another .blend's folder is left intact,
    since that file still uses it.  Returns the list of ``(old, new)`` folders.
    """
    from . import frame

    new_root = default_cache_dir(blend_path)
    old_root = default_cache_dir(bpy.data.filepath) if bpy.data.filepath else session_cache_dir(create=False)
    session = session_cache_dir(create=False)
    done = []
    for obj, p in list(_owned_layers()):
        old = layer_dir(p)
        if _inside(old, new_root):
            continue
        rel = Path(os.path.relpath(old.resolve(), old_root.resolve())) \
            if old_root is not None and _inside(old, old_root) else Path(old.name)
        new = new_root / rel
        if old.is_dir():
            try:
                new.parent.mkdir(parents=True, exist_ok=True)
                if new.exists():
                    shutil.rmtree(new)
                shutil.copytree(old, new, copy_function=_link_or_copy)
            except OSError as exc:  # a full or read-only disk: no half copy; the layer keeps its folder
                shutil.rmtree(new, ignore_errors=True)
                from ..core.files import write_error

                note_problem("save", f"{obj.name}: its files stay in {old}, not copied beside the .blend: "
                                     f"{write_error(exc, new) or exc}")
                continue
        _PENDING.append((obj.name, json.dumps(p), old, new, session is not None and _inside(old, session)))
        _repoint(old, new)
        # Stored relative to the file being written (bpy.data.filepath is still the old one).
        p["directory"] = "//" + os.path.relpath(new, Path(blend_path).parent)
        frame.set_params(obj, p)
        done.append((old, new))
    return done


def same_file_name(a, b, path=os.path):
    """Whether two paths name one file as the system compares names (Windows: in any letter case)."""
    return path.normcase(path.abspath(a)) == path.normcase(path.abspath(b))


def finish_save(filepath):
    """After the save: the session's originals go when ``filepath`` is now the edited
    file; after a "save copy" the layers point back where they were."""
    from . import frame

    copy = not same_file_name(bpy.data.filepath or "", filepath)
    for name, old_params, old, new, from_session in _PENDING:
        obj = bpy.data.objects.get(name)
        if copy:
            if obj is not None:
                frame.set_params(obj, json.loads(old_params))
            _repoint(new, old)
        elif from_session and old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
    _PENDING.clear()


@persistent
def _on_save_pre(filepath, *args):
    _PENDING.clear()
    if filepath:
        adopt_files(filepath)


@persistent
def _on_save_post(filepath, *args):
    if filepath:
        finish_save(filepath)


def in_use():
    """Folders and files the scene's layers still read (kept by :func:`clear_cache`)."""
    keep = {layer_dir(p).resolve() for _obj, p in _owned_layers()}
    for block in (*bpy.data.volumes, *bpy.data.images):
        fp = getattr(block, "filepath", "")
        if fp:
            keep.add(Path(bpy.path.abspath(fp)).resolve().parent)
    return keep


def clear_cache(root=None):
    """Delete everything in this file's cache folder that no layer reads.

    Returns ``(bytes freed, files removed, bytes kept)``.  Only this file's
    folder (:func:`cache_dir`) is touched, never another file's or session's.
    """
    root = Path(root) if root is not None else cache_dir()
    if not root.is_dir():
        return 0, 0, 0
    keep = in_use()
    freed = removed = 0

    def used(path):
        r = path.resolve()
        return any(r == k or _inside(k, r) or _inside(r, k) for k in keep)

    def sweep(folder):
        nonlocal freed, removed
        for entry in folder.iterdir():
            if not used(entry):
                size, count = tree_size(entry) if entry.is_dir() else (entry.lstat().st_size, 1)
                shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
                freed, removed = freed + size, removed + count
            elif entry.is_dir() and entry.resolve() not in keep:
                sweep(entry)  # a parent of something in use: look inside

    sweep(root)
    return freed, removed, tree_size(root)[0]


class NEPHELE_OT_clear_cache(bpy.types.Operator):
    """Delete this file's cached Nephele results that no layer uses (they are recomputed when needed)"""

    bl_idname = "nephele.clear_cache"
    bl_label = "Clear cache"
    bl_options = {"REGISTER"}

    def execute(self, context):
        root = cache_dir()
        try:
            freed, removed, kept = clear_cache(root)
        except OSError as exc:
            self.report({"ERROR"}, f"{root}: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Freed {format_bytes(freed)} ({removed} files) in {root}; "
                              f"{format_bytes(kept)} kept in use by the scene's layers")
        return {"FINISHED"}


_HANDLERS = (("save_pre", _on_save_pre), ("save_post", _on_save_post))


def install():
    """Add the save handlers once (idempotent); called by the add-on's ``register()``.
    Also removes ended sessions' empty or week-old folders."""
    from ..core.pipeline.cache import prune_sessions

    try:
        prune_sessions()
    except OSError:
        pass  # a read-only or missing cache folder: nothing to tidy
    for kind, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        if not any(getattr(h, "__name__", "") == fn.__name__ for h in handlers):
            handlers.append(fn)


def uninstall():
    for kind, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        for h in [h for h in handlers if getattr(h, "__name__", "") == fn.__name__]:
            handlers.remove(h)


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
    filter_glob: bpy.props.StringProperty(default="*.nc;*.nc4;*.cdf;*.zip;*.ctl;*.grib;*.grib1;*.grib2;*.grb;*.grb2",
                                          options={"HIDDEN"})
    hours_per_frame: bpy.props.FloatProperty(name="Hours per frame", default=1.0, min=1e-3, max=8760.0)
    set_frame_range: bpy.props.BoolProperty(name="Set frame range", default=True)

    def invoke(self, context, event):
        if self.kind == "FILE" and not self.filepath:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        source = {"DEMO": "demo", "DEMO_SMALL": "demo:small"}.get(self.kind, bpy.path.abspath(self.filepath))
        group = getattr(context.scene, "nephele_data", None)
        try:
            if self.kind == "FILE" and group is not None:  # the panel's "File overrides"
                ds, source = open_with_overrides(source, **overrides(group, source))
            else:
                ds = dataset(source)
        except (DataError, OSError, ImportError) as exc:
            self.report({"ERROR"}, str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__)
            return {"CANCELLED"}
        try:
            cfg = set_settings(context.scene, source=source, hours_per_frame=self.hours_per_frame)
        except DataError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
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
        draw_problem(col, "settings")
        draw_problem(col, "save")
        col.prop(group, "source")
        draw_problem(col, ("dataset", settings(context.scene)["source"]))
        col.prop(group, "hours_per_frame")
        col.prop(group, "frame_start")
        col.prop(group, "exaggeration")
        col.prop(group, "radius")
        header, body = layout.panel("NEPHELE_PT_data_overrides", default_closed=True)
        header.label(text="File overrides")
        if body is not None:  # used by the next "File…" import, as the CLI's reader options
            col = body.column()
            col.prop(group, "read_vertical")
            col.prop(group, "read_p0")
            col.prop(group, "read_time_units")
            col.prop(group, "read_earth_radius")
            col.prop(group, "read_var_map")
            col.prop(group, "read_level_type")
            col.prop(group, "read_member")
        row = layout.row()
        row.operator(NEPHELE_OT_clear_cache.bl_idname, icon="TRASH")
        where = "beside the .blend" if bpy.data.filepath else "this session's folder (moved beside the .blend on save)"
        layout.label(text=f"Files: {where}", icon="FILE_FOLDER")


CLASSES = (NephelePropsData, NEPHELE_OT_import_dataset, NEPHELE_OT_clear_cache, NEPHELE_PT_data)
SCENE_PROPERTIES = {"nephele_data": NephelePropsData}
