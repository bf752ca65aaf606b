"""Volume-rendered clouds (Fig. 2): a VDB sequence on disk, a volume object, a material.

"Add volume clouds" resamples every frame's model time into a sparse volume
(:func:`nephele.core.volume.sparse.resample`: opacity from the transfer function,
a second grid with the colour variable), writes one ``.vdb`` per frame
(:mod:`nephele.volume_files`) and makes a Volume object whose ``is_sequence`` maps frames to
files — Blender loads the sequence natively, so a farm render needs neither
the add-on nor the frame handler.  The material is Principled Volume with
density = the ``density`` grid × extinction and colour = the colour grid
through ``Map Range → Color Ramp`` (the colour map's control points), so the
colour map and extinction edit live; a changed transfer function (it is
baked into the grid) needs a re-bake, which the panel (:mod:`.volume_panel`) offers.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from ..core.climate.grid import EARTH_RADIUS
from ..core.errors import DataError
from ..core.memory import check_memory
from ..core.volume.sparse import ALTITUDE, DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE, EXACT, VOXELS
from ..core.volume.transfer import ALTITUDE_COLORS, TEMPERATURE_COLORS, ColorMap, TransferFunction
from ..core.volume.volume_atlas import DEFAULT_BELOW, DEFAULT_SUPPORT_SIZE, atlas_layout
from ..volume_files import bake_frame, bake_sequence, frame_path
from . import data_ops, frame, materials

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
    var, color_var = _resolve_fields(ds, source, var, color_var)
    f0, f1 = _bake_range(scene, cfg, ds, frames)
    params = _bake_params(cfg, source, var, tf, cmap, color_var, voxel_size, extinction, exaggeration, radius,
                          (f0, f1), mode, support_size, below)
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
    infos = _write_sequence(params, ds, out_dir, bake, cache, progress)
    # The exact mode shades a rotated-pole grid in its own frame: the object turns it into place.
    obj = _volume_object(name, out_dir, f0, f1, collection or scene.collection,
                         ds.grid.rotation if mode == EXACT else None)
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


def _resolve_fields(ds, source, var, color_var):
    """The dataset's names of the opacity and colour fields; the file's own names ('T') are
    accepted as well as Nephele's ('temperature'), as for contours."""
    if var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", path=source, field=var)
    if color_var and color_var != ALTITUDE:
        if color_var not in ds:
            raise DataError(f"no such colour variable (available: altitude, {', '.join(sorted(ds.variables))})",
                            path=source, field=color_var)
        color_var = ds.resolve(color_var)
    return ds.resolve(var), color_var


def _bake_params(cfg, source, var, tf, cmap, color_var, voxel_size, extinction, exaggeration, radius, frames, mode,
                 support_size, below):
    """The volume layer's parameters (:func:`nephele.core.volume.volume_task.frame_params` reads them)."""
    params = {
        "kind": KIND,
        "source": source,
        "var": var,
        "tf": tf.to_dict(),
        "cmap": cmap.to_dict(),
        "color_var": color_var or "",
        "voxel_size": float(voxel_size),
        "extinction": float(extinction),
        "exaggeration": cfg["exaggeration"]
        if exaggeration is None
        else data_ops.check_setting("exaggeration", exaggeration),
        "radius": cfg["radius"] if radius is None else data_ops.check_setting("radius", radius),
        "frame_start": cfg["frame_start"],
        "hours_per_frame": cfg["hours_per_frame"],
        "frames": list(frames),
        "mode": mode,
        "baked_tf": tf.to_dict(),
    }
    if mode == EXACT:
        params.update(support_size=float(support_size), below=float(below))
    elif mode != VOXELS:
        raise DataError(f'must be "{EXACT}" or "{VOXELS}", got {mode!r}', field="mode")
    return params


def _bake_range(scene, cfg, ds, frames):
    """``(first, last)`` frames to bake: ``frames``, else the scene's range within the data's time span."""
    if frames is None:
        d0, d1 = data_ops.frame_range_for(ds, cfg)
        f0, f1 = max(scene.frame_start, d0), min(scene.frame_end, d1)
        return (d0, d0) if f1 < f0 else (f0, f1)
    f0, f1 = int(frames[0]), int(frames[1])
    if f1 < f0:
        raise DataError(f"last frame {f1} is before the first {f0}", field="frames")
    return f0, f1


def _write_sequence(params, ds, out_dir, bake, cache, progress):
    """The sequence's files in ``out_dir`` (the exact mode's heights atlas, then every frame, or none
    with ``bake="lazy"``); files of an older, longer bake are dropped.  Returns the bake summaries;
    sets ``params["layout"]`` in the exact mode."""
    f0, f1 = params["frames"]
    if params["mode"] == EXACT:
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
    for old in (*out_dir.glob(f"{PREFIX}_*.vdb"), *out_dir.glob(f"{PREFIX}_[0-9]*.exr")):
        num = old.stem.rsplit("_", 1)[-1]
        if num.isdigit() and int(num) > f1 - f0 + 1:
            old.unlink()
    return infos


def _volume_object(name, out_dir, f0, f1, collection, rotation):
    """The volume object ``name`` (made, or reused) showing the sequence in ``out_dir`` from frame ``f0``,
    linked to ``collection`` and turned by ``rotation`` (3x3, or None)."""
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
    if obj.name not in collection.objects:
        collection.objects.link(obj)
    obj.matrix_world = Matrix.Identity(4) if rotation is None else Matrix(rotation.tolist()).to_4x4()
    return obj


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


def _within(tf, baked):
    """The transfer function ``tf`` is non-zero only where the baked one's support is."""
    new, old = tf.support(), TransferFunction.from_dict(baked).support()
    return new is None or (old is not None and new[0] >= old[0] and new[1] <= old[1])
