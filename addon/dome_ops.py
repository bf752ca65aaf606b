"""Dome cameras in Blender: a Cycles fisheye that renders the final frame, and the EEVEE cube-map route.

:func:`add_dome_camera` builds a rig: an empty ``DomeRig`` whose axes are the
theatre frame of :mod:`nephele.core.camera.dome` (x right, y front, z up; move or
turn the rig to place the audience), with one fisheye camera ``DomeCamera``
or, in stereo, ``DomeCamera_L`` / ``DomeCamera_R`` a fixed baseline apart
along the rig's x axis (see :func:`nephele.core.camera.dome.stereo_eyes` for why not
Cycles' spherical stereo; Blender's own stereo also offsets the eyes along
the camera's x axis, which on the front-at-top Omnimax frame is the
audience's *left*, swapping the eyes).  Stereo renders use Blender's multi-view with the
``_L`` / ``_R`` camera suffixes, so every frame is written as
``name_L.png`` and ``name_R.png`` for the farm's post-processing.

Cycles renders the dome frame directly: an equidistant lens is
``FISHEYE_LENS_POLYNOMIAL`` as an exact f-theta (``k1 = -(fov/2)/(sensor_width/2)``,
horizontal sensor fit, ``sensor_height = sensor_width * H / W``) and an
equisolid lens ``FISHEYE_EQUISOLID``; the Omnimax lens offset is ``shift_y``
(in frame heights for panoramic cameras).  EEVEE renders a panoramic camera
as a plain perspective view without a word, so :func:`render_dome_eevee`
renders six 90 deg cube faces per eye and remaps them with
:func:`nephele.core.camera.dome.remap`; :func:`engine_warning` (also run before every
render by a ``render_pre`` handler) says when a panoramic camera meets EEVEE.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 7,
   Omnimax stereo).
"""

import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
from bpy.app.handlers import persistent
from mathutils import Matrix, Vector

from ..core.camera import dome as core_dome
from ..core.errors import DataError
from ..fileio import read_image, write_image
from . import frame
from .mesh import select_only
from .panel import SubPanel

RIG_NAME = "DomeRig"
CAMERA_NAME = "DomeCamera"
SENSOR_WIDTH = 36.0
EEVEE_ENGINES = ("BLENDER_EEVEE", "BLENDER_EEVEE_NEXT")


def _lens_rotation(camera):
    """Rotation (4x4) taking a Blender camera (looks down -Z, up +Y) to the dome lens frame."""
    a, b, c = camera.basis
    return Matrix([[a[i], b[i], -c[i]] for i in range(3)]).to_4x4()


def configure_fisheye(cam_data, camera):
    """Set Blender camera data so a Cycles render is ``camera``'s dome frame (a core DomeCamera)."""
    cam_data.type = "PANO"
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = SENSOR_WIDTH
    cam_data.sensor_height = SENSOR_WIDTH * camera.height / camera.width
    half = math.radians(camera.fov) / 2.0
    if camera.lens == "equidistant":
        cam_data.panorama_type = "FISHEYE_LENS_POLYNOMIAL"
        cam_data.fisheye_polynomial_k0 = 0.0
        cam_data.fisheye_polynomial_k1 = -half / (SENSOR_WIDTH / 2.0)
        for k in (2, 3, 4):
            setattr(cam_data, f"fisheye_polynomial_k{k}", 0.0)
    else:
        cam_data.panorama_type = "FISHEYE_EQUISOLID"
        cam_data.fisheye_fov = 2.0 * half
        cam_data.fisheye_lens = (SENSOR_WIDTH / 2.0) / (2.0 * math.sin(half / 2.0))
    cam_data.shift_x = 0.0
    cam_data.shift_y = camera.lens_shift


def camera_params(camera, *, stereo=False, separation=0.065, face_size=None, supersample=2):
    """The JSON-able parameters stored on the rig (``obj["nephele"]``, kind ``"dome"``)."""
    return {
        "kind": "dome",
        "preset": camera.preset,
        "width": camera.width,
        "height": camera.height,
        "fov": camera.fov,
        "tilt": camera.tilt,
        "lens": camera.lens,
        "lens_shift": camera.lens_shift,
        "stereo": bool(stereo),
        "separation": float(separation),
        "face_size": face_size,
        "supersample": int(supersample),
    }


def dome_from_params(p):
    """The core DomeCamera described by a rig's parameters."""
    return core_dome.dome_camera(
        p["preset"], width=p["width"], height=p["height"], fov=p["fov"], tilt=p["tilt"], lens=p["lens"],
        lens_shift=p["lens_shift"]
    )


def _remove(name):
    ob = bpy.data.objects.get(name)
    if ob is not None:
        data = ob.data
        bpy.data.objects.remove(ob, do_unlink=True)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)


def add_dome_camera(
    preset="omnimax",
    *,
    tilt=None,
    fov=None,
    width=None,
    height=None,
    lens="equidistant",
    lens_shift=None,
    stereo=False,
    separation=0.065,
    location=None,
    yaw=0.0,
    scene=None,
):
    """Add (or replace) the dome rig and make its camera the scene's camera.

    Parameters
    ----------
    preset : {"domemaster", "omnimax"}
    tilt, fov, width, height, lens, lens_shift
        See :func:`nephele.core.camera.dome.dome_camera` (unset: the preset's defaults).
    stereo : bool
        Two cameras ``separation`` apart along the rig's x axis, rendered as
        multi-view ``_L`` / ``_R`` frames.
    separation : float
        Eye separation in scene units.
    location : (3,) floats, optional
        The audience's eye point (the dome's centre).  Default: outside the
        scene's globe, the rig turned to look at it along the lens axis
        (:func:`audience_placement`; ``yaw`` then unused), or the origin when
        there is no globe.
    yaw : float
        Degrees the rig is turned about the vertical (0: the front is +y).
    scene : bpy.types.Scene, optional

    Returns
    -------
    The rig (an empty) whose children are the camera(s).

    Raises
    ------
    DataError
        Bad preset, field of view, size, tilt or eye separation.
    """
    scene = scene or bpy.context.scene
    camera = core_dome.dome_camera(preset, width=width, height=height, fov=fov, tilt=tilt, lens=lens,
                                   lens_shift=lens_shift)
    eyes = core_dome.stereo_eyes(separation) if stereo else {"": np.zeros(3)}
    rotation = (0.0, 0.0, -math.radians(yaw))
    if location is None:
        placed = audience_placement(camera, scene)
        location, rotation = placed if placed is not None else ((0.0, 0.0, 0.0), rotation)
    for name in (CAMERA_NAME, CAMERA_NAME + "_L", CAMERA_NAME + "_R", RIG_NAME):
        _remove(name)
    rig = bpy.data.objects.new(RIG_NAME, None)
    rig.empty_display_type = "ARROWS"
    rig.location = location
    rig.rotation_euler = rotation
    scene.collection.objects.link(rig)
    frame.set_params(rig, camera_params(camera, stereo=stereo, separation=separation))
    cams = []
    for suffix, pos in eyes.items():
        name = CAMERA_NAME + (f"_{suffix}" if suffix else "")
        data = bpy.data.cameras.new(name)
        configure_fisheye(data, camera)
        data.clip_start = 0.01
        ob = bpy.data.objects.new(name, data)
        ob.parent = rig
        ob.matrix_basis = Matrix.Translation(Vector(pos)) @ _lens_rotation(camera)
        scene.collection.objects.link(ob)
        cams.append(ob)
    scene.camera = cams[0]
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = camera.width, camera.height, 100
    r.use_border = False
    r.use_multiview = bool(stereo)
    if stereo:
        r.views_format = "MULTIVIEW"
        for v in r.views:
            v.use = v.name in ("left", "right")
        r.views["left"].camera_suffix, r.views["right"].camera_suffix = "_L", "_R"
        r.image_settings.views_format = "INDIVIDUAL"
    return rig


AUDIENCE_DISTANCE = 2.5
"""The audience sits this many globe radii (with haze) from the centre: the globe
spans about 47 deg of the dome, centred on the lens axis."""


def scene_globe(scene):
    """``(centre, radius)`` of the scene's Nephele globe (radius with its haze glow), or None."""
    from . import globe_ops

    for ob in scene.objects:
        if "nephele_globe" in ob:
            return Vector(ob.matrix_world.translation), globe_ops.frame_radius(scene) * max(ob.matrix_world.to_scale())
    return None


def audience_placement(camera, scene, *, distance=AUDIENCE_DISTANCE):
    """``(location, rotation_euler)`` of a rig that sees the scene's globe centred on its
    lens axis from ``distance`` globe radii, or None when the scene has no globe.

    The audience looks from where the scene's camera does (the artist's chosen
    view), else from the sun's side (the lit face), else from below; the rig is
    turned so its lens axis points at the globe's centre.
    """
    found = scene_globe(scene)
    if found is None:
        return None
    centre, radius = found
    axis = Vector(tuple(camera.basis[2])).normalized()
    cam = scene.camera
    sun = next((ob for ob in scene.objects if ob.type == "LIGHT" and ob.data.type == "SUN"), None)
    if cam is not None and frame.params(cam.parent or cam).get("kind") != "dome" \
            and (cam.matrix_world.translation - centre).length > radius:
        side = (cam.matrix_world.translation - centre).normalized()
    elif sun is not None:
        side = (sun.matrix_world.to_3x3() @ Vector((0.0, 0.0, 1.0))).normalized()
    else:
        side = -axis
    turn = axis.rotation_difference(-side)
    return tuple(centre + distance * radius * side), tuple(turn.to_euler())


def dome_rig(scene=None):
    """The scene's dome rig (the parent of the scene camera, else any rig), or None."""
    scene = scene or bpy.context.scene
    cam = scene.camera
    for ob in ([cam.parent] if cam is not None and cam.parent is not None else []) + list(scene.objects):
        if ob is not None and frame.params(ob).get("kind") == "dome":
            return ob
    return None


def engine_warning(scene=None):
    """A warning when the scene camera is panoramic and the engine is EEVEE (else None)."""
    scene = scene or bpy.context.scene
    cam = scene.camera
    if scene.render.engine in EEVEE_ENGINES and cam is not None and cam.type == "CAMERA" and cam.data.type == "PANO":
        return (
            f"EEVEE renders the panoramic camera '{cam.name}' as a plain perspective view: "
            "render dome frames with Cycles, or with EEVEE through the cube-map route "
            "(Nephele > Dome > Render dome frame (EEVEE), or nephele.addon.dome_ops.render_dome_eevee)"
        )
    return None


@persistent
def _warn_before_render(scene, depsgraph=None):
    msg = engine_warning(scene)
    if msg:
        print(f"Nephele warning: {msg}")


def install():
    """Add the render_pre warning once (idempotent); called by the add-on's ``register()``."""
    handlers = bpy.app.handlers.render_pre
    if not any(getattr(h, "__name__", "") == _warn_before_render.__name__ for h in handlers):
        handlers.append(_warn_before_render)


def uninstall():
    """Remove the render_pre warning; called by the add-on's ``unregister()``."""
    handlers = bpy.app.handlers.render_pre
    for h in [h for h in handlers if getattr(h, "__name__", "") == _warn_before_render.__name__]:
        handlers.remove(h)


# --- the EEVEE route: six cube faces, remapped ---------------------------------------------------


def default_face_size(camera):
    """Cube face size matching the dome frame's angular resolution at the lens centre."""
    px_per_rad = camera.radius / (math.radians(camera.fov) / 2.0)
    return max(8, int(math.ceil(px_per_rad * math.pi / 2.0)))


def _face_matrix(name):
    f, u = (Vector(v) for v in core_dome.CUBE_AXES[name])
    r = f.cross(u)
    return Matrix([[r[i], u[i], -f[i]] for i in range(3)]).to_4x4()


def render_cube_faces(scene, eye_matrix, face_size, workdir):
    """Render the six 90 deg faces seen from ``eye_matrix`` (the theatre frame at one eye).

    Returns a (6, n, n, 4) float32 array in :data:`nephele.core.camera.dome.CUBE_FACES` order.
    """
    r = scene.render
    saved = (scene.camera, r.resolution_x, r.resolution_y, r.resolution_percentage, r.use_multiview, r.filepath,
             r.image_settings.file_format, r.image_settings.color_mode, r.pixel_aspect_x, r.pixel_aspect_y)
    data = bpy.data.cameras.new("NepheleCubeFace")
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.angle = math.pi / 2.0
    data.shift_x = data.shift_y = 0.0
    if scene.camera is not None and scene.camera.type == "CAMERA":
        data.clip_start, data.clip_end = scene.camera.data.clip_start, scene.camera.data.clip_end
    ob = bpy.data.objects.new("NepheleCubeFace", data)
    scene.collection.objects.link(ob)
    faces = []
    try:
        scene.camera = ob
        r.resolution_x = r.resolution_y = face_size
        r.resolution_percentage = 100
        r.pixel_aspect_x = r.pixel_aspect_y = 1.0
        r.use_multiview = False
        r.image_settings.file_format = "PNG"
        r.image_settings.color_mode = "RGBA"
        for name in core_dome.CUBE_FACES:
            ob.matrix_world = eye_matrix @ _face_matrix(name)
            r.filepath = str(Path(workdir) / f"face_{name}.png")
            bpy.ops.render.render(write_still=True)
            faces.append(read_image(r.filepath))
    finally:
        (scene.camera, r.resolution_x, r.resolution_y, r.resolution_percentage, r.use_multiview, r.filepath,
         r.image_settings.file_format, r.image_settings.color_mode, r.pixel_aspect_x, r.pixel_aspect_y) = saved
        bpy.data.objects.remove(ob, do_unlink=True)
        bpy.data.cameras.remove(data)
    return np.stack(faces)


def render_dome_eevee(filepath, *, scene=None, face_size=None, supersample=None, keep_faces=None):
    """Render the dome rig's frame(s) with the scene's engine through six cube faces per eye.

    Works for any engine (it is the way to get a dome frame from EEVEE).
    Stereo rigs give ``<stem>_L<ext>`` and ``<stem>_R<ext>``, like Blender's
    multi-view output.

    Parameters
    ----------
    filepath : str or Path
        Output image (PNG).
    face_size : int, optional
        Cube face size in pixels (default: the rig's, else matching the dome
        frame's resolution, :func:`default_face_size`).
    supersample : int, optional
        Directions per pixel along each axis for the remap (default: the rig's, 2).
    keep_faces : str or Path, optional
        A folder to keep the rendered faces in (``face_<name>.png`` per eye folder).

    Returns
    -------
    list of Path : the frames written.
    """
    scene = scene or bpy.context.scene
    rig = dome_rig(scene)
    if rig is None:
        raise DataError("no dome camera in the scene: add one first (Add dome camera)", field="camera")
    p = frame.params(rig)
    camera = dome_from_params(p)
    n = int(face_size or p.get("face_size") or default_face_size(camera))
    ss = int(supersample or p.get("supersample") or 2)
    from ..core.memory import check_memory
    from ..core.pipeline.cache import Cache

    # The remap table (a face index and two coordinates, float64, per supersample) and the
    # six RGBA float faces, before they are allocated.
    check_memory(camera.width * camera.height * ss * ss * 24 + 6 * n * n * 16 * 2,
                 f"the cube-map dome frame {camera.width}x{camera.height} (cube face {n}, supersample {ss})",
                 field="width")
    table = core_dome.stored_remap_table(camera, "cube", n, ss, Cache(frame.results_dir()))
    filepath = Path(filepath)
    eyes = core_dome.stereo_eyes(p["separation"]) if p.get("stereo") else {"": np.zeros(3)}
    written = []
    for suffix, pos in eyes.items():
        eye = rig.matrix_world @ Matrix.Translation(Vector(pos))
        with tempfile.TemporaryDirectory(prefix="nephele_cube_") as tmp:
            workdir = Path(keep_faces) / (suffix or "mono") if keep_faces else Path(tmp)
            workdir.mkdir(parents=True, exist_ok=True)
            faces = render_cube_faces(scene, eye, n, workdir)
        out = filepath.with_name(f"{filepath.stem}_{suffix}{filepath.suffix}") if suffix else filepath
        written.append(write_image(out, table.apply(faces)))
    return written


def render_dome_frame(filepath, *, scene=None):
    """Render the current frame of a scene with a dome rig, whatever the engine; returns the paths.

    Cycles (and any engine with panoramic cameras) renders the fisheye frame
    directly; EEVEE goes through :func:`render_dome_eevee`.  Stereo rigs
    write ``<stem>_L`` and ``<stem>_R`` either way.  For the farm: call this
    instead of ``bpy.ops.render.render`` when :func:`dome_rig` finds a rig.
    """
    scene = scene or bpy.context.scene
    filepath = Path(filepath)
    if scene.render.engine in EEVEE_ENGINES:
        return render_dome_eevee(filepath, scene=scene)
    if dome_rig(scene) is None:
        raise DataError("no dome camera in the scene: add one first (Add dome camera)", field="camera")
    saved = scene.render.filepath
    try:
        scene.render.filepath = str(filepath)
        bpy.ops.render.render(write_still=True)
    finally:
        scene.render.filepath = saved
    if scene.render.use_multiview:
        return [filepath.with_name(f"{filepath.stem}_{s}{filepath.suffix}") for s in "LR"]
    return [filepath]


# --- UI -----------------------------------------------------------------------------------------

_PRESET_ITEMS = [
    ("omnimax", "Omnimax", "15-perf 70 mm frame, 2048x1500, lens centre below the frame centre, tilted dome"),
    ("domemaster", "Domemaster", "Square 180 deg fisheye, zenith at the centre, front at the bottom"),
]
_LENS_ITEMS = [
    ("equidistant", "Equidistant (f-theta)", "Radius proportional to the angle from the lens axis"),
    ("equisolid", "Equisolid", "Radius proportional to sin(angle / 2)"),
]


def _preset_changed(self, context):
    d = core_dome.PRESET_DEFAULTS[self.preset]
    self.width, self.height, self.tilt, self.fov = d["width"], d["height"], d["tilt"], d["fov"]


class NepheleDomeSettings(bpy.types.PropertyGroup):
    preset: bpy.props.EnumProperty(name="Preset", items=_PRESET_ITEMS, update=_preset_changed)
    tilt: bpy.props.FloatProperty(name="Dome tilt", default=25.0, min=-90.0, max=90.0, soft_min=0.0, soft_max=45.0,
                                  description="Degrees the dome's zenith is tipped forward from vertical")
    fov: bpy.props.FloatProperty(name="Field of view", default=180.0, min=1.0, max=360.0, soft_min=90.0,
                                 description="Degrees across the frame width (the fisheye circle's diameter)")
    width: bpy.props.IntProperty(name="Width", default=2048, min=8, max=16384, soft_min=16)
    height: bpy.props.IntProperty(name="Height", default=1500, min=8, max=16384, soft_min=16)
    lens: bpy.props.EnumProperty(name="Lens", items=_LENS_ITEMS)
    stereo: bpy.props.BoolProperty(name="Stereo", default=False,
                                   description="Left/right cameras on a fixed horizontal baseline (_L/_R frames)")
    separation: bpy.props.FloatProperty(name="Eye separation", default=0.065, min=0.0, max=100.0, soft_max=1.0,
                                        unit="LENGTH")
    face_size: bpy.props.IntProperty(name="Cube face", default=0, min=0, max=8192,
                                     description="EEVEE route: cube face size in pixels (0: match the dome frame)")


class NEPHELE_OT_add_dome_camera(bpy.types.Operator):
    """Add a dome camera rig whose Cycles render is the final frame (unset values: the preset's)"""

    bl_idname = "nephele.add_dome_camera"
    bl_label = "Add dome camera"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=_PRESET_ITEMS)
    # No hard limits here: out-of-range values reach core.camera.dome, which refuses them by name
    # (a clamp would silently render something else).
    tilt: bpy.props.FloatProperty(name="Dome tilt", default=25.0)
    fov: bpy.props.FloatProperty(name="Field of view", default=180.0)
    width: bpy.props.IntProperty(name="Width", default=2048)
    height: bpy.props.IntProperty(name="Height", default=1500)
    lens: bpy.props.EnumProperty(name="Lens", items=_LENS_ITEMS)
    stereo: bpy.props.BoolProperty(name="Stereo", default=False)
    separation: bpy.props.FloatProperty(name="Eye separation", default=0.065, unit="LENGTH")

    def invoke(self, context, event):
        s = context.scene.nephele_dome
        for k in ("preset", "tilt", "fov", "width", "height", "lens", "stereo", "separation"):
            setattr(self, k, getattr(s, k))
        return self.execute(context)

    def execute(self, context):
        # Values not given (a script calling the operator) come from the preset.
        given = {k: getattr(self, k) for k in ("tilt", "fov", "width", "height") if self.properties.is_property_set(k)}
        # The audience's eye: the 3D cursor, unless it lies inside the globe (its
        # centre, where the cursor starts): then outside, looking at it.
        cursor = context.scene.cursor.location
        found = scene_globe(context.scene)
        inside = found is not None and (cursor - found[0]).length <= found[1]
        try:
            rig = add_dome_camera(
                self.preset, lens=self.lens, stereo=self.stereo, separation=self.separation,
                location=None if inside else tuple(cursor), scene=context.scene, **given,
            )
        except DataError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        fs = context.scene.nephele_dome.face_size if hasattr(context.scene, "nephele_dome") else 0
        if fs:
            p = frame.params(rig)
            p["face_size"] = fs
            frame.set_params(rig, p)
        msg = engine_warning(context.scene)
        if msg:
            self.report({"WARNING"}, msg)
        select_only(context, rig)
        return {"FINISHED"}


class NEPHELE_OT_render_dome_eevee(bpy.types.Operator):
    """Render the dome frame through six cube faces (the way to get dome output from EEVEE)"""

    bl_idname = "nephele.render_dome_cube"
    bl_label = "Render dome frame (cube map)"

    filepath: bpy.props.StringProperty(name="Output", subtype="FILE_PATH", default="//dome.png")

    def execute(self, context):
        try:
            paths = render_dome_eevee(bpy.path.abspath(self.filepath), scene=context.scene)
        except DataError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, "Wrote " + ", ".join(str(p) for p in paths))
        return {"FINISHED"}


class NEPHELE_PT_dome(SubPanel, bpy.types.Panel):
    bl_label = "Dome"
    bl_idname = "NEPHELE_PT_dome"

    def draw(self, context):
        s = context.scene.nephele_dome
        col = self.layout.column()
        for k in ("preset", "lens", "tilt", "fov", "width", "height", "stereo"):
            col.prop(s, k)
        sub = col.column()
        sub.enabled = s.stereo
        sub.prop(s, "separation")
        col.operator(NEPHELE_OT_add_dome_camera.bl_idname, icon="CAMERA_DATA")
        col.separator()
        col.prop(s, "face_size")
        col.operator(NEPHELE_OT_render_dome_eevee.bl_idname, icon="RENDER_STILL")
        msg = engine_warning(context.scene)
        if msg:
            box = col.box()
            box.label(text="EEVEE renders panoramic cameras flat:", icon="ERROR")
            box.label(text="use Cycles or the cube-map render")


CLASSES = (NepheleDomeSettings, NEPHELE_OT_add_dome_camera, NEPHELE_OT_render_dome_eevee, NEPHELE_PT_dome)
SCENE_PROPERTIES = {"nephele_dome": NepheleDomeSettings}
