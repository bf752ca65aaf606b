"""Blender side of the multiple-scattering cloud (Fig. 6).

"Add scattering cloud" builds the droplet density (:mod:`nephele.core.volume.cloud_density`),
runs the binned shooting solve (:mod:`nephele.core.light.scatter`: 96 bins, or ``6 n^2`` with
"Bins per face" ``n``) as a modal operator that advances one group of bins per
timer tick (progress in the status bar and the panel; the interface stays live;
Esc cancels), then writes one VDB per frame
with ``density`` (extinction) and ``emission`` (in-scattered radiance toward
that frame's camera, exact sun single scattering included) and loads them as a
native volume sequence.  The material is Volume Absorption + Emission driven by
those grids, so Cycles renders an emission-absorption volume: no scattering
left to path trace.  The sky is none, uniform, or the scene's world baked into
the solve's bins (:func:`bake_world`: Cycles renders the world alone as a panorama).

:func:`add_pathtraced_cloud` builds the same medium for Cycles' own volume path
tracing (the benchmark's reference).

"Motion: Drifting noise" solves a cloud whose noise drifts through it, a solve a frame (each
started from the frame before), each frame's VDB with its own density; "Live update" re-solves
the cloud in the background when its albedo, g, sun or density change (:mod:`.scatter_jobs`,
which also holds the operator's job).
"""

import bpy

from . import frame
from . import scatter_scene as ss
from .panel import SubPanel
from .scatter_jobs import ScatterJob, live_status, resolve


def _live(props, context):
    """Property update: re-solve the live scattering clouds (:func:`.scatter_jobs.resolve`)."""
    resolve(props, context)


def _props_to_scene_check(props):
    if props.resolution[0] < 2 or props.resolution[1] < 2 or props.resolution[2] < 2:
        raise ValueError("resolution must be at least 2 in each direction")
    if props.bins_per_face % 2:
        raise ValueError(f"bins per face must be even (2, 4, 6 or 8), got {props.bins_per_face}")


class NEPHELE_OT_add_scattering_cloud(bpy.types.Operator):
    """Build a cloud, solve multiple scattering (binned directions) and write per-frame emission volumes"""

    bl_idname = "nephele.add_scattering_cloud"
    bl_label = "Add scattering cloud"
    bl_options = {"REGISTER", "UNDO"}

    _timer = None
    _job = None

    def _start(self, context):
        props = context.scene.nephele_scatter
        _props_to_scene_check(props)
        self._job = ScatterJob(context, props)
        if self._job.scene is not context.scene:
            self.report({"INFO"}, f"The cloud goes to its own scene '{self._job.scene.name}'")
            if context.window is not None:
                context.window.scene = self._job.scene

    def _select(self):
        # Blender convention: the new object alone selected and active (in the cloud's scene).
        layer = self._job.scene.view_layers[0]
        for o in list(layer.objects.selected):
            if o is not None:  # None: an object this operator replaced
                o.select_set(False, view_layer=layer)
        self._job.obj.select_set(True, view_layer=layer)
        layer.objects.active = self._job.obj

    def execute(self, context):
        try:
            self._start(context)
            while not self._job.step(budget=1e9):
                pass
        except (ValueError, RuntimeError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, self._job.status)
        self._select()
        return {"FINISHED"}

    def invoke(self, context, event):
        try:
            self._start(context)
        except (ValueError, RuntimeError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.progress_begin(0.0, 1.0)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        props = self._job.props
        if event.type == "ESC":
            self._end(context)
            props.status = "Cancelled"
            props.progress = 0.0
            self.report({"WARNING"}, "Scattering cancelled")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            done = self._job.step(budget=0.15)
        except (ValueError, RuntimeError, OSError) as exc:
            self._end(context)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        props.progress = self._job.fraction
        props.status = self._job.status
        context.window_manager.progress_update(self._job.fraction)
        if context.workspace:
            context.workspace.status_text_set(self._job.status)
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        if done:
            self._end(context)
            props.progress = 1.0
            self.report({"INFO"}, self._job.status)
            self._select()
            return {"FINISHED"}
        return {"RUNNING_MODAL"}


class NepheleScatterProps(bpy.types.PropertyGroup):
    resolution: bpy.props.IntVectorProperty(name="Grid", size=3, default=(24, 24, 18), min=2, max=512)
    size: bpy.props.FloatVectorProperty(name="Box", size=3, default=(1.0, 1.0, 0.75), min=1e-3)
    extinction: bpy.props.FloatProperty(name="Extinction", default=40.0, min=0.0,
                                        description="Extinction per scene unit at density 1", update=_live)
    albedo: bpy.props.FloatProperty(name="Albedo", default=0.99, min=0.0, max=1.0, update=_live)
    anisotropy: bpy.props.FloatProperty(name="Anisotropy g", default=0.8, min=-0.999, max=0.999,
                                        description="Henyey-Greenstein asymmetry (0.8: water droplets)", update=_live)
    noise_amplitude: bpy.props.FloatProperty(name="Noise", default=0.7, min=0.0, update=_live)
    noise_scale: bpy.props.FloatProperty(name="Noise scale", default=5.0, min=0.01, update=_live)
    octaves: bpy.props.IntProperty(name="Octaves", default=4, min=1, max=8, update=_live)
    seed: bpy.props.IntProperty(name="Seed", default=0, update=_live)
    sun_elevation: bpy.props.FloatProperty(name="Sun elevation", default=38.0, min=-90.0, max=90.0, update=_live)
    sun_azimuth: bpy.props.FloatProperty(name="Sun azimuth", default=-30.0, update=_live)
    sun_irradiance: bpy.props.FloatProperty(name="Sun irradiance", default=1.0, min=0.0, update=_live)
    sky: bpy.props.EnumProperty(
        name="Sky", default="UNIFORM",
        items=(("NONE", "None", "No skylight: the sun alone"),
               ("UNIFORM", "Uniform", "A uniform sky above the cloud of the radiance below"),
               ("WORLD", "Scene's world",
                "The scene's world (e.g. a Sky Texture) rendered around the cloud and binned into the solve's "
                "direction bins.  When a sun lights the cloud (the lamp or the sun irradiance here), the "
                "world's Sky Texture sun discs are left out of the bake, so the sun does not count twice: "
                "match the sky's sun to it (Sky Texture rotation = 90 degrees - azimuth)")))
    sky_radiance: bpy.props.FloatProperty(name="Sky radiance", default=0.0, min=0.0,
                                          description="Radiance of the uniform sky (light travelling downward)")
    tolerance: bpy.props.FloatProperty(name="Tolerance", default=1e-3, min=1e-8, max=0.5)
    max_passes: bpy.props.IntProperty(name="Max passes", default=100, min=1)
    bins_per_face: bpy.props.IntProperty(
        name="Bins per face", default=4, min=2, max=8, step=2,
        description="Direction bins per cube-face side, even: 6 n^2 bins (4: the paper's 96; 6: 216, closer "
                    "to exact for a sharp forward peak, 2.7 times the solve time and 2.2 times the memory)")
    use_scene_sun: bpy.props.BoolProperty(
        name="Scene's sun", default=True,
        description="Light the cloud with the scene's sun lamp (its direction and strength) when it has one")
    own_scene: bpy.props.BoolProperty(
        name="Own scene", default=False,
        description="Put the cloud in a scene of its own (else in this one, in front of the camera and "
                    "outside any globe)")
    orbit_camera: bpy.props.BoolProperty(name="Orbit camera", default=True,
                                         description="Add a camera looping around the cloud if the scene has none")
    orbit_elevation: bpy.props.FloatProperty(
        name="Orbit elevation", default=15.0, min=-80.0, max=80.0,
        description="Degrees of the orbit camera above the cloud's centre (the paper's 15; below zero the "
                    "cloud is seen from underneath, against the sky)")
    live_update: bpy.props.BoolProperty(
        name="Live update", default=True,
        description="Re-solve the scattering cloud in the background when its albedo, g, sun or density change")
    evolve: bpy.props.EnumProperty(
        name="Motion", default="NONE",
        items=(("NONE", "Still", "One cloud for the whole film: one solve"),
               ("DRIFT", "Drifting noise", "The noise drifts through the ellipsoids over the film: a solve a frame, "
                                           "each started from the frame before")))
    drift: bpy.props.FloatVectorProperty(name="Drift", size=3, default=(0.25, 0.1, 0.02),
                                         description="How far the noise moves over the film (box units, x y z)")
    directory: bpy.props.StringProperty(name="Output", default=ss.DEFAULT_DIRECTORY, subtype="DIR_PATH")
    progress: bpy.props.FloatProperty(name="Progress", default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    status: bpy.props.StringProperty(name="Status", default="")


class NEPHELE_PT_scatter(SubPanel, bpy.types.Panel):
    bl_label = "Scattering cloud (Fig. 6)"
    bl_idname = "NEPHELE_PT_scatter"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        p = context.scene.nephele_scatter
        col = self.layout.column()
        col.prop(p, "resolution")
        col.prop(p, "size")
        col.prop(p, "extinction")
        col.prop(p, "noise_amplitude")
        col.prop(p, "noise_scale")
        col.prop(p, "octaves")
        col.prop(p, "seed")
        col.separator()
        col.prop(p, "albedo")
        col.prop(p, "anisotropy")
        col.prop(p, "use_scene_sun")
        col.prop(p, "sun_elevation")
        col.prop(p, "sun_azimuth")
        col.prop(p, "sun_irradiance")
        col.prop(p, "sky")
        if p.sky == "UNIFORM":
            col.prop(p, "sky_radiance")
        col.prop(p, "tolerance")
        col.prop(p, "max_passes")
        col.prop(p, "bins_per_face")
        col.prop(p, "own_scene")
        col.prop(p, "orbit_camera")
        sub = col.row()
        sub.active = p.orbit_camera
        sub.prop(p, "orbit_elevation")
        col.prop(p, "evolve")
        if p.evolve == "DRIFT":
            col.prop(p, "drift")
        col.prop(p, "live_update")
        col.prop(p, "directory")
        col.operator(NEPHELE_OT_add_scattering_cloud.bl_idname)
        cloud = context.scene.objects.get(ss.OBJECT_NAME)
        live = None if cloud is None or frame.params(cloud).get("kind") != ss.KIND else live_status(cloud)
        if live:
            col.label(text=live)
        col.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG6"
        if p.status:
            col.prop(p, "progress")
            col.label(text=p.status)


CLASSES = (NepheleScatterProps, NEPHELE_OT_add_scattering_cloud, NEPHELE_PT_scatter)
SCENE_PROPERTIES = {"nephele_scatter": NepheleScatterProps}

