"""Volume-rendered clouds (Fig. 2): a VDB sequence on disk, a volume object, a material.

"Add volume clouds" resamples every frame's model time into a sparse volume
(:func:`nephele.core.volume.sparse.resample`: opacity from the transfer function,
a second grid with the colour variable), writes one ``.vdb`` per frame
(:mod:`.vdb`) and makes a Volume object whose ``is_sequence`` maps frames to
files — Blender loads the sequence natively, so a farm render needs neither
the add-on nor the frame handler.  The material is Principled Volume with
density = the ``density`` grid × extinction and colour = the colour grid
through ``Map Range → Color Ramp`` (the colour map's control points), so the
colour map and extinction edit live; a changed transfer function (it is
baked into the grid) needs a re-bake, which the panel offers.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

import json
import math
from pathlib import Path

import numpy as np

import bpy
from mathutils import Matrix

from ..core.errors import DataError
from ..core.climate.grid import EARTH_RADIUS
from ..core.pipeline.cache import check_memory, format_bytes
from ..core.volume.sparse import ALTITUDE, DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE, EXACT, VOXELS
from ..core.volume.transfer import ALTITUDE_COLORS, TEMPERATURE_COLORS, ColorMap, TransferFunction
from ..core.volume.volume_atlas import DEFAULT_BELOW, DEFAULT_SUPPORT_SIZE, atlas_layout
from . import data_ops, frame, materials, tf_ramp
from .panel import SubPanel
from .mesh import select_only
from ..volume_files import bake_frame, bake_sequence, frame_path

KIND = "volume"
OBJECT_NAME = "Nephele Clouds"
PREFIX = "clouds"
COLOR_MAPS = {"altitude": ALTITUDE_COLORS, "temperature": TEMPERATURE_COLORS}
"""Default colour map per colour variable (others: grey over the field's range)."""


def default_color_map(color_var):
    return COLOR_MAPS.get(color_var, ColorMap(points=((0.0, (0.6, 0.6, 0.65)), (1.0, (1.0, 1.0, 1.0)))))


def volume_material(name, extinction, color_var, cmap, anisotropy=0.3, exact=None):
    """Principled Volume: density grid × ``extinction``, colour through ``cmap``.

    Parameters
    ----------
    name : str
    extinction : float
        Extinction per scene unit at opacity 1.
    color_var : str
        The colour grid's name (``""``: a constant colour, ``cmap``'s first).
    cmap : ColorMap
    exact : dict, optional
        The exact mode (:mod:`.volume_exact`): ``layout``
        (:meth:`~nephele.core.volume.volume_atlas.AtlasLayout.to_dict`), ``tf``
        (TransferFunction), ``below`` (metres), ``values`` and ``heights``
        (bpy images).  The density is then the transfer function of the
        field evaluated per sample, times ``extinction``.
    """
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    tree = mat.node_tree
    if tree is None:
        mat.use_nodes = True
        tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (500, 0)
    pv = tree.nodes.new("ShaderNodeVolumePrincipled")
    pv.name = pv.label = "Nephele volume"
    pv.location = (200, 0)
    # The density grid (the transfer function's opacity) times the extinction.
    pv.inputs["Density"].default_value = float(extinction)
    pv.inputs["Density Attribute"].default_value = "density"
    pv.inputs["Color Attribute"].default_value = ""
    pv.inputs["Anisotropy"].default_value = float(anisotropy)
    color_source = color_var
    if exact is not None:
        from .volume_exact import field_nodes, tf_nodes

        value, color, ok = field_nodes(tree, exact["layout"], exact["values"], exact["heights"],
                                       below=exact["below"], color_altitude=color_var == ALTITUDE,
                                       index_image=exact.get("index"))
        opacity = tf_nodes(tree, value, exact["tf"])
        # Density socket = opacity × inside × extinction (a linked socket replaces the Density value).
        dens = tree.nodes.new("ShaderNodeMath")
        dens.name = dens.label = "Nephele density"
        dens.operation = "MULTIPLY"
        dens.location = (-100, 300)
        tree.links.new(opacity, dens.inputs[0])
        tree.links.new(ok, dens.inputs[1])
        scale = tree.nodes.new("ShaderNodeMath")
        scale.name = scale.label = "Nephele extinction"
        scale.operation = "MULTIPLY"
        scale.location = (50, 300)
        tree.links.new(dens.outputs[0], scale.inputs[0])
        scale.inputs[1].default_value = float(extinction)
        tree.links.new(scale.outputs[0], pv.inputs["Density"])
        pv.inputs["Density Attribute"].default_value = ""
        color_source = color if color_var else None
    if color_var:
        lo, hi = cmap.range
        ramp = materials.attribute_ramp_nodes(tree, color_source, lo, hi, [(p, c) for p, c in cmap.normalized()],
                                              location=(-500, 0))
        tree.links.new(ramp.outputs["Color"], pv.inputs["Color"])
    else:
        pv.inputs["Color"].default_value = tuple(cmap.colors[0]) + (1.0,)
    tree.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    return mat


def _obj_params(obj):
    p = frame.params(obj)
    return p if p.get("kind") == KIND else None


def refresh_material(obj):
    """Rebuild ``obj``'s material from its stored parameters."""
    p = _obj_params(obj)
    if p is None:
        return None
    cmap = ColorMap.from_dict(p["cmap"])
    exact = None
    if p.get("mode") == EXACT:
        exact = {"layout": p["layout"], "tf": TransferFunction.from_dict(p["tf"]), "below": p["below"],
                 "values": _atlas_image(obj.name, p), "heights": _fixed_image(obj.name, p, "heights"),
                 "index": _fixed_image(obj.name, p, "index") if p["layout"].get("index") else None}
    mat = volume_material(f"{obj.name} material", p["extinction"], p.get("color_var", ""), cmap, exact=exact)
    if exact is not None:
        _sequence_users(mat, p)
    if not obj.data.materials:
        obj.data.materials.append(mat)
    else:
        obj.data.materials[0] = mat
    return mat


def _blend_path(path):
    return bpy.path.relpath(str(path)) if bpy.data.filepath else str(path)


def _image(name, path):
    img = bpy.data.images.get(name)
    if img is None:
        # A lazily baked sequence's files do not exist yet: no load().
        img = bpy.data.images.new(name, 1, 1, alpha=True, float_buffer=True)
    img.source = "FILE"
    img.filepath = _blend_path(path)
    # Raw data in every channel: no colour management, no alpha association.
    img.colorspace_settings.name = "Non-Color"
    img.alpha_mode = "CHANNEL_PACKED"
    return img


def _fixed_image(name, p, what):
    """A time-independent atlas image: the ``heights``, or a curvilinear grid's column ``index`` map."""
    img = _image(f"{name} {what}", data_ops.layer_dir(p) / f"{PREFIX}_{what}.exr")
    img.reload()
    return img


def _atlas_image(name, p):
    """The values atlas sequence; the Image Texture nodes' image users map frames to files."""
    img = _image(f"{name} values", frame_path(data_ops.layer_dir(p), PREFIX, 1).with_suffix(".exr"))
    img.source = "SEQUENCE"
    img.reload()
    return img


def _sequence_users(mat, p):
    """Point the values atlas nodes at frame ``f0`` → file 1, as the volume sequence does."""
    f0, f1 = p["frames"]
    for node in mat.node_tree.nodes:
        if node.type == "TEX_IMAGE" and node.image is not None and node.image.source == "SEQUENCE":
            iu = node.image_user
            iu.frame_start, iu.frame_duration, iu.frame_offset = int(f0), int(f1) - int(f0) + 1, 0
            iu.use_auto_refresh = True
            iu.use_cyclic = False


def volume_dir(name, directory=None):
    """Where a volume's sequence goes: ``directory``, else beside the .blend
    (``<blend>_nephele_cache/volumes/<name>``), else this session's own folder
    (:func:`.data_ops.cache_dir`; saving the file moves it beside the .blend)."""
    if directory:
        return Path(bpy.path.abspath(directory))
    return data_ops.owned_dir("volumes", name)


BYTES_PER_VOXEL = {EXACT: 60.0, VOXELS: 20.0}
"""Peak bytes per support voxel (exact) or per voxel of the cloudy blocks (voxels)
while one frame is resampled: measured with tracemalloc on demo:small (exact,
support 0.01: 1.04 M voxels, 61 MB; exaggeration 150: 3.0 M, 164 MB; voxels
0.0027: 14.4 M block voxels, 284 MB)."""
DISK_PER_VOXEL = {EXACT: 0.85, VOXELS: 4.0}
"""Bytes on disk per voxel (exact: 856 kB for 1.04 M support voxels; voxels:
two half-float grids)."""
SECONDS_PER_VOXEL = {EXACT: 1.7e-6, VOXELS: 0.85e-6}
"""Resampling time per voxel on this project's 2-core test machine (1.7 s and
12 s for the cases above); a bake then measures its own rate."""


def bake_estimate(ds, var, tf, *, hours=0.0, mode=EXACT, size=None, exaggeration=30.0, radius=1.0, below=0.0):
    """Memory, disk and time of one frame's resample, before any of it is allocated.

    The voxels lie in the shell between the lowest and highest grid heights
    (exaggerated); the share of it that can hold cloud is taken as three
    times the share of grid cells whose corners reach the transfer
    function's non-zero range (plus 5 %), which covers the padding the
    resampler adds around them (demo:small: 25 % of cells, 80 % of the shell
    holds support voxels).

    Returns a dict: ``voxels``, ``memory`` (peak bytes), ``disk`` (bytes per
    frame), ``seconds`` (per frame), ``shell_voxels``.
    """
    size = float(size if size is not None else (DEFAULT_SUPPORT_SIZE if mode == EXACT else DEFAULT_VOXEL_SIZE))
    support = tf.support()
    hs = radius * exaggeration / EARTH_RADIUS
    heights = np.asarray(ds.grid.height, dtype=np.float64)
    r_out = radius + max(float(np.nanmax(heights)), 0.0) * hs
    r_in = max(radius + min(float(np.nanmin(heights)) - below, 0.0) * hs, 0.0)
    shell = 4.0 / 3.0 * math.pi * (r_out ** 3 - r_in ** 3) / size ** 3
    if support is None:
        share = 0.0
    else:
        v = np.asarray(ds.read_at(var, hours))
        hit = (v >= support[0]) & (v <= support[1])
        # A cell can hold cloud when any of its 8 corners can (longitude periodic).
        cell = hit[:-1] | hit[1:]
        cell = cell[:, :-1] | cell[:, 1:]
        cell = cell | np.roll(cell, -1, axis=2)
        share = min(1.0, 3.0 * float(np.mean(cell)) + 0.05)
    voxels = shell * share
    atlas = float(np.asarray(ds.grid.height).size) * 4.0 * 4
    return {"voxels": voxels, "shell_voxels": shell, "memory": voxels * BYTES_PER_VOXEL[mode] + atlas,
            "disk": voxels * DISK_PER_VOXEL[mode] + atlas / 8.0, "seconds": voxels * SECONDS_PER_VOXEL[mode]}


def check_bake(ds, var, tf, *, hours, mode, size, exaggeration, radius, below=0.0, available=None):
    """:func:`bake_estimate`, refused with a :class:`DataError` naming what to change when
    one frame would need more memory than the machine has."""
    est = bake_estimate(ds, var, tf, hours=hours, mode=mode, size=size, exaggeration=exaggeration,
                        radius=radius, below=below)
    knob = "support voxel" if mode == EXACT else "voxel size"
    check_memory(est["memory"], f"resampling one frame of '{var}' at vertical exaggeration {exaggeration:g} "
                                f"and {knob} {size:g} (lower the exaggeration or raise the {knob})",
                 available=available)
    return est


def volume_look(scene):
    """Render settings volume clouds need to look like Fig. 2 (bright, lit by each other):
    at least 4 Cycles volume bounces (Blender's default 0 leaves only single
    scattering: flat dark-grey slabs), and the total bounces to allow them.
    Returns ``[(setting, old, new)]`` for what was raised."""
    c = scene.cycles
    changed = []
    for attr, need in (("volume_bounces", 4), ("max_bounces", 8), ("transparent_max_bounces", 8)):
        old = getattr(c, attr)
        if old < need:
            setattr(c, attr, need)
            changed.append((attr, old, need))
    return changed


def look_warnings(scene, obj=None):
    """Why the volume will not look right in ``scene`` (a list of short lines)."""
    out = []
    eng = scene.render.engine
    if eng == "CYCLES" and scene.cycles.volume_bounces < 1:
        out.append("Cycles volume bounces 0: clouds render as flat dark slabs")
    p = _obj_params(obj) if obj is not None else None
    if eng != "CYCLES" and p is not None and p.get("mode") == EXACT:
        out.append("Exact mode renders striped outside Cycles: use Cycles or the Voxels mode")
    for o in scene.objects:
        q = frame.params(o)
        if q.get("kind") in ("contour", "advected_contour") and not o.hide_render and not o.hide_get():
            out.append(f"Contour '{o.name}' (level {q.get('level', float('nan')):g} of '{q.get('var', '?')}') "
                       "is opaque and hides the clouds inside it: hide it to see them")
    return out


def add_volume_clouds(var="cloud", tf=None, *, source=None, color_var=ALTITUDE, cmap=None,
                      voxel_size=DEFAULT_VOXEL_SIZE, extinction=DEFAULT_EXTINCTION, frames=None,
                      directory=None, exaggeration=None, radius=None, scene=None, collection=None,
                      name=OBJECT_NAME, progress=None, bake="all", cache=None, mode=EXACT,
                      support_size=DEFAULT_SUPPORT_SIZE, below=DEFAULT_BELOW):
    """Bake a VDB sequence and add (or update) a volume object showing it.

    Parameters
    ----------
    var : str
        Field behind the opacity.
    tf : TransferFunction, optional
        Default: zero up to 0.3, rising to 1 at 1.
    source : str, optional
        Dataset; default: the scene's.
    color_var : str
        ``"altitude"``, another field, or ``""`` for one colour.
    cmap : ColorMap, optional
        Default: :data:`COLOR_MAPS` for the colour variable.
    voxel_size, extinction : float
        Scene units between voxels; extinction per scene unit at opacity 1.
    frames : (first, last), optional
        Default: the scene's frame range within the data's time span.
    directory : str, optional
        Default: :func:`volume_dir`.
    exaggeration, radius : float, optional
        Default: the scene's (the globe's).
    bake : {"all", "lazy"}
        ``"all"`` writes every frame's file now; ``"lazy"`` writes none: the
        frame handler writes each frame's file when the frame is shown (a
        farm render after ``nephele precompute`` filled the cache on Dask
        workers then only converts cached arrays into .vdb files).
    cache : str or Cache, optional
        Resampled volumes to use instead of resampling (default: the
        scene's cache, :func:`.frame.results_dir`).
    mode : {"exact", "voxels"}
        ``"exact"`` (default): the material evaluates the curvilinear field
        at every sample from atlas images (:mod:`.volume_exact`), the
        ``.vdb`` files hold only the support grid (voxel ``support_size``;
        ``below`` metres under the lowest level take its values).
        ``"voxels"``: the opacity resampled into voxels of ``voxel_size``.

    Returns
    -------
    (bpy.types.Object, list of dict)
        The object and the per-frame bake summaries (see
        :func:`~nephele.volume_files.bake_sequence`).
    """
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    source = cfg["source"] if source is None else str(source)
    tf = tf or TransferFunction.ramp(0.3, 1.0)
    cmap = cmap or default_color_map(color_var)
    ds = data_ops.dataset(source)
    # The file's own names ('T') are accepted as well as Nephele's ('temperature'), as for contours.
    if var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", path=source, field=var)
    var = ds.resolve(var)
    if color_var and color_var != ALTITUDE:
        if color_var not in ds:
            raise DataError(f"no such colour variable (available: altitude, {', '.join(sorted(ds.variables))})",
                            path=source, field=color_var)
        color_var = ds.resolve(color_var)
    if frames is None:
        d0, d1 = data_ops.frame_range_for(ds, cfg)
        f0, f1 = max(scene.frame_start, d0), min(scene.frame_end, d1)
        if f1 < f0:
            f0, f1 = d0, d0
    else:
        f0, f1 = int(frames[0]), int(frames[1])
        if f1 < f0:
            raise DataError(f"last frame {f1} is before the first {f0}", field="frames")
    params = {
        "kind": KIND,
        "source": source,
        "var": var,
        "tf": tf.to_dict(),
        "cmap": cmap.to_dict(),
        "color_var": color_var or "",
        "voxel_size": float(voxel_size),
        "extinction": float(extinction),
        "exaggeration": cfg["exaggeration"] if exaggeration is None else data_ops.check_setting("exaggeration", exaggeration),
        "radius": cfg["radius"] if radius is None else data_ops.check_setting("radius", radius),
        "frame_start": cfg["frame_start"],
        "hours_per_frame": cfg["hours_per_frame"],
        "frames": [f0, f1],
        "mode": mode,
        "baked_tf": tf.to_dict(),
    }
    if mode == EXACT:
        params.update(support_size=float(support_size), below=float(below))
    elif mode != VOXELS:
        raise DataError(f'must be "{EXACT}" or "{VOXELS}", got {mode!r}', field="mode")
    if bake not in ("all", "lazy"):
        raise DataError(f'must be "all" or "lazy", got {bake!r}', field="bake")
    # Memory checked on the first frame before anything is allocated or written.
    from ..core.pipeline.sources import frame_hours

    hours0 = frame_hours(f0, params["frame_start"], params["hours_per_frame"], last_hour=float(ds.hours[-1]))
    est = check_bake(ds, var, tf, hours=hours0, mode=mode,
                     size=support_size if mode == EXACT else voxel_size,
                     exaggeration=params["exaggeration"], radius=params["radius"],
                     below=below if mode == EXACT else 0.0)
    out_dir = volume_dir(name, directory)
    # Content-addressed entries (the farm's precompute): safe to share, named by their keys.
    cache = frame.results_dir() if cache is None else cache
    if mode == EXACT:
        from ..volume_files import write_exr

        layout = atlas_layout(ds.grid, params["radius"], params["exaggeration"])
        write_exr(out_dir / f"{PREFIX}_heights.exr", layout.heights)
        if layout.index is not None:
            write_exr(out_dir / f"{PREFIX}_index.exr", layout.index.image)
        params["layout"] = layout.to_dict()
    if bake == "all":
        infos = bake_sequence(params, range(f0, f1 + 1), out_dir, PREFIX, cache=cache, progress=progress)
    else:
        infos = []
        out_dir.mkdir(parents=True, exist_ok=True)
    # Drop files of an older, longer bake so the directory holds one sequence.
    for stale in (*out_dir.glob(f"{PREFIX}_*.vdb"), *out_dir.glob(f"{PREFIX}_[0-9]*.exr")):
        num = stale.stem.rsplit("_", 1)[-1]
        if num.isdigit() and int(num) > f1 - f0 + 1:
            stale.unlink()
    first = str(frame_path(out_dir, PREFIX, 1))
    vol = bpy.data.volumes.get(name) or bpy.data.volumes.new(name)
    vol.filepath = bpy.path.relpath(first) if bpy.data.filepath else first
    vol.is_sequence = f1 > f0
    vol.frame_start = f0
    vol.frame_duration = f1 - f0 + 1
    vol.frame_offset = 0
    vol.sequence_mode = "EXTEND"
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "VOLUME":
        obj = bpy.data.objects.new(name, vol)
    elif obj.data is not vol:
        obj.data = vol
    coll = collection or scene.collection
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    # The exact mode shades a rotated-pole grid in its own frame: the object turns it into place.
    rotation = ds.grid.rotation if mode == EXACT else None
    obj.matrix_world = Matrix.Identity(4) if rotation is None else Matrix(rotation.tolist()).to_4x4()
    params["directory"] = data_ops.stored_dir(out_dir)
    params["owned"] = not directory  # a folder Nephele chose: saving moves it beside the .blend
    params["estimate"] = {k: float(v) for k, v in est.items()}
    params["value_max"] = max((i["value_max"] for i in infos), default=float("nan"))
    params["empty"] = bool(infos) and all(i["active_voxels"] == 0 for i in infos)
    params["lazy"] = bake == "lazy"
    if params["empty"]:
        params["value_range"] = list(data_range(ds, var, params, f0, f1))
    frame.set_params(obj, params)
    refresh_material(obj)
    return obj, infos


@frame.register_updater(KIND)
def _write_frame(obj, params, scene, frame_number):
    """A lazily baked volume: write the shown frame's file if it is missing
    or stale (from the scene's cache when precomputed), before Blender reads it."""
    if not params.get("lazy"):
        return
    f0, f1 = params["frames"]
    f = min(max(int(round(frame_number)), int(f0)), int(f1))
    bake_frame(params, f, f - int(f0) + 1, data_ops.layer_dir(params), PREFIX,
               cache=frame.results_dir())


def data_range(ds, var, params, f0, f1, samples=24):
    """``(lowest, highest)`` finite value of ``var`` over frames ``f0..f1`` (up to ``samples`` of them)."""
    from ..core.pipeline.sources import frame_hours

    lo, hi = math.inf, -math.inf
    for f in sorted({int(round(x)) for x in np.linspace(f0, f1, min(samples, f1 - f0 + 1))}):
        h = frame_hours(f, params["frame_start"], params["hours_per_frame"], last_hour=float(ds.hours[-1]))
        v = np.asarray(ds.read_at(var, h))
        v = v[np.isfinite(v)]
        if v.size:
            lo, hi = min(lo, float(v.min())), max(hi, float(v.max()))
    return (lo, hi) if lo <= hi else (math.nan, math.nan)


def eevee_volume_settings(scene, tile_size="2", samples=64):
    """EEVEE renders volumes in screen-space froxels, 8 px wide by default:
    far too coarse for clouds a few voxels thick.  Finer tiles, shadows on."""
    ee = scene.eevee
    ee.volumetric_tile_size = str(tile_size)
    ee.volumetric_samples = int(samples)
    ee.use_volumetric_shadows = True
    return ee


def empty_message(params):
    """The warning for a bake with no cloud at all, or None."""
    if not params.get("empty"):
        return None
    tf = TransferFunction.from_dict(params["tf"])
    support = tf.support()
    lo = support[0] if support else float("nan")
    vmin, vmax = params.get("value_range", (float("nan"), params["value_max"]))
    return (f"Volume is empty: the opacity is zero for every value of '{params['var']}' "
            f"(threshold {lo:g}; the data range {vmin:g} to {vmax:g} over frames "
            f"{params['frames'][0]}-{params['frames'][1]}, largest value {params['value_max']:g}); "
            "lower the threshold and re-bake")


# ---------------------------------------------------------------- the panel


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


def _within(tf, baked):
    """The transfer function ``tf`` is non-zero only where the baked one's support is."""
    new, old = tf.support(), TransferFunction.from_dict(baked).support()
    return new is None or (old is not None and new[0] >= old[0] and new[1] <= old[1])


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
    var: bpy.props.StringProperty(name="Variable", default="cloud", description="Field behind the opacity")
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
