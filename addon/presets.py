"""The paper's figures as presets: each recipe builds one figure's scene into a scene.

One recipe per figure of Max & Crawfis (``fig1`` ... ``fig7``), each with its
``*_DEFAULTS``: the data, the layer, camera, sun and sky and the render
settings.  The examples (``examples/fig*.py``) parse their command line and
call these recipes, and the operator ``nephele.paper_figure`` (a button in
each figure's panel) calls them with the defaults, so the panel's preset and
the example build the same scene.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Figs. 1-7.
"""

import math

import bpy
import numpy as np

from . import frame, globe_ops, globe_scene

FIG1_DEFAULTS = {
    "source": "demo",
    "level": 0.15,
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.climate.grid.DEFAULT_EXAGGERATION
    "method": "cubes",
    "haze": "volume",  # "volume", "shell" (cheap, closed form) or "none"
    "camera_lon": -40.0,
    "camera_lat": 22.0,
    "camera_distance": 4.5,
    "frames": (1, 24),
    "size": (640, 480),
    "samples": 32,
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG2_DEFAULTS = {
    "source": "demo",
    "threshold": 0.3,
    "full": 0.7,
    "extinction": None,  # None: nephele.core.volume.sparse.DEFAULT_EXTINCTION
    "mode": None,  # None: "exact" for Cycles, "voxels" for EEVEE (which renders the exact shader striped)
    "voxel_size": None,  # None: nephele.core.volume.sparse.DEFAULT_VOXEL_SIZE (voxel mode)
    "color_var": "altitude",
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.climate.grid.DEFAULT_EXAGGERATION
    "haze": True,
    "camera_lon": -115.0,
    "camera_lat": 28.0,
    "camera_distance": 3.0,
    "engine": "CYCLES",
    "frames": (1, 24),
    "size": (640, 480),
    "samples": 32,
    "vdb_dir": None,  # None: the volume layer's own cache folder (beside the saved .blend)
    "bake": "all",  # "lazy": each frame's .vdb written when shown (farm: after nephele precompute)
    "volume_bounces": 4,  # clouds lit by each other; 0: single scattering (a preview, several times faster)
    "volume_biased": False,  # Cycles' ray marching: ~20x less set-up a frame than null scattering, ~2.5% darker
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG3_DEFAULTS = {
    "source": "demo:small",
    "hours_per_frame": 1.0,
    "exaggeration": None,
    "extinction": 60.0,
    "contrast": 0.8,
    "camera_lon": -30.0,
    "camera_lat": 30.0,
    "camera_distance": 3.6,
    "frames": (1, 1),
    "size": (320, 240),
    "samples": 4,
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG4_DEFAULTS = {
    "source": "demo",
    "level": 0.15,
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.climate.grid.DEFAULT_EXAGGERATION
    "method": "cubes",
    "strategy": "restart",
    "period": 24,
    "vertical": "auto",  # the demo's levels follow the air (w is the lift of riding them): kept, exact there
    "haze": True,
    "camera_lon": -40.0,
    "camera_lat": 30.0,
    "camera_distance": 3.2,
    "frames": (1, 13),
    "size": (480, 360),
    "samples": 16,
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG5_DEFAULTS = {
    "source": "demo:small",
    "hours_per_frame": 1.0,
    "exaggeration": None,
    "lon": -40.0,
    "lat": 35.0,
    "height": 2000.0,
    "radius": 0.05,
    "hours": 24.0,
    "sides": 32,
    # Optical depth about 1 across the generator's diameter: translucent smoke, as in the paper.
    "density": 10.0,
    "grow": False,  # True: the release lasts until the frame's time (the smoke leaves the generator and is carried)
    "volume_biased": False,  # Cycles' ray marching: ~20x less set-up a frame than null scattering, ~2.5% darker
    "camera_lon": -40.0,
    "camera_lat": 38.0,
    "camera_distance": 2.2,
    "frames": (1, 1),
    "size": (320, 240),
    "samples": 16,
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG6_DEFAULTS = {
    "frames": 120,  # the camera's orbit
    "grid": (24, 24, 18),
    "sun_irradiance": 7.0,
    "sky_radiance": 0.35,
    "sky": "uniform",  # or "world": a Sky Texture world with the cloud's sun, baked into the bins
    "camera_elevation": None,  # degrees; None: the paper's 15, or -20 under a world sky (seen against it)
    "directory": None,  # None: the scattering panel's output folder
    "size": (300, 255),  # the paper's
    "samples": 32,
    "volume_biased": False,  # Cycles' ray marching: ~20x less set-up a frame than null scattering, ~2.5% darker
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}

FIG7_DEFAULTS = {
    "seed": 0,
    "film_frames": 240,
    "spacing": 0.8,  # nm; 0.5 for the full-quality film
    "tiles": (3, 3, 1),
    "dome": None,  # or "omnimax" / "domemaster"
    "stereo": False,
    "separation": 0.006,  # scene units (1 = 100 nm): a 0.6 nm eye base, about 1/30 of the nearest molecules
    "size": (320, 240),
    "samples": 8,
    "max_bounces": None,  # None: Cycles' 12; 3 for a preview (the headlit lattice is mostly direct light)
    "annotations": False,  # the caption (and for climate data the model time and a legend) over renders
}


def _reset(props):
    """Every property of a panel's property group back to its default (the example starts from a fresh file)."""
    for prop in props.bl_rna.properties:
        if prop.identifier != "rna_type" and not prop.is_readonly:
            props.property_unset(prop.identifier)
    return props


def _annotate(scene, o, figure, **kw):
    """With ``o["annotations"]``: the figure's annotation layer (:mod:`.annotate_ops`) over every render."""
    if o["annotations"]:
        from . import annotate_ops

        annotate_ops.add_annotations(scene, figure=figure, **kw)


def fig1(scene, **options):
    """Fig. 1, contour surfaces of 15% cloudiness, into ``scene``; returns a dict of the main objects.

    Options (see :data:`FIG1_DEFAULTS`): ``source``, ``level``, ``hours_per_frame``,
    ``exaggeration``, ``method``, ``haze``, ``camera_lon``, ``camera_lat``,
    ``camera_distance``, ``frames`` (first, last), ``size`` (w, h), ``samples``.
    """
    from . import contour_ops

    o = globe_scene.merge_options(FIG1_DEFAULTS, options)
    haze = {True: "volume", False: "none"}.get(o["haze"], o["haze"])
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=haze != "none",
                                         haze_mode=haze if haze != "none" else "volume")
    clouds = contour_ops.add_contour("cloud", o["level"], scene=scene, color_var="altitude",
                                     method=o["method"], name="Clouds 15%")
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    frame.install()
    _annotate(scene, o, "fig1")
    return {"globe": globe, "clouds": clouds, "camera": camera, **sky}


def fig2(scene, **options):
    """Fig. 2, volume-rendered clouds over the terrain, into ``scene``; returns a dict of the main objects.

    Options (see :data:`FIG2_DEFAULTS`): ``source``, ``threshold``, ``full``,
    ``extinction``, ``mode`` (``"exact"``: the material evaluates the
    curvilinear field per sample; ``"voxels"``: a resampled VDB),
    ``voxel_size``, ``color_var``, ``hours_per_frame``, ``exaggeration``,
    ``haze``, ``camera_lon``, ``camera_lat``, ``camera_distance``, ``engine``
    (CYCLES or BLENDER_EEVEE), ``frames`` (first, last), ``size`` (w, h),
    ``samples``, ``vdb_dir``, ``bake`` (``"all"`` now, or ``"lazy"``: per
    frame when shown, from the cache that ``nephele precompute`` fills), ``volume_bounces`` (Cycles;
    default 4, 0 for single scattering).
    """
    from ..core.volume.sparse import DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE
    from ..core.volume.transfer import TransferFunction
    from . import volume_ops

    o = globe_scene.merge_options(FIG2_DEFAULTS, options)
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(-0.075, -0.863, 0.5), haze=bool(o["haze"]))
    clouds, infos = volume_ops.add_volume_clouds(
        "cloud", TransferFunction.ramp(float(o["threshold"]), float(o["full"])), scene=scene,
        color_var=o["color_var"],
        voxel_size=DEFAULT_VOXEL_SIZE if o["voxel_size"] is None else float(o["voxel_size"]),
        extinction=DEFAULT_EXTINCTION if o["extinction"] is None else float(o["extinction"]),
        directory=o["vdb_dir"], bake=o["bake"],
        mode=o["mode"] or ("voxels" if o["engine"] == "BLENDER_EEVEE" else "exact"),
    )
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"], engine=o["engine"])
    # Clouds lit by the sun and by each other (a few volume bounces).
    scene.cycles.volume_bounces = int(o["volume_bounces"])
    scene.cycles.volume_biased = bool(o["volume_biased"])
    scene.eevee.taa_render_samples = int(o["samples"])
    volume_ops.eevee_volume_settings(scene)
    frame.install()
    _annotate(scene, o, "fig2")
    return {"globe": globe, "clouds": clouds, "camera": camera, "bake": infos, **sky}


def fig3(scene, **options):
    """Fig. 3, clouds and wind as texture splats, into ``scene``; returns a dict of the main objects.

    Options: see :data:`FIG3_DEFAULTS`.
    """
    from . import splat_ops

    o = globe_scene.merge_options(FIG3_DEFAULTS, options)
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=False)
    p = _reset(scene.nephele_splats)
    p.extinction, p.contrast = o["extinction"], o["contrast"]
    with bpy.context.temp_override(scene=scene):
        if bpy.ops.nephele.add_wind_splats() != {"FINISHED"}:
            raise RuntimeError("Add wind splats failed")
        splats = bpy.context.view_layer.objects.active
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    scene.cycles.use_denoising = False  # the denoiser smears the streaks
    splat_ops.render_settings(scene)
    _annotate(scene, o, "fig3")
    return {"globe": globe, "splats": splats, "camera": camera, **sky}


def fig4(scene, **options):
    """Fig. 4, the clouds of Fig. 1 with a texture carried by the wind, into ``scene``.

    Options (see :data:`FIG4_DEFAULTS`): ``source``, ``level``, ``hours_per_frame``,
    ``exaggeration``, ``method``, ``strategy``, ``period``, ``vertical``, ``haze``,
    ``camera_lon``, ``camera_lat``, ``camera_distance``, ``frames`` (first, last),
    ``size`` (w, h), ``samples``.  Returns a dict of the main objects.
    """
    from . import advect_ops, contour_ops

    o = globe_scene.merge_options(FIG4_DEFAULTS, options)
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=bool(o["haze"]))
    clouds = contour_ops.add_contour("cloud", o["level"], scene=scene, color_var="altitude",
                                     method=o["method"], name="Clouds 15%")
    advect_ops.add_advected_texture(clouds, strategy=o["strategy"], period=int(o["period"]), vertical=o["vertical"],
                                    scene=scene)
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    frame.install()
    _annotate(scene, o, "fig4")
    return {"globe": globe, "clouds": clouds, "camera": camera, **sky}


def fig5(scene, **options):
    """Fig. 5, smoke in the global air circulation (a flow volume), into ``scene``.

    Options: see :data:`FIG5_DEFAULTS`.  Returns a dict of the main objects.
    """
    o = globe_scene.merge_options(FIG5_DEFAULTS, options)
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=False)
    p = _reset(scene.nephele_flowvol)
    p.lon, p.lat, p.height, p.radius = o["lon"], o["lat"], o["height"], o["radius"]
    p.hours, p.sides = o["hours"], o["sides"]
    p.density = o["density"]
    p.live = False
    if o["exaggeration"] is not None:
        p.exaggeration = o["exaggeration"]
    with bpy.context.temp_override(scene=scene):
        if bpy.ops.nephele.add_flow_volume() != {"FINISHED"}:
            raise RuntimeError(f"Add flow volume failed: {p.status}")
    scene.cycles.volume_biased = bool(o["volume_biased"])
    if o["grow"]:
        smoke = bpy.data.objects["Flow volume smoke"]
        frame.set_params(smoke, {**frame.params(smoke), "grow": True})
        frame.submit(smoke, scene, force=True)
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    _annotate(scene, o, "fig5")
    return {"globe": globe, "smoke": bpy.data.objects["Flow volume smoke"], "camera": camera, **sky}


def fig6(scene, modal=False, **options):
    """Fig. 6, a cloud lit by multiple scattering with the camera looping around it, into ``scene``.

    Options (see :data:`FIG6_DEFAULTS`): ``frames`` (the orbit's length),
    ``grid``, ``sun_irradiance``, ``sky_radiance``, ``sky`` (``"uniform"``: a blue
    background, the cloud lit by a uniform sky of ``sky_radiance``; ``"world"``: a
    Sky Texture world, :func:`.scatter_scene.add_sky_world`, with its sun where the
    cloud's sun is, lighting the cloud through :func:`.scatter_scene.bake_world`),
    ``camera_elevation`` (degrees of the orbit above the cloud's centre; default 15, or -20
    under a world sky so that the sky is behind the cloud), ``directory`` (the VDBs),
    ``size``, ``samples``.  ``modal``: the solve runs as the scattering
    operator's modal job (progress, Esc) and the cloud appears when it ends
    (the returned ``"cloud"`` is then None).  Returns ``{"cloud": obj, "camera": camera}``.
    """
    o = globe_scene.merge_options(FIG6_DEFAULTS, options)
    scene.frame_start, scene.frame_end = 1, int(o["frames"])
    p = _reset(scene.nephele_scatter)
    p.resolution = tuple(int(v) for v in o["grid"])
    p.sun_irradiance = o["sun_irradiance"]
    p.sky_radiance = o["sky_radiance"]
    elevation = o["camera_elevation"]
    p.orbit_elevation = (-20.0 if o["sky"] == "world" else 15.0) if elevation is None else float(elevation)
    if o["directory"]:
        p.directory = str(o["directory"])
    if o["sky"] == "world":
        from . import scatter_scene

        p.sky = "WORLD"
        world = scatter_scene.add_sky_world(p.sun_elevation, p.sun_azimuth, name="Fig6 sky")
    elif o["sky"] == "uniform":
        world = bpy.data.worlds.new("Fig6 sky")
        if world.node_tree is None:
            world.use_nodes = True
        bg = world.node_tree.nodes["Background"]
        bg.inputs["Color"].default_value = (0.22, 0.36, 0.66, 1.0)
        bg.inputs["Strength"].default_value = 1.0
    else:
        raise ValueError(f"sky must be 'uniform' or 'world', got {o['sky']!r}")
    scene.world = world
    with bpy.context.temp_override(scene=scene):
        result = bpy.ops.nephele.add_scattering_cloud("INVOKE_DEFAULT" if modal else "EXEC_DEFAULT")
        if not result & {"FINISHED", "RUNNING_MODAL"}:
            raise RuntimeError(f"Add scattering cloud failed: {p.status}")
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(o["samples"])
    scene.cycles.use_denoising = True  # OIDN: the emission volume's sampling noise only
    scene.cycles.volume_bounces = 0  # the light is in the emission grid already
    scene.cycles.volume_biased = bool(o["volume_biased"])
    # a physical sky is high dynamic range (bright horizon, sun-side glow): AgX rolls it off
    # where Standard clips it to white
    scene.view_settings.view_transform = "AgX" if o["sky"] == "world" else "Standard"
    scene.render.resolution_x, scene.render.resolution_y = (int(v) for v in o["size"])
    scene.render.resolution_percentage = 100
    _annotate(scene, o, "fig6")
    return {"cloud": None if modal else bpy.data.objects["Scattering cloud"], "camera": scene.camera}


def cap_bounces(scene, bounces):
    """At most ``bounces`` bounces per Cycles light path (each kind capped too), no caustics."""
    c = scene.cycles
    b = int(bounces)
    c.max_bounces = b
    c.diffuse_bounces, c.glossy_bounces = min(b, c.diffuse_bounces), min(b, c.glossy_bounces)
    c.transmission_bounces = min(b, c.transmission_bounces)
    c.transparent_max_bounces = min(b, c.transparent_max_bounces)
    c.caustics_reflective = c.caustics_refractive = False  # opaque molecules: caustic paths would only add noise


def fig7(scene, **options):
    """Fig. 7, muscle cross-bridges in motion, into ``scene``; returns ``{"film": obj, "camera": camera or rig}``.

    Options (see :data:`FIG7_DEFAULTS`): ``seed``, ``film_frames``, ``spacing``
    (nm), ``tiles``, ``dome`` (None: a perspective camera inside the lattice;
    ``"omnimax"`` or ``"domemaster"``: the dome rig, its front along the fibre),
    ``stereo``, ``separation``, ``size``, ``samples``, ``max_bounces`` (None: Cycles' own).
    """
    from . import dome_ops, muscle_ops

    o = globe_scene.merge_options(FIG7_DEFAULTS, options)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(o["samples"])
    scene.cycles.use_denoising = False
    if o["max_bounces"] is not None:
        cap_bounces(scene, o["max_bounces"])
    frame.install()
    obj = muscle_ops.add_muscle_film(seed=o["seed"], frames=o["film_frames"], spacing=o["spacing"],
                                     tiles=tuple(o["tiles"]), scene=scene)
    cam = scene.camera
    w, h = (int(v) for v in o["size"])
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    if o["dome"]:
        # The dome's front is +y: turn the lattice so its fibre (local z) runs along +y, keeping it centred.
        rot = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)  # rotation by -90 degrees about x
        obj.rotation_euler = (-math.pi / 2, 0.0, 0.0)
        obj.location = tuple(rot @ np.array(obj.location))
        eye = rot @ np.array(cam.location)
        bpy.data.objects.remove(cam, do_unlink=True)
        cam = dome_ops.add_dome_camera(o["dome"], stereo=bool(o["stereo"]), separation=float(o["separation"]),
                                       location=tuple(eye), width=w, height=h, scene=scene)
        light = bpy.data.objects.get("Muscle light")  # the headlight rides with the audience
        if light is not None:
            light.parent = cam
            light.location = (0.03, 0.03, 0.0)
    _annotate(scene, o, "fig7")
    return {"film": obj, "camera": cam}


# enum id: (recipe, label, what the preset builds)
FIGURES = {
    "FIG1": (fig1, "Fig. 1 contour surfaces", "15% cloudiness contour over the relief globe, sky, sun, haze, camera"),
    "FIG2": (fig2, "Fig. 2 volume clouds", "Volume-rendered clouds over the globe with 4 volume bounces"),
    "FIG3": (fig3, "Fig. 3 wind splats", "Clouds and wind as texture splats over the globe"),
    "FIG4": (fig4, "Fig. 4 advected texture", "The Fig. 1 clouds with a texture carried by the wind"),
    "FIG5": (fig5, "Fig. 5 flow volume", "Smoke released into the global winds for 24 hours"),
    "FIG6": (fig6, "Fig. 6 scattering cloud", "A multiply scattering cloud and a camera orbiting it"),
    "FIG7": (fig7, "Fig. 7 muscle film", "Muscle cross-bridges in motion, a camera inside the lattice"),
}


def clear_scene(scene):
    """Empty ``scene`` as a new file's: its objects removed (those no other scene uses are deleted), camera
    and world unset, Cycles settings and colour management back to a new scene's (a previous figure's
    bounces or view transform would otherwise change this one's look)."""
    _reset(scene.cycles)
    fresh = bpy.data.scenes.new("Nephele fresh settings")
    try:
        for name in ("view_transform", "look", "exposure", "gamma"):
            setattr(scene.view_settings, name, getattr(fresh.view_settings, name))
    finally:
        bpy.data.scenes.remove(fresh)
    for obj in list(scene.objects):
        if len(obj.users_scene) > 1:
            for coll in list(obj.users_collection):
                if scene.user_of_id(coll) or coll is scene.collection:
                    coll.objects.unlink(obj)
        else:
            bpy.data.objects.remove(obj, do_unlink=True)
    scene.camera = None
    scene.world = None


class NEPHELE_OT_paper_figure(bpy.types.Operator):
    """Build the paper's figure in this scene, as its example does (data, layer, camera, sun and sky, render
    settings)"""

    bl_idname = "nephele.paper_figure"
    bl_label = "Make the paper's figure"
    bl_options = {"REGISTER", "UNDO"}

    figure: bpy.props.EnumProperty(name="Figure", items=[(k, v[1], v[2]) for k, v in FIGURES.items()])
    annotations: bpy.props.BoolProperty(name="Annotations", default=False,
                                        description="Lay the caption, the model time and a legend over every render")
    replace: bpy.props.BoolProperty(name="Replace the scene's objects", default=True,
                                    description="Empty this scene first, as the example starts from an empty file")

    def invoke(self, context, event):
        if self.replace and len(context.scene.objects):
            return context.window_manager.invoke_confirm(
                self, event, title=f"{FIGURES[self.figure][1]}: replace the {len(context.scene.objects)} objects "
                                   "of this scene?")
        return self.execute(context)

    def execute(self, context):
        scene = context.scene
        if self.replace:
            clear_scene(scene)
        # Fig. 6's solve (~30 s) runs as the scattering operator's modal job where there is a window to show it.
        # Fig. 2's 24 frames (~40 s) bake in the background (nephele.bake_volume) where there is a window.
        window = context.window is not None
        options = ({"modal": True} if self.figure == "FIG6" and window
                   else {"bake": "lazy"} if self.figure == "FIG2" and window else {})
        options["annotations"] = self.annotations
        try:
            out = FIGURES[self.figure][0](scene, **options)
        except (ValueError, RuntimeError, OSError) as exc:
            self.report({"ERROR"}, f"{FIGURES[self.figure][1]}: {exc}")
            return {"CANCELLED"}
        if options.get("bake") == "lazy":
            bpy.ops.nephele.bake_volume("INVOKE_DEFAULT", name=out["clouds"].name)
        self.report({"INFO"}, f"{FIGURES[self.figure][1]}: built, {len(scene.objects)} objects")
        return {"FINISHED"}


CLASSES = (NEPHELE_OT_paper_figure,)
