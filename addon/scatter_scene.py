"""The scattering cloud's pieces of a Blender scene (Fig. 6): cameras, the sun and the world
(:func:`bake_world`: Cycles renders the world alone as a panorama, for the solve's sky bins),
the emission and the path-traced materials (:func:`add_pathtraced_cloud` is the benchmark's
reference), where the cloud goes in the scene, and the ``"scatter"`` task of the panel's
settings.  :mod:`.scatter_jobs` runs the solves with them; :mod:`.scatter_ops` is the panel
and the operator.
"""

import math
from pathlib import Path

import bpy
import numpy as np

from ..core.light import scatter_task
from ..core.light.sky import luminance, panorama_radiance
from ..core.volume import cloud_density as cd
from ..fileio import dense_grids, write_vdb
from .camera import camera_object, look_at
from .render_device import use_device


def add_camera(cam, name="Scatter camera"):
    """A Blender camera matching :class:`nephele.core.splats.camera.Camera` ``cam`` (perspective)."""
    scene = bpy.context.scene
    obj = camera_object(scene, name, angle=math.radians(cam.fov))
    obj.location = tuple(cam.position)
    look_at(obj, tuple(cam.position + cam.basis()[0]))
    scene.render.resolution_x, scene.render.resolution_y = cam.width, cam.height
    scene.render.resolution_percentage = 100
    return obj


def add_sun(sun_dir, irradiance, name="Sun"):
    """A Sun light shining from ``sun_dir`` (toward the sun) with ``irradiance`` W/m^2, angle 0."""
    from mathutils import Vector

    data = bpy.data.lights.new(name, "SUN")
    data.energy = float(irradiance)
    data.angle = 0.0
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    obj.rotation_euler = Vector(sun_dir).to_track_quat("Z", "Y").to_euler()
    return obj


def black_world(scene=None):
    """A new black world, made ``scene``'s (default: the current scene's); returns it."""
    world = bpy.data.worlds.new("Scatter world")
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Color"].default_value = (0, 0, 0, 1)
        bg.inputs["Strength"].default_value = 0.0
    (scene or bpy.context.scene).world = world
    return world


def _volume_object(name, filepath, sequence=None, scene=None):
    vol = bpy.data.volumes.new(name)
    vol.filepath = str(filepath)
    if sequence is not None:
        start, count = sequence
        vol.is_sequence = True
        vol.frame_start = start
        vol.frame_duration = count
        vol.sequence_mode = "CLIP"
    obj = bpy.data.objects.new(name, vol)
    (scene or bpy.context.scene).collection.objects.link(obj)
    return obj


def emission_material(name="Scattering cloud"):
    """Volume Absorption (density grid) + Emission (emission grid): an emission-absorption medium."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    dens = nt.nodes.new("ShaderNodeAttribute")
    dens.attribute_name = "density"
    emis = nt.nodes.new("ShaderNodeAttribute")
    emis.attribute_name = "emission"
    absorb = nt.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0, 0, 0, 1)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (1, 1, 1, 1)
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(dens.outputs["Fac"], absorb.inputs["Density"])
    nt.links.new(emis.outputs["Fac"], em.inputs["Strength"])
    nt.links.new(absorb.outputs[0], add.inputs[0])
    nt.links.new(em.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Volume"])
    return mat


def scattering_material(albedo, g, name="Path-traced cloud"):
    """Principled Volume: colour = albedo, density from the grid (extinction), anisotropy g."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color"].default_value = (albedo, albedo, albedo, 1)
    pv.inputs["Density"].default_value = 1.0
    pv.inputs["Anisotropy"].default_value = g
    pv.inputs["Density Attribute"].default_value = "density"
    nt.links.new(pv.outputs[0], out.inputs["Volume"])
    return mat


def cycles_settings(scene, samples, *, denoise=False, threads=None, bounces=256, device="CPU"):
    """Cycles for volumes: many volume bounces, no clamping, box pixel filter, on ``device``
    (:data:`~nephele.addon.render_device.DEVICES`: the CPU, or every GPU of a backend)."""
    scene.render.engine = "CYCLES"
    c = scene.cycles
    use_device(scene, device)
    c.samples = int(samples)
    c.use_adaptive_sampling = False
    c.use_denoising = bool(denoise)
    if denoise:
        c.denoiser = "OPENIMAGEDENOISE"
    c.max_bounces = bounces
    c.volume_bounces = bounces
    c.transparent_max_bounces = bounces
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(threads)


def render_rgba(scene, path):
    """Render ``scene`` to an OpenEXR at ``path``; its float32 RGBA (height, width, 4), row 0 at the top."""
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True, scene=scene.name)
    img = bpy.data.images.load(str(path), check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1].copy()


def render_array(scene, path):
    """Render the scene to an OpenEXR at ``path`` and return its luminance-free red channel
    as float32 (height, width), row 0 at the top (all channels are equal for grey media)."""
    return render_rgba(scene, path)[..., 0].copy()


# Camera rotation that makes Cycles' equirectangular panorama (default ranges) look along +x at
# its centre with +z up: the convention of :func:`..core.light.sky.panorama_radiance`
# (checked against a render of the world's direction in tests/addon/test_scatter_world.py).
PANORAMA_ROTATION = (math.pi / 2, 0.0, -math.pi / 2)


def sky_texture_nodes(tree, _seen=None):
    """The Sky Texture nodes of a node tree and of the node groups inside it (each group once)."""
    seen = set() if _seen is None else _seen
    if tree is None or tree.as_pointer() in seen:
        return []
    seen.add(tree.as_pointer())
    found = []
    for node in tree.nodes:
        if node.bl_idname == "ShaderNodeTexSky":
            found.append(node)
        elif getattr(node, "node_tree", None) is not None:
            found += sky_texture_nodes(node.node_tree, seen)
    return found


def bake_world(world, center=(0.0, 0.0, 0.0), *, size=(256, 128), samples=64, sun_disc=False, threads=None,
               bins_per_face=4):
    """The light of ``world`` per direction bin: (6 n^2,) radiances for the solve's ``sky_radiance``
    (``n = bins_per_face``, the solve's; 4: 96 bins).

    Cycles renders the world alone (a temporary scene sharing ``world``, no objects) through an
    equirectangular panoramic camera at ``center`` (world coordinates; a world's light does not
    depend on it, but a later world might), ``size`` pixels, ``samples`` per pixel (box filter:
    each pixel is the mean over its footprint; Sky Texture, no disc, against 256 samples: 64
    within 0.5% in every bin, 16 within 2% in the darkest ground bins; 3.5 s on 2 cores),
    then :func:`..core.light.sky.panorama_radiance` averages its :func:`luminance` over the
    bins with exact solid angles.  The temporary scene, camera and
    image go again.  A world held out of camera rays (ray visibility) is shown to the bake's
    camera all the same: it still lights the cloud.

    ``sun_disc``: keep the sun discs of the world's Sky Texture nodes (node groups' too).  Off by default: the
    cloud's sun is a separate parallel beam (the sun lamp or the panel's sun, exact and sharp),
    so a baked disc would light the cloud twice; the discs are switched off for the bake only.
    Leave it on only when nothing else is the sun (the disc is then blurred over its bin).
    """
    import tempfile

    if world is None:
        raise ValueError("the scene has no world to bake: add one (World properties) or pick another sky")
    tmp = bpy.data.scenes.new("Nephele sky bake")
    cam_data = bpy.data.cameras.new("Nephele sky bake")
    cam_data.type = "PANO"
    cam_data.panorama_type = "EQUIRECTANGULAR"
    cam = bpy.data.objects.new("Nephele sky bake", cam_data)
    discs = sky_texture_nodes(world.node_tree)
    was = [n.sun_disc for n in discs]
    seen = world.cycles_visibility.camera  # a world held out of camera rays still lights the cloud
    try:
        if not seen:
            world.cycles_visibility.camera = True
        tmp.world = world
        tmp.collection.objects.link(cam)
        tmp.camera = cam
        cam.location = tuple(center)
        cam.rotation_euler = PANORAMA_ROTATION
        cycles_settings(tmp, samples, threads=threads, bounces=0)
        tmp.render.film_transparent = False
        tmp.render.resolution_x, tmp.render.resolution_y = (int(v) for v in size)
        tmp.render.resolution_percentage = 100
        for n in discs:
            n.sun_disc = bool(sun_disc) and n.sun_disc
        with tempfile.TemporaryDirectory(prefix="nephele_sky_") as d:
            pano = render_rgba(tmp, Path(d) / "sky.exr")
    finally:
        if not seen:
            world.cycles_visibility.camera = False
        for n, w in zip(discs, was):
            n.sun_disc = w
        bpy.data.objects.remove(cam)
        bpy.data.cameras.remove(cam_data)
        bpy.data.scenes.remove(tmp)
    return panorama_radiance(np.maximum(luminance(pano), 0.0), bins_per_face=bins_per_face)


def add_sky_world(sun_elevation=38.0, sun_azimuth=-30.0, *, strength=0.08, sky_type="MULTIPLE_SCATTERING",
                  sun_disc=True, name="Sky"):
    """A world of Blender's Sky Texture (Nishita's model is ``"MULTIPLE_SCATTERING"`` or
    ``"SINGLE_SCATTERING"`` since Blender 5; also ``"PREETHAM"``, ``"HOSEK_WILKIE"``) with its
    sun at ``sun_elevation`` and ``sun_azimuth`` (degrees, azimuth from +x toward +y as in
    :func:`sun_direction`; the node's rotation is measured from +y the other way:
    ``sun_rotation = 90 - azimuth``).  ``strength`` scales the Background (0.08: the upper
    hemisphere's mean luminance about 0.37 for the default sun at 38 degrees).  Returns the world."""
    world = bpy.data.worlds.new(name)
    if world.node_tree is None:
        world.use_nodes = True
    nt = world.node_tree
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = sky_type
    sky.sun_disc = bool(sun_disc)
    sky.sun_elevation = math.radians(sun_elevation)
    sky.sun_rotation = math.radians(90.0 - sun_azimuth)
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = float(strength)
    nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    return world


def add_pathtraced_cloud(sigma, size, *, albedo, g, vdb_path, name="Path-traced cloud"):
    """The same medium for Cycles' volume path tracing (the reference)."""
    write_vdb(vdb_path, dense_grids({"density": sigma}, size))
    obj = _volume_object(name, vdb_path)
    obj.data.materials.append(scattering_material(albedo, g))
    return obj


# --------------------------------------------------------------------------- operator

KIND = "scatter"
OBJECT_NAME = "Scattering cloud"


def sun_direction(elevation_deg, azimuth_deg):
    """Unit vector toward the sun from elevation and azimuth (degrees, azimuth from +x toward +y)."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))


def cloud_params(props):
    """:class:`nephele.core.volume.cloud_density.CloudParams` from the panel's properties."""
    nx, ny, nz = props.resolution
    return cd.CloudParams(shape=(int(nz), int(ny), int(nx)), size=tuple(props.size),
                          noise_amplitude=props.noise_amplitude, noise_scale=props.noise_scale,
                          octaves=props.octaves, seed=props.seed)


def add_orbit_camera(center, radius, height, frames, fov=math.radians(40.0), name="Scatter orbit", scene=None):
    """A camera looping once around ``center`` over ``frames`` (the paper's animation):
    parented to an empty whose z rotation is keyed linearly from 0 to 360 degrees."""
    scene = scene or bpy.context.scene
    pivot = bpy.data.objects.new(name + " pivot", None)
    scene.collection.objects.link(pivot)
    pivot.location = center
    data = bpy.data.cameras.new(name)
    data.sensor_fit = "HORIZONTAL"
    data.angle = fov
    data.clip_start = 0.01
    cam = bpy.data.objects.new(name, data)
    scene.collection.objects.link(cam)
    cam.parent = pivot
    cam.location = (radius, 0.0, height)
    look_at(cam, (0.0, 0.0, 0.0))
    first, last = frames[0], frames[-1]
    n = max(len(frames), 1)
    pivot.rotation_euler = (0.0, 0.0, 0.0)
    pivot.keyframe_insert("rotation_euler", index=2, frame=first)
    pivot.rotation_euler = (0.0, 0.0, 2 * math.pi * (last + 1 - first) / n)
    pivot.keyframe_insert("rotation_euler", index=2, frame=last + 1)
    fcurves = _fcurves(pivot)
    for fc in fcurves:
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"
    scene.camera = cam
    return cam


def _fcurves(obj):
    ad = obj.animation_data
    act = ad.action if ad else None
    if act is None:
        return []
    if hasattr(act, "fcurves"):
        return list(act.fcurves)
    # Blender 5 layered actions: fcurves live in the channelbags of the strips.
    out = []
    for layer in act.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out.extend(bag.fcurves)
    return out


DEFAULT_DIRECTORY = "//nephele_scatter"


def output_directory(text):
    """Absolute output directory.  The default (``//nephele_scatter``) is a folder
    Nephele owns: beside the saved .blend, or this session's own folder in an
    unsaved file (:func:`.data_ops.owned_dir`, moved beside the .blend on save);
    another blend-relative path in an unsaved file goes there too instead of
    the file system root."""
    from . import data_ops

    if text == DEFAULT_DIRECTORY:
        return data_ops.owned_dir("scatter")
    if text.startswith("//") and not bpy.data.filepath:
        return data_ops.owned_dir("scatter", text[2:].strip("/\\"))
    return Path(bpy.path.abspath(text)).resolve()


SCENE_NAME = "Nephele scattering"
BYTES_PER_CELL = 8000.0
"""Peak memory of the scattering solve per grid cell (tracemalloc: 7.6 kB at
24x24x18 with its fixed costs, 16.6 kB at 16x16x12; the solution alone holds
1.93 kB per cell), with 96 bins; the per-bin arrays, nearly all of it, grow as the bins'
number, ``6 n^2``."""


def _globe(scene):
    """``(centre, radius with haze glow)`` of the scene's Nephele globe, or None."""
    from mathutils import Vector

    from .globe_ops import frame_radius

    for ob in scene.objects:
        if "nephele_globe" in ob:
            return Vector(ob.matrix_world.translation), frame_radius(scene) * max(ob.matrix_world.to_scale())
    return None


def placement(scene, size):
    """World position of the cloud box's corner (its ``(0, 0, 0)``).

    Without a globe: centred on the origin, resting on z = 0 (the paper's
    Fig. 6 set-up).  With one the box at the origin would sit inside the
    Earth, so it goes in front of the scene camera, as far as it can while
    staying wholly outside the globe (and its haze glow); with no camera, or
    one too close to the globe, it floats above the north pole.
    """
    from mathutils import Vector

    half = Vector(size) / 2.0
    found = _globe(scene)
    if found is None:
        return (-half.x, -half.y, 0.0)
    centre, radius = found
    clear = radius + 1.1 * half.length  # the box's bounding sphere stays outside
    cam = scene.camera
    if cam is not None:
        eye = cam.matrix_world.translation
        ahead = (cam.matrix_world.to_3x3() @ Vector((0.0, 0.0, -1.0))).normalized()
        # The farthest point along the view that keeps the cloud clear of the globe.
        for s in np.linspace((eye - centre).length + radius, 1.5 * half.length, 200).tolist():
            c = eye + s * ahead
            if (c - centre).length >= clear and all((eye + t * ahead - centre).length >= clear
                                                    for t in np.linspace(0.0, s, 16).tolist()):
                return tuple(c - half)
    c = centre + Vector((0.0, 0.0, clear))
    return tuple(c - half)


def scene_sun(scene):
    """The scene's first visible sun lamp, or None."""
    return next((ob for ob in scene.objects if ob.type == "LIGHT" and ob.data.type == "SUN" and not ob.hide_render),
                None)


def own_scene(context):
    """A scene of the cloud's own (same frame range; a black world, or this scene's world
    when that world lights the cloud), for the "Own scene" option: its frames are stepped
    without the main scene's layers."""
    scene = context.scene
    new = bpy.data.scenes.get(SCENE_NAME) or bpy.data.scenes.new(SCENE_NAME)
    if scene.nephele_scatter.sky == "WORLD" and scene.world is not None:
        new.world = scene.world  # the sky lighting the cloud is also seen behind it
    elif new.world is None or new.world == scene.world:
        black_world(new)
    new.frame_start, new.frame_end = scene.frame_start, scene.frame_end
    new.frame_current = scene.frame_current
    new.render.engine = "CYCLES"
    r0, r = scene.render, new.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = r0.resolution_x, r0.resolution_y, r0.resolution_percentage
    # The panel's settings follow the artist into the new scene.
    for prop in type(scene.nephele_scatter).bl_rna.properties:
        if prop.identifier not in ("rna_type", "directory") and not prop.is_readonly:
            setattr(new.nephele_scatter, prop.identifier, getattr(scene.nephele_scatter, prop.identifier))
    if scene.nephele_scatter.directory != DEFAULT_DIRECTORY:
        new.nephele_scatter.directory = bpy.path.abspath(scene.nephele_scatter.directory)
    return new


def panel_sun(props, scene):
    """(direction toward the sun, irradiance) the panel lights the cloud with: the scene's sun
    lamp with "Scene's sun" (its direction and strength), else the panel's sun."""
    from mathutils import Vector

    lamp = scene_sun(scene) if props.use_scene_sun else None
    if lamp is not None:  # lit like the rest of the scene
        return tuple(lamp.matrix_world.to_3x3() @ Vector((0.0, 0.0, 1.0))), lamp.data.energy
    return sun_direction(props.sun_elevation, props.sun_azimuth), props.sun_irradiance


def panel_task(props, scene, old):
    """The ``"scatter"`` task (:func:`..core.light.scatter_task.task_params`) of the panel's
    cloud, albedo, g, sun and solve settings; the sky from ``old``'s solve (a baked world is
    not baked again)."""
    sun, irradiance = panel_sun(props, scene)
    return scatter_task.task_params(
        cloud_params(props), props.extinction, albedo=props.albedo, g=props.anisotropy, sun_dir=list(sun),
        sun_irradiance=irradiance, sky_radiance=old["solve"]["sky_radiance"], tol=props.tolerance,
        max_passes=props.max_passes, bins_per_face=props.bins_per_face)
