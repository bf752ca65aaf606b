"""Splats with a flowing wind texture (Fig. 3): one view-facing quad per sample.

"Add wind splats" turns every sample of the scene's dataset whose opacity
(the transfer function of the cloud field) is above zero into a splat.  The
object is a mesh of points only; each point carries the splat's centre, the
rows of its inverse cell Jacobian (world offsets to unit-kernel offsets),
its opacity, colour and wind as point attributes written with
``foreach_set``.  A Geometry Nodes modifier puts a quad on every point
facing the scene's active camera, sized to the bounding box of the
ellipsoid's shadow in the view plane, and sorts the points back to front
(EEVEE blends one object's faces in their order).  The material computes
the exact ray integral of the kernel through each shading point:

``q = M (x - c)`` projected off ``m = M v``, footprint ``F(|q|) / |m|``

with ``F`` the unit kernel's radial footprint table (an image), so the
same material is right for orthographic and perspective views.  The splat's
alpha is ``1 - exp(-opacity * footprint * streak)``; the streak texture is
one of ``N`` phase-shifted maps (tiles of one image) laid along the wind
projected on the view plane, chosen per splat from the model time, so the
streaks move downwind as the frames advance.  The frame updater refills
the points for the frame's model time, as the contours do.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3.
.. [2] L. Westover, "Footprint evaluation for volume rendering", SIGGRAPH 1990.
.. [3] R. Crawfis and N. Max, "Texture splats for 3D scalar and vector field
   visualization", IEEE Visualization 1993.
"""

import zlib

import bpy
import numpy as np

from ..core.errors import DataError
from ..core.splats import default_tile, splat_kernel, splat_samples, streak_maps, streak_offsets
from ..core.surface.contour_task import frame_hours
from ..core.volume.sparse import DEFAULT_EXTINCTION
from ..core.volume.transfer import TransferFunction
from . import data_ops, frame
from .mesh import select_only, set_point_attribute
from .nodes import Nodes
from .panel import SubPanel

KIND = "splats"
GROUP_NAME = "Nephele Splats"
OBJECT_NAME = "Nephele Splats"
CENTER, M0, M1, M2, AXES = "splat_center", "splat_m0", "splat_m1", "splat_m2", "splat_axis"
OPACITY, COLOR, WIND, SPEED, PHASE = "splat_opacity", "splat_color", "splat_wind", "splat_speed", "splat_phase"
TIME_NODE = "Nephele splat time"


# ---------------------------------------------------------------- points


def fill_points(me, splats, phase=None):
    """Replace ``me`` by one vertex per splat carrying the splat's attributes.

    Parameters
    ----------
    me : bpy.types.Mesh
    splats : nephele.core.splats.Splats
        ``centers`` (object space), ``axes`` (principal semi-axes of the
        cut-off ellipsoid as columns), ``radius`` (cut-off, cell units),
        ``opacity``, ``color``, ``wind`` (scene units per hour).
    phase : (n, 2) array, optional
        Streak texture offsets of each splat in tiles (default: zero).

    Notes
    -----
    Attributes: ``splat_center``; ``splat_m0..2``, the rows of
    ``R axes⁻¹`` (scene offset → cell offset); ``splat_axis0..2``, the
    columns of ``axes`` (the quad's half-size along a unit view-plane vector
    ``e`` is ``|axesᵀ e|``); ``splat_opacity``, ``splat_color`` (RGBA),
    ``splat_wind``, ``splat_phase`` (2-D, stored as a vector).
    """
    centers = np.ascontiguousarray(splats.centers, dtype=np.float32).reshape(-1, 3)
    n = len(centers)
    axes = np.asarray(splats.axes, dtype=np.float64).reshape(n, 3, 3)
    to_cells = float(splats.radius) * np.linalg.inv(axes) if n else np.zeros((0, 3, 3))
    phase = np.zeros((n, 2)) if phase is None else np.asarray(phase, dtype=np.float64).reshape(n, 2)
    me.clear_geometry()
    if n:
        me.vertices.add(n)
        me.attributes["position"].data.foreach_set("vector", centers.ravel())
    rgba = np.ones((n, 4), dtype=np.float32)
    rgba[:, :3] = np.asarray(splats.color, dtype=np.float32).reshape(n, 3)
    for name, values in (
        (CENTER, centers),
        (M0, to_cells[:, 0, :]), (M1, to_cells[:, 1, :]), (M2, to_cells[:, 2, :]),
        (AXES + "0", axes[:, :, 0]), (AXES + "1", axes[:, :, 1]), (AXES + "2", axes[:, :, 2]),
        (OPACITY, np.asarray(splats.opacity, dtype=np.float32).reshape(n)),
        (COLOR, rgba),
        (WIND, np.asarray(splats.wind, dtype=np.float32).reshape(n, 3)),
        (PHASE, np.column_stack([phase, np.zeros(n)])),
    ):
        set_point_attribute(me, name, values)
    me.update()
    return me


# ---------------------------------------------------------------- geometry nodes


def _link(tree, src, dst):
    tree.links.new(src, dst)


def _gn_attr(tree, name, dtype="FLOAT_VECTOR", loc=(0, 0)):
    node = tree.nodes.new("GeometryNodeInputNamedAttribute")
    node.data_type = dtype
    node.inputs["Name"].default_value = name
    node.location = loc
    return node.outputs["Attribute"]


def splat_node_group(material):
    """Geometry nodes: a camera-facing quad per point, sorted back to front, realized.

    The quad lies in the active camera's x-y plane, turned and sized to the
    principal axes of the cut-off ellipsoid's shadow along the view: with
    ``a = axesᵀ e_x`` and ``b = axesᵀ e_y`` the shadow's shape matrix is
    ``[[a·a, a·b], [a·b, b·b]]``; its axes are at ``θ = ½ atan2(2 a·b,
    a·a − b·b)`` from ``e_x`` with half-lengths ``√λ±`` (4/π of the
    ellipse's area; the camera-aligned bounding box was up to twice that for
    the flat splats of thin levels seen obliquely), grown to hold the splat's
    perspective view from the eye (see the comment in the code).  Point attributes carry over to the
    quad's corners for ``material`` (set on the quads: generated geometry
    has no material of its own).
    """
    name = f"{GROUP_NAME} {material.name}"
    ng = bpy.data.node_groups.get(name)
    if ng is not None:
        bpy.data.node_groups.remove(ng)
    ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    g = Nodes(ng)
    cam = _camera_frame(ng)
    theta, major, minor = _shadow_ellipse(ng, g, cam)
    rel, along, across, k = _perspective(ng, g, cam, theta)
    r_z = g.vmath("LENGTH", _shadow(ng, g, cam["ez"], -500), loc=(-400, -500))
    scale = ng.nodes.new("ShaderNodeCombineXYZ")
    scale.location = (900, -100)
    _link(ng, g.math("MULTIPLY", g.math("MULTIPLY_ADD", r_z, along, major, loc=(700, 100)), k, loc=(800, 100)),
          scale.inputs[0])
    _link(ng, g.math("MULTIPLY", g.math("MULTIPLY_ADD", r_z, across, minor, loc=(700, -50)), k, loc=(800, -50)),
          scale.inputs[1])
    scale.inputs[2].default_value = 1.0
    spin = ng.nodes.new("FunctionNodeAxisAngleToRotation")
    spin.location = (200, -250)
    spin.inputs["Axis"].default_value = (0.0, 0.0, 1.0)
    _link(ng, theta, spin.inputs["Angle"])
    turn = ng.nodes.new("FunctionNodeRotateRotation")
    turn.location = (400, -250)
    turn.rotation_space = "LOCAL"
    _link(ng, cam["rot"], turn.inputs["Rotation"])
    _link(ng, spin.outputs[0], turn.inputs["Rotate By"])
    _sorted_quads(ng, g, g.vmath("DOT_PRODUCT", rel, cam["ez"], loc=(-400, 300)), turn.outputs[0], scale.outputs[0],
                  material)
    return ng


def _camera_frame(ng):
    """The active camera in the object's space: ``rot``, its ``location`` and axes ``ex``, ``ey``, ``ez``."""
    cam = ng.nodes.new("GeometryNodeInputActiveCamera")
    cam.location = (-1400, -300)
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.transform_space = "RELATIVE"  # the camera in this object's space, where the attributes are
    info.location = (-1200, -300)
    _link(ng, cam.outputs[0], info.inputs["Object"])
    rot = info.outputs["Rotation"]

    def cam_axis(v, y):
        node = ng.nodes.new("FunctionNodeRotateVector")
        node.location = (-1000, y)
        node.inputs["Vector"].default_value = v
        _link(ng, rot, node.inputs["Rotation"])
        return node.outputs[0]

    return {"rot": rot, "location": info.outputs["Location"], "ex": cam_axis((1, 0, 0), -300),
            "ey": cam_axis((0, 1, 0), -450), "ez": cam_axis((0, 0, 1), -600)}


def _shadow(ng, g, e, y):
    """``axesᵀ e``: the ellipsoid's semi-axes projected on the view-plane direction ``e``."""
    comps = [g.vmath("DOT_PRODUCT", _gn_attr(ng, AXES + str(k), loc=(-1000, y - 60 * k)), e,
                     loc=(-800, y - 60 * k)) for k in range(3)]
    comb = ng.nodes.new("ShaderNodeCombineXYZ")
    comb.location = (-600, y)
    for k in range(3):
        _link(ng, comps[k], comb.inputs[k])
    return comb.outputs[0]


def _shadow_ellipse(ng, g, cam):
    """The orthographic shadow's axis angle ``θ`` from ``e_x`` and its half-lengths ``√λ+``, ``√λ-``.

    The shadow ellipse {P M u : |u| <= 1} has the 2x2 shape matrix C = (P M)(P M)ᵀ, P = [e_x e_y]ᵀ:
    its principal axes are at angle θ = atan2(2 c01, c00 - c11) / 2 from e_x, half-lengths √λ±.
    """
    a, b = _shadow(ng, g, cam["ex"], 0), _shadow(ng, g, cam["ey"], -250)
    c00 = g.vmath("DOT_PRODUCT", a, a, loc=(-400, 100))
    c11 = g.vmath("DOT_PRODUCT", b, b, loc=(-400, 0))
    c01 = g.vmath("DOT_PRODUCT", a, b, loc=(-400, -100))
    half_diff = g.math("MULTIPLY", g.math("SUBTRACT", c00, c11, loc=(-250, 50)), 0.5, loc=(-100, 50))
    mean = g.math("MULTIPLY", g.math("ADD", c00, c11, loc=(-250, 150)), 0.5, loc=(-100, 150))
    root = g.math("SQRT", g.math("ADD", g.math("MULTIPLY", half_diff, half_diff, loc=(50, 0)),
                                 g.math("MULTIPLY", c01, c01, loc=(50, -100)), loc=(200, 0)),
                  loc=(350, 0))
    theta = g.math("MULTIPLY", g.math("ARCTAN2", g.math("MULTIPLY", c01, 2.0, loc=(-250, -150)),
                                      half_diff, loc=(-100, -150)), 0.5, loc=(50, -200))
    # ARCTAN2(y, x) = atan2(2 c01, (c00 - c11)/2 ... ) has the sign of atan2(2 c01, c00 - c11): same angle.
    major = g.math("SQRT", g.math("ADD", mean, root, loc=(500, 100)), loc=(600, 100))
    # max(., 0): λ₋ of a splat seen exactly edge-on is 0 up to rounding.
    minor = g.math("SQRT", g.math("MAXIMUM", g.math("SUBTRACT", mean, root, loc=(500, -50)), 0.0, loc=(550, -50)),
                   loc=(600, -50))
    return theta, major, minor


def _perspective(ng, g, cam, theta):
    """The point's offset from the eye ``rel`` and how the quad grows under perspective:
    ``(rel, along, across, k)`` (see below)."""
    # Under perspective the rays through a splat are not along the camera's z: a point d of the
    # ellipsoid is seen on the quad's plane (through the centre, parallel to the view plane) at
    # (d_xy + t d_z) depth / (depth - d_z), t = the centre's lateral offset / depth: the orthographic
    # shadow plus a segment of length |t| r_z along t (r_z = the ellipsoid's extent along the view
    # axis), scaled by at most k = depth / (depth - r).  So each half-length grows by r_z |t . axis|
    # and then by k: the quad holds every ray that meets the splat, for either kind of camera.
    # Splats reaching the eye's plane (depth <= r) get no quad, as the core renderer drops them.
    ex, ey, ez = cam["ex"], cam["ey"], cam["ez"]
    pos = ng.nodes.new("GeometryNodeInputPosition")
    pos.location = (-800, 300)
    rel = g.vmath("SUBTRACT", pos.outputs[0], cam["location"], loc=(-600, 300))
    depth = g.math("MULTIPLY", g.vmath("DOT_PRODUCT", rel, ez, loc=(-400, 450)), -1.0, loc=(-250, 450))
    tx = g.math("DIVIDE", g.vmath("DOT_PRODUCT", rel, ex, loc=(-400, 550)), depth, loc=(-250, 550))
    ty = g.math("DIVIDE", g.vmath("DOT_PRODUCT", rel, ey, loc=(-400, 600)), depth, loc=(-250, 600))
    cos, sin = g.math("COSINE", theta, loc=(200, 550)), g.math("SINE", theta, loc=(200, 600))
    along = g.math("ABSOLUTE", g.math("MULTIPLY_ADD", tx, cos, g.math("MULTIPLY", ty, sin, loc=(350, 600)),
                                      loc=(500, 550)), loc=(650, 550))
    across = g.math("ABSOLUTE", g.math("SUBTRACT", g.math("MULTIPLY", ty, cos, loc=(350, 650)),
                                       g.math("MULTIPLY", tx, sin, loc=(350, 700)), loc=(500, 650)), loc=(650, 650))
    lengths = (g.vmath("LENGTH", _gn_attr(ng, AXES + str(k), loc=(-600, 650 + 60 * k)), loc=(-400, 650 + 60 * k))
               for k in range(2))
    reach = g.math("MAXIMUM", g.math("MAXIMUM", *lengths, loc=(-250, 700)),
                   g.vmath("LENGTH", _gn_attr(ng, AXES + "2", loc=(-600, 770)), loc=(-400, 770)), loc=(-100, 700))
    gap = g.math("SUBTRACT", depth, reach, loc=(50, 650))
    k = g.math("MULTIPLY", g.math("DIVIDE", depth, g.math("MAXIMUM", gap, 1e-9, loc=(200, 650)), loc=(350, 650)),
               g.math("GREATER_THAN", gap, 1e-4, loc=(200, 750)), loc=(500, 650))
    return rel, along, across, k


def _sorted_quads(ng, g, key, quad_rot, scale, material):
    """Points sorted by ``key`` (back to front), a quad instanced on each, realized, with ``material``."""
    gin = ng.nodes.new("NodeGroupInput")
    gin.location = (-1400, 0)
    gout = ng.nodes.new("NodeGroupOutput")
    gout.location = (1000, 0)
    sort = ng.nodes.new("GeometryNodeSortElements")
    sort.domain = "POINT"
    sort.location = (-200, 300)
    _link(ng, gin.outputs[0], sort.inputs["Geometry"])
    _link(ng, key, sort.inputs["Sort Weight"])  # -depth along the camera's view (its -z): farthest first
    quad = ng.nodes.new("GeometryNodeMeshGrid")
    quad.location = (0, -300)
    quad.inputs["Size X"].default_value = 2.0
    quad.inputs["Size Y"].default_value = 2.0
    quad.inputs["Vertices X"].default_value = 2
    quad.inputs["Vertices Y"].default_value = 2
    inst = ng.nodes.new("GeometryNodeInstanceOnPoints")
    inst.location = (200, 0)
    _link(ng, sort.outputs[0], inst.inputs["Points"])
    _link(ng, quad.outputs["Mesh"], inst.inputs["Instance"])
    _link(ng, quad_rot, inst.inputs["Rotation"])
    _link(ng, scale, inst.inputs["Scale"])
    real = ng.nodes.new("GeometryNodeRealizeInstances")
    real.location = (500, 0)
    _link(ng, inst.outputs[0], real.inputs["Geometry"])
    setmat = ng.nodes.new("GeometryNodeSetMaterial")
    setmat.location = (750, 0)
    _link(ng, real.outputs[0], setmat.inputs["Geometry"])
    setmat.inputs["Material"].default_value = material
    _link(ng, setmat.outputs[0], gout.inputs[0])


def add_modifier(obj, material):
    """Give ``obj`` the splat Geometry Nodes modifier (once) drawing with ``material``."""
    mod = obj.modifiers.get("Nephele splats") or obj.modifiers.new("Nephele splats", "NODES")
    mod.node_group = splat_node_group(material)
    return mod


# ---------------------------------------------------------------- material


def _sh_vmath(tree, op, a, b=None, loc=(0, 0)):
    node = tree.nodes.new("ShaderNodeVectorMath")
    node.operation = op
    node.location = loc
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, bpy.types.NodeSocket):
            tree.links.new(v, node.inputs[i])
        else:
            node.inputs[i].default_value = v
    return node.outputs["Value" if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE") else "Vector"]


def _sh_math(tree, op, a, b=None, c=None, loc=(0, 0)):
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = op
    node.location = loc
    for i, v in enumerate((a, b, c)):
        if v is None:
            continue
        if isinstance(v, bpy.types.NodeSocket):
            tree.links.new(v, node.inputs[i])
        else:
            node.inputs[i].default_value = float(v)
    return node.outputs[0]


def _sh_attr(tree, name, loc, out="Vector"):
    node = tree.nodes.new("ShaderNodeAttribute")
    node.attribute_name = name
    node.location = loc
    return node.outputs[out]


def data_image(name, values):
    """A float, non-colour image holding ``values`` ((h, w) or (h, w, 4)), packed into the .blend."""
    values = np.asarray(values, dtype=np.float32)
    if values.ndim == 2:
        values = np.repeat(values[..., None], 4, axis=2)
        values[..., 3] = 1.0
    h, w = values.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (img.size[0], img.size[1]) != (w, h):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    img.alpha_mode = "CHANNEL_PACKED"
    img.pixels.foreach_set(np.ascontiguousarray(values).ravel())
    img.pack()
    return img


def footprint_image(kernel, size=4096):
    """The kernel's radial footprint as a ``size × 1`` float image, linear in ``ρ²``.

    Texel ``i`` holds ``kernel.footprint`` at ``ρ² = R² i / (size - 1)``
    (the core renderer's lookup is linear in ``ρ²`` too); a lookup past the
    last texel's centre clips to zero.  The material reads the nearest texel
    (4096 of them: within 1e-3 of the peak).
    """
    rho = np.sqrt(np.linspace(0.0, kernel.radius**2, int(size)))
    table = kernel.footprint(np.column_stack([rho, np.zeros_like(rho)]))
    return data_image(f"Nephele footprint {kernel.kind} R{kernel.radius:g} s{kernel.sigma:g} w{kernel.window}",
                      table[None, :])


def streaks_image(maps):
    """The ``n`` streak maps side by side, each padded by one wrapped texel per side.

    The padding gives bilinear filtering each map's own periodic neighbour at
    its edges instead of the next map's.
    """
    maps = np.asarray(maps, dtype=np.float32)
    n, size, _ = maps.shape
    padded = np.pad(maps, ((0, 0), (1, 1), (1, 1)), mode="wrap")
    atlas = np.concatenate(list(padded), axis=1)  # rows = v, columns = u, map k at columns k(size+2)...
    return data_image(f"Nephele streaks {n}x{size} {zlib.crc32(maps.tobytes()):08x}", atlas)


def splat_material(name, footprint, kernel_radius, *, extinction=1.0, streaks=None, n_maps=1, tile=0.1,
                   contrast=0.0, streak_mean=1.0):
    """The splat material (see the module docstring); rebuilt in place if it exists.

    Parameters
    ----------
    footprint : bpy.types.Image
        From :func:`footprint_image`.
    kernel_radius : float
        The kernel's cut-off in cell units.
    extinction : float
        Extinction per scene unit at opacity 1 (node "Nephele extinction").
    streaks : bpy.types.Image, optional
        From :func:`streaks_image` (``n_maps`` maps); None: no streaks.
    tile : float
        Scene units along the projected wind covered by one streak map.
    contrast : float
        0: no streaks; 1: optical depth × map / ``streak_mean``.

    Notes
    -----
    The model time in hours (which picks each splat's streak map) is the
    value node "Nephele splat time", set by the frame updater.
    """
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    # EEVEE: blended in the geometry nodes' back-to-front order; Cycles: exact transparency.
    mat.surface_render_method = "BLENDED"
    mat.use_transparency_overlap = True
    mat.use_backface_culling = False

    tc = tree.nodes.new("ShaderNodeTexCoord")
    tc.location = (-2200, 200)
    geo = tree.nodes.new("ShaderNodeNewGeometry")
    geo.location = (-2200, -200)
    d = _sh_vmath(tree, "SUBTRACT", tc.outputs["Object"], _sh_attr(tree, CENTER, (-2200, 0)), loc=(-2000, 100))
    view = geo.outputs["Incoming"]  # unit, towards the viewer; the object is not rotated
    rows = [_sh_attr(tree, m, (-2000, -100 - 150 * i)) for i, m in enumerate((M0, M1, M2))]

    def to_cells(vec, y):
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        comb.location = (-1600, y)
        for i, row in enumerate(rows):
            tree.links.new(_sh_vmath(tree, "DOT_PRODUCT", row, vec, loc=(-1800, y - 60 * i)), comb.inputs[i])
        return comb.outputs[0]

    u = to_cells(d, 300)  # the shading point's cell offset
    m = to_cells(view, -300)  # the view direction in cell units per scene unit
    mm = _sh_vmath(tree, "DOT_PRODUCT", m, m, loc=(-1400, -300))
    um = _sh_vmath(tree, "DOT_PRODUCT", u, m, loc=(-1400, 0))
    tm = _sh_vmath(tree, "SCALE", m, None, loc=(-1000, -100))
    tree.links.new(_sh_math(tree, "DIVIDE", um, mm, loc=(-1200, 0)), tm.node.inputs["Scale"])
    q = _sh_vmath(tree, "SUBTRACT", u, tm, loc=(-800, 100))  # off the view line through the shading point
    rho2 = _sh_vmath(tree, "DOT_PRODUCT", q, q, loc=(-600, 100))

    # F(ρ²): texel i's centre (i + 0.5)/n holds ρ² = R² i / (n - 1).
    n = footprint.size[0]
    uvx = _sh_math(tree, "MULTIPLY_ADD", rho2, (n - 1) / (n * float(kernel_radius) ** 2), 0.5 / n, loc=(-400, 100))
    # Nearest texel: EEVEE's filtered lookup of this 1-texel-high table came out striped in columns and
    # 15 % dark (64×48 test frame); nearest matches the core renderer in both engines.
    tex = _image_lookup(tree, footprint, uvx, 0.5, "Nephele footprint", (0, 100), interpolation="Closest")
    fp = _sh_math(tree, "MULTIPLY", tex, _sh_math(tree, "INVERSE_SQRT", mm, loc=(0, -200)), loc=(250, 0))
    ext = tree.nodes.new("ShaderNodeValue")
    ext.name = ext.label = "Nephele extinction"
    ext.outputs[0].default_value = float(extinction)
    ext.location = (250, -300)
    tau = _sh_math(tree, "MULTIPLY", fp, _sh_attr(tree, OPACITY, (250, -450), out="Fac"), loc=(450, 0))
    tau = _sh_math(tree, "MULTIPLY", tau, ext.outputs[0], loc=(600, 0))
    if streaks is not None and contrast > 0:
        t = streak_nodes(tree, streaks, n_maps, d, view, tile, location=(-600, -900))
        gain = _sh_math(tree, "MULTIPLY_ADD", t, float(contrast) / float(streak_mean), 1.0 - float(contrast),
                        loc=(600, -600))
        tau = _sh_math(tree, "MULTIPLY", tau, gain, loc=(750, 0))
    # alpha = 1 - exp(-τ): the splat's slab of optical depth τ.
    minus = _sh_math(tree, "MULTIPLY", tau, -1.0, loc=(900, -100))
    alpha = _sh_math(tree, "SUBTRACT", 1.0, _sh_math(tree, "EXPONENT", minus, loc=(1050, -100)), loc=(1200, 0))
    emit = tree.nodes.new("ShaderNodeEmission")
    emit.location = (1200, -300)
    tree.links.new(_sh_attr(tree, COLOR, (1000, -400), out="Color"), emit.inputs["Color"])
    transp = tree.nodes.new("ShaderNodeBsdfTransparent")
    transp.location = (1200, -150)
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.location = (1400, 0)
    tree.links.new(alpha, mix.inputs[0])
    tree.links.new(transp.outputs[0], mix.inputs[1])
    tree.links.new(emit.outputs[0], mix.inputs[2])
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (1600, 0)
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def _image_lookup(tree, image, x, y, name, loc, interpolation="Linear"):
    """Red channel of ``image`` at texture coordinates (``x``, ``y``): bilinear (or ``interpolation``), zero outside."""
    uv = tree.nodes.new("ShaderNodeCombineXYZ")
    uv.location = (loc[0] - 200, loc[1])
    for i, v in enumerate((x, y)):
        if isinstance(v, bpy.types.NodeSocket):
            tree.links.new(v, uv.inputs[i])
        else:
            uv.inputs[i].default_value = float(v)
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.name = tex.label = name
    tex.image = image
    tex.interpolation = interpolation
    tex.extension = "CLIP"
    tex.location = loc
    tree.links.new(uv.outputs[0], tex.inputs["Vector"])
    sep = tree.nodes.new("ShaderNodeSeparateColor")
    sep.location = (loc[0] + 300, loc[1])
    tree.links.new(tex.outputs["Color"], sep.inputs[0])
    return sep.outputs[0]


def streak_nodes(tree, image, n_maps, d, view, tile, location=(0, 0)):
    """The streak map value at the shading point (see :func:`nephele.core.splats` conventions).

    ``wp = wind - (wind·v) v``; ``e_a = wp/|wp|``, ``e_b = v × e_a``;
    ``(a, b) = (d·e_a, d·e_b) / tile + phase``; map
    ``k = floor(n frac(|wp| hours / tile))`` at ``(frac a, frac b)``.
    """
    x, y = location
    wind = _sh_attr(tree, WIND, (x - 600, y))
    along = _sh_vmath(tree, "SCALE", view, None, loc=(x - 400, y - 100))
    tree.links.new(_sh_vmath(tree, "DOT_PRODUCT", wind, view, loc=(x - 600, y - 150)), along.node.inputs["Scale"])
    wp = _sh_vmath(tree, "SUBTRACT", wind, along, loc=(x - 200, y))
    speed = _sh_vmath(tree, "LENGTH", wp, loc=(x, y + 150))
    ea = _sh_vmath(tree, "NORMALIZE", wp, loc=(x, y))
    eb = _sh_vmath(tree, "CROSS_PRODUCT", view, ea, loc=(x + 200, y - 100))
    phase = tree.nodes.new("ShaderNodeSeparateXYZ")
    phase.location = (x + 200, y - 300)
    tree.links.new(_sh_attr(tree, PHASE, (x, y - 300)), phase.inputs[0])
    inv_tile = 1.0 / float(tile)
    a = _sh_math(tree, "MULTIPLY_ADD", _sh_vmath(tree, "DOT_PRODUCT", d, ea, loc=(x + 400, y)), inv_tile,
                 loc=(x + 600, y))
    tree.links.new(phase.outputs[0], a.node.inputs[2])
    b = _sh_math(tree, "MULTIPLY_ADD", _sh_vmath(tree, "DOT_PRODUCT", d, eb, loc=(x + 400, y - 150)), inv_tile,
                 loc=(x + 600, y - 150))
    tree.links.new(phase.outputs[1], b.node.inputs[2])
    hours = tree.nodes.new("ShaderNodeValue")
    hours.name = hours.label = TIME_NODE
    hours.location = (x, y + 300)
    cycles = _sh_math(tree, "MULTIPLY", _sh_math(tree, "MULTIPLY", speed, hours.outputs[0], loc=(x + 200, y + 250)),
                      inv_tile, loc=(x + 400, y + 250))
    k = _sh_math(tree, "FLOOR", _sh_math(tree, "MULTIPLY", _sh_math(tree, "FRACT", cycles, loc=(x + 600, y + 250)),
                                         float(n_maps), loc=(x + 800, y + 250)), loc=(x + 1000, y + 250))
    # Padded atlas: map k's texel centres u_i = (k (s+2) + 1 + i + 0.5) / (n (s+2)), i = frac(a) s - 0.5.
    size = image.size[1] - 2
    width = float(n_maps * (size + 2))
    fa = _sh_math(tree, "FRACT", a, loc=(x + 800, y))
    fb = _sh_math(tree, "FRACT", b, loc=(x + 800, y - 150))
    ux = _sh_math(tree, "MULTIPLY_ADD", k, (size + 2) / width, loc=(x + 1200, y + 100))
    tree.links.new(_sh_math(tree, "MULTIPLY_ADD", fa, size / width, 1.0 / width, loc=(x + 1000, y)),
                   ux.node.inputs[2])
    vy = _sh_math(tree, "MULTIPLY_ADD", fb, size / (size + 2.0), 1.0 / (size + 2.0), loc=(x + 1000, y - 150))
    return _bilinear_lookup(tree, image, ux, vy, "Nephele streaks", (x + 1500, y))


def _bilinear_lookup(tree, image, u, v, name, loc):
    """Red channel of ``image`` at (``u``, ``v``), bilinear from four nearest-texel reads.

    The same numbers in Cycles and EEVEE: EEVEE's own filtered lookup (mipmaps chosen from screen
    derivatives, which jump where the streak coordinates wrap) was 4 % dark and 23 % off on 4×4
    blocks in the 64×48 test frame.  Texel ``i`` has its centre at ``(i + 0.5) / size``.
    """
    w, h = image.size
    x, y = loc

    def corners(c, n, yy):
        t = _sh_math(tree, "MULTIPLY_ADD", c, float(n), -0.5, loc=(x - 800, yy))
        t0 = _sh_math(tree, "FLOOR", t, loc=(x - 650, yy))
        frac = _sh_math(tree, "SUBTRACT", t, t0, loc=(x - 500, yy))
        c0 = _sh_math(tree, "MULTIPLY_ADD", t0, 1.0 / n, 0.5 / n, loc=(x - 500, yy - 100))
        c1 = _sh_math(tree, "ADD", c0, 1.0 / n, loc=(x - 350, yy - 100))
        return c0, c1, frac

    u0, u1, fu = corners(u, w, y)
    v0, v1, fv = corners(v, h, y - 250)
    reads = [[_image_lookup(tree, image, uu, vv, f"{name} {i}{j}", (x + 300 * i, y - 300 * j - 400),
                            interpolation="Closest") for i, uu in enumerate((u0, u1))] for j, vv in enumerate((v0, v1))]

    def lerp(a, b, f, yy):
        return _sh_math(
            tree, "MULTIPLY_ADD", _sh_math(tree, "SUBTRACT", b, a, loc=(x + 700, yy)), f, a, loc=(x + 850, yy)
        )

    return lerp(lerp(*reads[0], fu, y), lerp(*reads[1], fu, y - 150), fv, y - 75)



# ---------------------------------------------------------------- object, updater, operator


def _samples(params, hours):
    kernel = splat_kernel(params["kernel"])
    sp = splat_samples(data_ops.dataset(params["source"]), params["var"], hours,
                       TransferFunction.from_dict(params["tf"]), color_var=params["color_var"] or None,
                       exaggeration=params["exaggeration"], stride=params["stride"], kernel=kernel)
    return sp, kernel


@frame.register_updater(KIND)
def update_splats(obj, params, scene, frame_number):
    """Refill ``obj``'s points with the splats of the frame's model time and set the streak clock."""
    ds = data_ops.dataset(params["source"])
    hours = round(frame_hours(frame_number, params["frame_start"], params["hours_per_frame"],
                              last_hour=float(ds.hours[-1])), 6)
    mat = obj.data.materials[0] if obj.data.materials else None
    if mat is not None and TIME_NODE in mat.node_tree.nodes:
        mat.node_tree.nodes[TIME_NODE].outputs[0].default_value = hours
    if obj.get("nephele_shown") == repr(hours) and len(obj.data.vertices):
        return
    sp, _ = _samples(params, hours)
    fill_points(obj.data, sp, streak_offsets(np.arange(len(sp))))
    obj["nephele_shown"] = repr(hours)
    obj["nephele_hours"] = hours


def add_wind_splats(var="cloud", tf=None, *, color_var="altitude", kernel="gaussian", stride=1,
                    extinction=DEFAULT_EXTINCTION, streaks=True, n_maps=8, tile=None, contrast=0.6,
                    source=None, exaggeration=None, scene=None, collection=None, name=OBJECT_NAME):
    """Add (or rebuild) a splat object following the frame; returns ``(object, number of splats)``.

    ``tf`` defaults to zero up to 0.3, 1 at 1; ``tile`` (scene units per
    streak map) defaults to the first frame's :func:`default_tile`.
    """
    scene = scene or bpy.context.scene
    cfg = data_ops.settings(scene)
    tf = tf or TransferFunction.ramp(0.3, 1.0)
    params = {
        "kind": KIND, "source": str(source or cfg["source"]), "var": str(var), "tf": tf.to_dict(),
        "color_var": str(color_var or ""), "kernel": str(kernel), "stride": int(stride),
        "exaggeration": float(cfg["exaggeration"] if exaggeration is None else exaggeration),
        "hours_per_frame": float(cfg["hours_per_frame"]), "frame_start": int(cfg["frame_start"]),
    }
    ds = data_ops.dataset(params["source"])
    for field in (var,) + ((color_var,) if color_var and color_var != "altitude" else ()):
        if field not in ds:
            raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})",
                            path=params["source"], field=field)
    hours = frame_hours(scene.frame_current, params["frame_start"], params["hours_per_frame"],
                        last_hour=float(ds.hours[-1]))
    sp, k = _samples(params, hours)
    tile = float(default_tile(sp) if tile is None else tile)
    if not tile > 0:
        raise DataError(f"must be > 0, got {tile!r}", field="streak tile")
    maps = streak_maps(int(n_maps), 64)
    mat = splat_material(f"{name} material", footprint_image(k), k.radius, extinction=extinction,
                         streaks=streaks_image(maps) if streaks else None, n_maps=int(n_maps), tile=tile,
                         contrast=float(contrast) if streaks else 0.0, streak_mean=float(maps.mean()))
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    coll = collection or scene.collection
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    obj.matrix_world.identity()  # the material works in object space with world view vectors
    camera_only(obj)
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    add_modifier(obj, mat)
    params["tile"] = tile
    frame.set_params(obj, params)
    obj["nephele_shown"] = ""
    update_splats(obj, params, scene, scene.frame_current + scene.frame_subframe)
    return obj, len(obj.data.vertices)


def camera_only(obj):
    """Let only camera rays see the splats.

    The splats are an emission–absorption medium seen from the eye, as in the
    paper's figure and the core renderer: no shadows, reflections or
    indirect light from them.  Otherwise every shadow and bounce ray from the
    globe beneath crosses its ~60 splat layers as well (Cycles, Fig. 3 of the
    full demo at 80×60: 27.5 s → 8.2 s).
    """
    for flag in ("visible_shadow", "visible_diffuse", "visible_glossy", "visible_transmission",
                 "visible_volume_scatter"):
        setattr(obj, flag, False)
    obj.visible_camera = True
    return obj


def render_settings(scene):
    """Cycles settings splats need: every transparent layer traced, no Russian roulette on them."""
    scene.cycles.transparent_max_bounces = 1024
    scene.cycles.min_transparent_bounces = 1024
    return scene


class NephelePropsSplats(bpy.types.PropertyGroup):
    var: bpy.props.StringProperty(name="Variable", default="cloud", description="Field behind the opacity",
                                  search=data_ops.variable_search)
    threshold: bpy.props.FloatProperty(name="Threshold", default=0.3, min=0.0, max=1e6,
                                       description="Opacity is zero up to this value: no splat there")
    full: bpy.props.FloatProperty(name="Full at", default=1.0, min=0.0, max=1e6)
    opacity: bpy.props.FloatProperty(name="Opacity", default=1.0, min=0.0, max=1e3)
    color_var: bpy.props.StringProperty(name="Colour by", default="altitude",
                                        description='"altitude", a field such as "temperature", or empty (white)')
    kernel: bpy.props.EnumProperty(name="Kernel", default="gaussian", items=[
        ("gaussian", "Normalised", "Windowed Gaussian, weights sum to 1 within ~1e-4"),
        ("paper", "Paper", "Truncated Gaussian (sigma 0.65, R 2.5): within 0.5%")])
    stride: bpy.props.IntProperty(name="Stride", default=1, min=1, max=16, description="Every n-th sample")
    extinction: bpy.props.FloatProperty(name="Extinction", default=DEFAULT_EXTINCTION, min=0.0, max=1e6,
                                        description="Extinction per scene unit at opacity 1")
    streaks: bpy.props.BoolProperty(name="Wind streaks", default=True)
    n_maps: bpy.props.IntProperty(name="Maps", default=8, min=1, max=64, description="Streak maps in a cycle")
    tile: bpy.props.FloatProperty(name="Tile", default=0.0, min=0.0, max=10.0, precision=4,
                                  description="Scene units per streak map (0: twice the median splat size)")
    contrast: bpy.props.FloatProperty(name="Contrast", default=0.6, min=0.0, max=1.0)


class NEPHELE_OT_add_wind_splats(bpy.types.Operator):
    """One view-facing splat per cloudy sample, with streaks flowing along the wind"""

    bl_idname = "nephele.add_wind_splats"
    bl_label = "Add wind splats"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.nephele_splats
        try:
            tf = TransferFunction.ramp(s.threshold, s.full, s.opacity)
            obj, n = add_wind_splats(s.var, tf, color_var=s.color_var, kernel=s.kernel, stride=s.stride,
                                     extinction=s.extinction, streaks=s.streaks, n_maps=s.n_maps,
                                     tile=s.tile or None, contrast=s.contrast, scene=context.scene)
        except (DataError, ValueError, OSError, ImportError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        render_settings(context.scene)
        self.report({"INFO"}, f"{obj.name}: {n} splats")
        select_only(context, obj)
        return {"FINISHED"}


class NEPHELE_PT_splats(SubPanel, bpy.types.Panel):
    bl_label = "Wind splats (Fig. 3)"
    bl_idname = "NEPHELE_PT_splats"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = getattr(context.scene, "nephele_splats", None)
        if s is None:
            return
        col = self.layout.column()
        for prop in ("var", "threshold", "full", "opacity", "color_var", "kernel", "stride", "extinction",
                     "streaks", "n_maps", "tile", "contrast"):
            col.prop(s, prop)
        self.layout.operator(NEPHELE_OT_add_wind_splats.bl_idname, icon="PARTICLES")
        self.layout.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG3"
        obj = context.active_object
        if obj is not None and frame.params(obj).get("kind") == KIND:
            self.layout.label(text=f"{len(obj.data.vertices)} splats, model time {obj.get('nephele_hours', 0):.2f} h")


CLASSES = (NephelePropsSplats, NEPHELE_OT_add_wind_splats, NEPHELE_PT_splats)
SCENE_PROPERTIES = {"nephele_splats": NephelePropsSplats}
