"""The globe under the clouds: real relief, land/sea colours, sky, sun and blue haze.

The globe and every layer over it (contours, volumes, textures) use the same
``radius`` and vertical ``exaggeration`` — both default to the scene's
Nephele settings (:func:`nephele.addon.data_ops.settings`), which default to
radius 1 and :data:`nephele.core.climate.grid.DEFAULT_EXAGGERATION`.  The haze is
the paper's "blue atmospheric haze, decreasing exponentially with altitude":
a volume shell whose extinction is ``d0 * exp(-(r - R) / H)``.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import math
from pathlib import Path

import bpy
import numpy as np

from ..core.climate import relief as core_relief
from ..core.climate.grid import EARTH_RADIUS, globe_radius, lonlat_to_xyz
from . import data_ops, materials
from .camera import camera_object, look_at
from .mesh import fill_mesh, select_only
from .nodes import Nodes
from .panel import SubPanel

GLOBE_NAME = "Nephele Globe"
HAZE_NAME = "Nephele Haze"
SUN_NAME = "Nephele Sun"

TERRAIN_RANGE = (-8000.0, 6000.0)
"""Heights (m) mapped to the ends of the terrain colour ramp."""


def _pos(h):
    return (h - TERRAIN_RANGE[0]) / (TERRAIN_RANGE[1] - TERRAIN_RANGE[0])


TERRAIN_RAMP = [
    (_pos(-7000.0), (0.004, 0.012, 0.06)),
    (_pos(-3500.0), (0.008, 0.04, 0.16)),
    (_pos(-200.0), (0.02, 0.12, 0.30)),
    (_pos(-1.0), (0.05, 0.22, 0.38)),
    (_pos(0.0), (0.10, 0.22, 0.06)),
    (_pos(400.0), (0.20, 0.30, 0.08)),
    (_pos(1200.0), (0.38, 0.33, 0.16)),
    (_pos(2500.0), (0.30, 0.20, 0.12)),
    (_pos(4500.0), (0.55, 0.52, 0.50)),
    (1.0, (0.90, 0.90, 0.92)),
]
"""Ocean blues darkening with depth, then land greens, browns and rock/snow (linear RGB)."""


def load_relief(relief=None):
    """Surface height of the Earth on a longitude × latitude grid.

    Parameters
    ----------
    relief : None, "flat", str/Path, or tuple
        None: the relief shipped with Nephele (:mod:`nephele.core.climate.relief`,
        1° ETOPO-derived).  ``"flat"``: a smooth sea-level sphere.  A path:
        an ETOPO ``.cdf`` file (e.g. ``etopo60.cdf``, read by
        :func:`nephele.core.climate.relief.load_etopo`).  A tuple ``(lon (ni,), lat (nj,), height (nj, ni))``.

    Returns
    -------
    lon, lat, height : ndarray
        Longitudes ascending in [-180, 180), latitudes ascending, heights (m).
    """
    if isinstance(relief, str) and relief == "flat":
        lon = np.arange(-179.0, 180.0, 2.0)
        lat = np.arange(-89.0, 90.0, 2.0)
        return lon, lat, np.zeros((lat.size, lon.size))
    if relief is None:
        lon, lat, height = core_relief.load_relief()
    elif isinstance(relief, (str, Path)):
        lon, lat, height = core_relief.load_etopo(relief)
    else:
        lon, lat, height = relief
    lon = np.asarray(lon, dtype=np.float64)
    lat = np.asarray(lat, dtype=np.float64)
    height = np.asarray(height, dtype=np.float64)
    if height.shape != (lat.size, lon.size):
        raise ValueError(f"relief of shape {height.shape} does not match (lat={lat.size}, lon={lon.size})")
    # Longitudes into [-180, 180), ascending; latitudes ascending.
    lon = (lon + 180.0) % 360.0 - 180.0
    order = np.argsort(lon, kind="stable")
    lon, height = lon[order], height[:, order]
    if lat[0] > lat[-1]:
        lat, height = lat[::-1], height[::-1]
    return lon, lat, np.nan_to_num(height, nan=0.0)


def sphere_arrays(lon, lat, radii):
    """A closed triangulated sphere through a lon × lat grid of points, plus the two poles.

    Parameters
    ----------
    lon : (ni,) degrees, lat : (nj,) degrees strictly inside (-90, 90), ascending
    radii : (nj, ni) distance of each grid point from the centre; the poles get
        the mean radius of the nearest row.

    Returns
    -------
    vertices (nj*ni + 2, 3) float32, faces (m, 3) int32 (outward winding),
    lonlat (nj*ni + 2, 2) float32.
    """
    ni, nj = lon.size, lat.size
    radii = np.asarray(radii, dtype=np.float64)
    pts = lonlat_to_xyz(lon[None, :], lat[:, None], radii).reshape(-1, 3)
    south = np.array([[0.0, 0.0, -radii[0].mean()]])
    north = np.array([[0.0, 0.0, radii[-1].mean()]])
    vertices = np.concatenate([pts, south, north]).astype(np.float32)
    idx = np.arange(nj * ni).reshape(nj, ni)
    a = idx[:-1, :]
    b = np.roll(idx[:-1, :], -1, axis=1)
    c = np.roll(idx[1:, :], -1, axis=1)
    d = idx[1:, :]
    # Counter-clockwise seen from outside: east is +lon, north is +lat.
    quads = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    s, n = nj * ni, nj * ni + 1
    row0, row1 = idx[0], idx[-1]
    south_fan = np.stack([np.full(ni, s), np.roll(row0, -1), row0], -1)
    north_fan = np.stack([np.full(ni, n), row1, np.roll(row1, -1)], -1)
    faces = np.concatenate(quads + [south_fan, north_fan]).astype(np.int32)
    lonlat = np.concatenate([
        np.stack(np.broadcast_arrays(lon[None, :], lat[:, None]), -1).reshape(-1, 2),
        [[0.0, -90.0], [0.0, 90.0]],
    ]).astype(np.float32)
    return vertices, faces, lonlat


def globe_arrays(lon, lat, height, radius=1.0, exaggeration=None):
    """Vertices, faces and attributes of the relief globe (oceans flat at sea level)."""
    exaggeration = data_ops.DEFAULTS["exaggeration"] if exaggeration is None else exaggeration
    radii = globe_radius(np.maximum(height, 0.0), radius, exaggeration)
    vertices, faces, lonlat = sphere_arrays(lon, lat, radii)
    h = np.concatenate([height.ravel(), [height[0].mean(), height[-1].mean()]]).astype(np.float32)
    return vertices, faces, {"height": h, "latitude": lonlat[:, 1].copy()}


def terrain_material(name="Nephele Terrain"):
    """Land/sea colours from the ``height`` attribute; land ice poleward of ~65°."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    materials.enable_nodes(mat)
    tree = mat.node_tree
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (500, 0)
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (200, 0)
    ramp = materials.attribute_ramp_nodes(tree, "height", *TERRAIN_RANGE, TERRAIN_RAMP, location=(-1000, 200))
    # Land above sea level and poleward of 62..72 degrees turns to ice.
    height = nodes["Nephele attribute"]
    land = nodes.new("ShaderNodeMath")
    land.operation = "GREATER_THAN"
    land.inputs[1].default_value = 0.0
    links.new(height.outputs["Fac"], land.inputs[0])
    lat = nodes.new("ShaderNodeAttribute")
    lat.attribute_name = "latitude"
    lat.location = (-1000, -200)
    absl = nodes.new("ShaderNodeMath")
    absl.operation = "ABSOLUTE"
    links.new(lat.outputs["Fac"], absl.inputs[0])
    polar = nodes.new("ShaderNodeMapRange")
    polar.inputs["From Min"].default_value = 62.0
    polar.inputs["From Max"].default_value = 72.0
    links.new(absl.outputs["Value"], polar.inputs["Value"])
    ice = nodes.new("ShaderNodeMath")
    ice.operation = "MULTIPLY"
    links.new(land.outputs["Value"], ice.inputs[0])
    links.new(polar.outputs["Result"], ice.inputs[1])
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.location = (-100, 100)
    links.new(ice.outputs["Value"], mix.inputs["Factor"])
    links.new(ramp.outputs["Color"], mix.inputs["A"])
    mix.inputs["B"].default_value = (0.85, 0.88, 0.92, 1.0)
    links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    # Water is glossier than land.
    rough = nodes.new("ShaderNodeMapRange")
    rough.inputs["To Min"].default_value = 0.7
    rough.inputs["To Max"].default_value = 0.9
    links.new(land.outputs["Value"], rough.inputs["Value"])
    links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _link(obj, scene, collection):
    coll = collection or scene.collection
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    return obj


def _object(name, data, scene, collection):
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(name, data)
    elif obj.data is not data:
        obj.data = data
    return _link(obj, scene, collection)


def add_globe(relief=None, exaggeration=None, radius=None, *, scene=None, collection=None, name=GLOBE_NAME):
    """Add (or rebuild) the relief globe, coloured land/sea, centred at the origin.

    Parameters
    ----------
    relief : see :func:`load_relief`
    exaggeration, radius : float, optional
        Vertical exaggeration and sea-level radius; default: the scene's
        Nephele settings (the same values every layer uses).
    scene : bpy.types.Scene, optional
        Default: the current scene.
    collection : bpy.types.Collection, optional
        Default: the scene's master collection.

    Returns
    -------
    bpy.types.Object
        A mesh object with point attributes ``height`` (m, negative under the
        sea) and ``latitude`` (degrees); its ``["nephele_globe"]`` records the
        radius and exaggeration used.
    """
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    exaggeration = cfg["exaggeration"] if exaggeration is None else float(exaggeration)
    radius = cfg["radius"] if radius is None else float(radius)
    if not (radius > 0 and exaggeration >= 0):
        raise ValueError(f"globe needs radius > 0 and exaggeration >= 0, got {radius}, {exaggeration}")
    lon, lat, height = load_relief(relief)
    arrays = globe_arrays(lon, lat, height, radius, exaggeration)
    me = bpy.data.meshes.get(name)
    me = fill_mesh(me or bpy.data.meshes.new(name), arrays)
    obj = _object(name, me, scene, collection)
    materials.assign(obj, terrain_material())
    obj["nephele_globe"] = {"radius": radius, "exaggeration": exaggeration}
    return obj


def haze_material(radius, exaggeration, *, density=None, scale_height=8000.0, color=(0.25, 0.5, 1.0),
                  name="Nephele Haze"):
    """Volume material: extinction ``density * color * exp(-(r - R) / H)``, ``r`` = |object coordinates|.

    ``density`` (per scene unit) defaults to a vertical optical depth of
    0.08 at the ``color`` channel of weight 1: ``0.08 / H_scene`` with
    ``H_scene = radius * exaggeration * scale_height / EARTH_RADIUS``, so the
    haze thickens toward the limb as it does seen from orbit.
    """
    h_scene = radius * max(exaggeration, 1e-6) * scale_height / EARTH_RADIUS
    density = 0.08 / h_scene if density is None else float(density)
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    materials.enable_nodes(mat)
    tree = mat.node_tree
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (600, 0)
    coords = nodes.new("ShaderNodeTexCoord")
    coords.location = (-800, 0)
    n = Nodes(tree)
    r = n.vmath("LENGTH", coords.outputs["Object"])
    # exp(-(r - R) / H) = exp((R - r) / H)
    dens = n.math("MULTIPLY", n.math("EXPONENT", n.math("DIVIDE", n.math("SUBTRACT", radius, r), h_scene)), density)
    scatter = nodes.new("ShaderNodeVolumeScatter")
    scatter.location = (300, 0)
    scatter.inputs["Color"].default_value = tuple(color) + (1.0,)
    scatter.inputs["Anisotropy"].default_value = 0.0
    links.new(dens, scatter.inputs["Density"])
    links.new(scatter.outputs["Volume"], out.inputs["Volume"])
    mat.cycles.volume_sampling = "DISTANCE"
    mat["nephele_haze"] = {"radius": radius, "scale_height_scene": h_scene, "density": density}
    return mat


def shell_haze_material(radius, exaggeration, sun_direction, *, density=None, scale_height=8000.0,
                        color=(0.25, 0.5, 1.0), brightness=0.9, name="Nephele Haze (shell)"):
    """Cheap haze: a transparent shell that applies the paper's fog blend in one surface hit.

    For a camera ray entering the shell at ``P`` with direction ``D``, the
    optical depth of an exponential atmosphere ``d0 exp(-(r - R)/H)`` is taken
    in closed form: a ray passing the globe at closest distance ``b > R``
    crosses ``d0 exp(-(b - R)/H) sqrt(2 pi b H)`` (Laplace's method on the
    whole chord); a ray reaching the ground at zenith-angle cosine ``mu``
    crosses ``d0 H / sqrt(mu^2 + 2H/(pi R))`` (a Chapman-function fit; against
    numerical quadrature for the default globe: within 1.5% at the zenith
    and past the limb, up to 19% high for rays grazing the ground).  Each channel is attenuated by
    ``T = exp(-tau * color)`` and the haze adds ``brightness * color * (1 - T)``
    where the sun is up.  Only camera rays entering from outside see it; the
    optical depth runs to the ground, so clouds get slightly more haze than
    the volume of :func:`haze_material` would give them.
    """
    h_scene = radius * max(exaggeration, 1e-6) * scale_height / EARTH_RADIUS
    density = 0.08 / h_scene if density is None else float(density)
    sun = np.asarray(sun_direction, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    tree = materials.enable_nodes(mat)
    tree.nodes.clear()
    n = Nodes(tree)
    geo = tree.nodes.new("ShaderNodeNewGeometry")
    path = tree.nodes.new("ShaderNodeLightPath")
    P, D = geo.outputs["Position"], n.vmath("SCALE", geo.outputs["Incoming"])
    D.node.inputs["Scale"].default_value = -1.0
    pd = n.vmath("DOT_PRODUCT", P, D)
    pp = n.vmath("DOT_PRODUCT", P, P)
    b = n.math("SQRT", n.math("MAXIMUM", n.math("SUBTRACT", pp, n.math("MULTIPLY", pd, pd)), 0.0))
    # Ray past the globe: the whole chord.
    tau_pass = n.math("MULTIPLY", n.math("EXPONENT", n.math("DIVIDE", n.math("SUBTRACT", radius, b), h_scene)),
                      n.math("MULTIPLY", n.math("SQRT", n.math("MULTIPLY", b, 2 * np.pi * h_scene)), density))
    # Ray to the ground: mu from the impact parameter.
    mu2 = n.math("MAXIMUM", n.math("SUBTRACT", 1.0, n.math("DIVIDE", n.math("MULTIPLY", b, b), radius * radius)), 0.0)
    tau_ground = n.math("DIVIDE", density * h_scene, n.math("SQRT", n.math("ADD", mu2, 2 * h_scene / (np.pi * radius))))
    hits = n.math("LESS_THAN", b, radius)
    tau = n.math("ADD", n.math("MULTIPLY", hits, tau_ground),
                 n.math("MULTIPLY", n.math("SUBTRACT", 1.0, hits), tau_pass))
    # Only camera rays entering from outside.
    seen = n.math("MULTIPLY", path.outputs["Is Camera Ray"], n.math("SUBTRACT", 1.0, geo.outputs["Backfacing"]))
    tau = n.math("MULTIPLY", tau, seen)
    # Daylight where the ray meets the ground (or passes closest): P + D * s.
    s_close = n.math("MULTIPLY", pd, -1.0)
    s_ground = n.math("SUBTRACT", s_close, n.math("SQRT", n.math("MULTIPLY", mu2, radius * radius)))
    s = n.math("ADD", n.math("MULTIPLY", hits, s_ground), n.math("MULTIPLY", n.math("SUBTRACT", 1.0, hits), s_close))
    scaled = n.vmath("SCALE", D)
    tree.links.new(s, scaled.node.inputs["Scale"])
    where = n.vmath("NORMALIZE", n.vmath("ADD", P, scaled))
    cos_sun = n.vmath("DOT_PRODUCT", where, tuple(sun))
    day = n.math("SMOOTH_MIN", 1.0, n.math("MAXIMUM", n.math("DIVIDE", n.math("ADD", cos_sun, 0.15), 0.4), 0.0), 0.1)
    trans = tree.nodes.new("ShaderNodeCombineColor")
    glow = tree.nodes.new("ShaderNodeCombineColor")
    for ch, c in zip(("Red", "Green", "Blue"), color):
        t = n.math("EXPONENT", n.math("MULTIPLY", tau, -float(c)))
        tree.links.new(t, trans.inputs[ch])
        tree.links.new(n.math("MULTIPLY", n.math("SUBTRACT", 1.0, t), n.math("MULTIPLY", day, brightness * c)),
                       glow.inputs[ch])
    transparent = tree.nodes.new("ShaderNodeBsdfTransparent")
    tree.links.new(trans.outputs["Color"], transparent.inputs["Color"])
    emission = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(glow.outputs["Color"], emission.inputs["Color"])
    emission.inputs["Strength"].default_value = 1.0
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(transparent.outputs[0], add.inputs[0])
    tree.links.new(emission.outputs[0], add.inputs[1])
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(add.outputs[0], out.inputs["Surface"])
    mat["nephele_haze"] = {"radius": radius, "scale_height_scene": h_scene, "density": density, "mode": "shell"}
    return mat


def add_sky_and_haze(scene=None, *, radius=None, exaggeration=None, haze=True, haze_mode="volume", haze_density=None,
                     scale_height=8000.0, haze_top=60000.0, sun_direction=(1.0, -0.35, 0.45),
                     sun_strength=4.0, background=(0.0015, 0.002, 0.004), collection=None):
    """Dark space behind the globe, a sun lamp and the blue haze shell.

    Parameters
    ----------
    scene : bpy.types.Scene, optional
    radius, exaggeration : float, optional
        Default: the scene's Nephele settings (must match the globe's).
    haze : bool
        Add the haze shell.
    haze_mode : {"volume", "shell"}
        ``"volume"``: a volume shader integrated by Cycles (about 3x the
        render time of the scene without haze); ``"shell"``: the same
        exponential atmosphere in closed form on a transparent surface
        (:func:`shell_haze_material`, nearly free).
    haze_density : float, optional
        Extinction at sea level per scene unit (see :func:`haze_material`).
    scale_height : float
        Height (m) over which the haze thins by a factor e.
    haze_top : float
        Height (m) of the shell's outer surface (the haze is cut there).
    sun_direction : 3-vector
        Direction *toward* the sun, world space.
    sun_strength : float
        Sun irradiance (W/m²).
    background : RGB
        World colour (near-black space).

    Returns
    -------
    dict with ``"world"``, ``"sun"`` and ``"haze"`` (None when ``haze`` is False).
    """
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    exaggeration = cfg["exaggeration"] if exaggeration is None else float(exaggeration)
    radius = cfg["radius"] if radius is None else float(radius)
    world = scene.world or bpy.data.worlds.new("Nephele World")
    scene.world = world
    materials.enable_nodes(world)
    bg = world.node_tree.nodes.get("Background") or world.node_tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = tuple(background) + (1.0,)
    bg.inputs["Strength"].default_value = 1.0
    wout = next((n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"), None)
    if wout is None:
        wout = world.node_tree.nodes.new("ShaderNodeOutputWorld")
    world.node_tree.links.new(bg.outputs["Background"], wout.inputs["Surface"])

    sun_data = bpy.data.lights.get(SUN_NAME) or bpy.data.lights.new(SUN_NAME, "SUN")
    sun_data.energy = sun_strength
    sun_data.angle = math.radians(0.53)
    sun = bpy.data.objects.get(SUN_NAME) or bpy.data.objects.new(SUN_NAME, sun_data)
    _link(sun, scene, collection)
    d = np.asarray(sun_direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    # A sun lamp shines along its local -Z: point local +Z toward the sun.
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = _z_to(d)

    haze_obj = None
    if not haze and bpy.data.objects.get(HAZE_NAME) is not None:
        bpy.data.objects[HAZE_NAME].hide_render = True  # an earlier call's haze: off
    if haze:
        top = float(globe_radius(haze_top, radius, exaggeration))
        lon = np.arange(-178.5, 180.0, 3.0)
        lat = np.arange(-88.5, 90.0, 3.0)
        v, f, _ = sphere_arrays(lon, lat, np.full((lat.size, lon.size), top))
        me = bpy.data.meshes.get(HAZE_NAME) or bpy.data.meshes.new(HAZE_NAME)
        fill_mesh(me, (v, f))
        haze_obj = _object(HAZE_NAME, me, scene, collection)
        haze_obj.location = (0.0, 0.0, 0.0)
        haze_obj.scale = (1.0, 1.0, 1.0)
        haze_obj.hide_render = False
        if haze_mode == "volume":
            mat = haze_material(radius, exaggeration, density=haze_density, scale_height=scale_height)
        elif haze_mode == "shell":
            mat = shell_haze_material(radius, exaggeration, d, density=haze_density, scale_height=scale_height)
        else:
            raise ValueError(f"haze_mode must be 'volume' or 'shell', got {haze_mode!r}")
        materials.assign(haze_obj, mat)
        # Seen by camera rays only: shadow and bounce rays through the shell
        # would triple the render time for a barely visible difference.
        for attr in ("visible_shadow", "visible_diffuse", "visible_glossy", "visible_transmission",
                     "visible_volume_scatter"):
            setattr(haze_obj, attr, False)
    return {"world": world, "sun": sun, "haze": haze_obj}


def _z_to(d):
    """Quaternion (w, x, y, z) rotating +Z onto unit vector ``d``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s = np.linalg.norm(axis)
    c = float(np.dot(z, d))
    if s < 1e-12:
        return (1.0, 0.0, 0.0, 0.0) if c > 0 else (0.0, 1.0, 0.0, 0.0)
    axis /= s
    ang = math.atan2(s, c)
    return (math.cos(ang / 2), *(axis * math.sin(ang / 2)))


FRAME_HEIGHT = 25000.0
"""Metres above sea level the default camera keeps in view all round the globe:
the highest relief and three scale heights of the haze, whose glow marks the limb."""


def frame_radius(scene=None):
    """Scene units from the centre that the whole globe, with its haze glow, fills."""
    cfg = data_ops.settings(scene or bpy.context.scene)
    return float(globe_radius(FRAME_HEIGHT, cfg["radius"], cfg["exaggeration"]))


def framing_distance(scene, lens, sensor=36.0, margin=1.08, radius=None):
    """Distance from the centre at which a ``lens`` mm camera (sensor fit AUTO on a
    ``sensor`` mm sensor) sees the sphere of ``radius`` (default :func:`frame_radius`)
    whole in the scene's frame, with ``margin`` room around it.

    The narrower side of the frame limits: half-angle ``atan(sensor/2 * short/long / lens)``;
    a sphere of radius ``r`` seen from ``d`` spans ``asin(r / d)``.
    """
    r = frame_radius(scene) if radius is None else float(radius)
    w = scene.render.resolution_x * scene.render.pixel_aspect_x
    h = scene.render.resolution_y * scene.render.pixel_aspect_y
    half = math.atan(0.5 * sensor * min(w, h) / max(w, h) / lens)
    return margin * r / math.sin(half)


def add_camera(scene=None, *, lon=-30.0, lat=25.0, distance=None, lens=50.0, name="Nephele Camera"):
    """A camera at ``distance`` from the centre above ``lon``, ``lat``, looking at the globe.

    ``distance`` None: :func:`framing_distance`, so the whole globe is in view
    whatever the frame's aspect (3.6 at 50 mm cropped it top and bottom).
    """
    scene = scene or bpy.context.scene
    if distance is None:
        distance = framing_distance(scene, lens)
    cam = camera_object(scene, name, lens=lens, clip_end=max(100.0, 4.0 * distance))
    cam.location = tuple(lonlat_to_xyz(lon, lat, distance))
    look_at(cam)
    return cam


class NEPHELE_OT_add_globe(bpy.types.Operator):
    """Add the Earth with real relief, coloured land and sea"""

    bl_idname = "nephele.add_globe"
    bl_label = "Add globe"
    bl_options = {"REGISTER", "UNDO"}

    flat: bpy.props.BoolProperty(name="Flat (no relief)", default=False)

    def execute(self, context):
        try:
            obj = add_globe("flat" if self.flat else None, scene=context.scene)
        except (ValueError, OSError, ImportError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.polygons)} triangles")
        select_only(context, obj)
        return {"FINISHED"}


class NEPHELE_OT_add_sky(bpy.types.Operator):
    """Add dark space, a sun and blue haze that thins exponentially with altitude"""

    bl_idname = "nephele.add_sky"
    bl_label = "Add sky"
    bl_options = {"REGISTER", "UNDO"}

    haze: bpy.props.BoolProperty(name="Haze", default=True)
    sun_strength: bpy.props.FloatProperty(name="Sun strength", default=4.0, min=0.0)

    def execute(self, context):
        sun = add_sky_and_haze(context.scene, haze=self.haze, sun_strength=self.sun_strength)["sun"]
        select_only(context, sun)
        return {"FINISHED"}


class NEPHELE_OT_add_camera(bpy.types.Operator):
    """Add a camera looking at the globe"""

    bl_idname = "nephele.add_camera"
    bl_label = "Add camera"
    bl_options = {"REGISTER", "UNDO"}

    lon: bpy.props.FloatProperty(name="Longitude", default=-30.0, min=-180.0, max=180.0)
    lat: bpy.props.FloatProperty(name="Latitude", default=25.0, min=-89.0, max=89.0)
    distance: bpy.props.FloatProperty(name="Distance", default=0.0, min=0.0, max=1e4,
                                      description="From the globe's centre (0: just far enough to see it whole)")
    lens: bpy.props.FloatProperty(name="Focal length", default=50.0, min=1.0, max=5000.0, unit="CAMERA")

    def execute(self, context):
        inside = frame_radius(context.scene)
        if 0.0 < self.distance <= inside:
            self.report({"ERROR"}, f"Distance {self.distance:g} is inside the globe and its haze "
                                   f"(radius {inside:.3g}): give more, or 0 to frame the globe")
            return {"CANCELLED"}
        cam = add_camera(context.scene, lon=self.lon, lat=self.lat, distance=self.distance or None, lens=self.lens)
        select_only(context, cam)
        return {"FINISHED"}


class NEPHELE_PT_globe(SubPanel, bpy.types.Panel):
    bl_label = "Globe and sky"
    bl_idname = "NEPHELE_PT_globe"

    def draw(self, context):
        col = self.layout.column(align=True)
        col.operator(NEPHELE_OT_add_globe.bl_idname, icon="WORLD")
        col.operator(NEPHELE_OT_add_sky.bl_idname, icon="LIGHT_SUN")
        col.operator(NEPHELE_OT_add_camera.bl_idname, icon="CAMERA_DATA")


CLASSES = (NEPHELE_OT_add_globe, NEPHELE_OT_add_sky, NEPHELE_OT_add_camera, NEPHELE_PT_globe)
