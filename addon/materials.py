"""Materials whose colour comes from a mesh attribute through a colour ramp.

The paper colours a contour surface by a second scalar ("a separate transfer
function can be used to specify the cloud color as a function of another
scalar variable like altitude or temperature").  Here that transfer function
is ``Attribute -> Map Range (vmin..vmax -> 0..1) -> Color Ramp -> BSDF``, so
changing the range or the ramp needs no new mesh.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import bpy

from ..core.volume.transfer import ALTITUDE_COLORS

RAMPS = {
    # Cloud tops: the volumes' altitude colours (warm grey low down, white, pale blue high up) over 0-12 km.
    "altitude": [(h / ALTITUDE_COLORS.points[-1][0], c) for h, c in ALTITUDE_COLORS.points],
    # Cold to warm.
    "temperature": [(0.0, (0.23, 0.30, 0.75)), (0.5, (0.87, 0.87, 0.87)), (1.0, (0.71, 0.02, 0.15))],
    # Perceptually ordered, dark to bright (viridis samples).
    "viridis": [(0.0, (0.267, 0.005, 0.329)), (0.25, (0.229, 0.322, 0.546)), (0.5, (0.128, 0.567, 0.551)),
                (0.75, (0.369, 0.789, 0.383)), (1.0, (0.993, 0.906, 0.144))],
    "grey": [(0.0, (0.2, 0.2, 0.2)), (1.0, (1.0, 1.0, 1.0))],
}
"""Named colour ramps: lists of ``(position 0..1, (r, g, b))`` in linear RGB."""


def enable_nodes(idblock):
    """Give a material or world its node tree (Blender < 5 creates it only on request)."""
    if idblock.node_tree is None:
        idblock.use_nodes = True
    return idblock.node_tree


def _stops(ramp):
    stops = RAMPS[ramp] if isinstance(ramp, str) else ramp
    if len(stops) < 1:
        raise ValueError("a colour ramp needs at least one stop")
    return [(float(p), tuple(c) + (1.0,) * (4 - len(c))) for p, c in stops]


def set_ramp(color_ramp, ramp):
    """Set the stops of a ``ColorRamp`` node's ``color_ramp`` from a name or a stop list."""
    stops = _stops(ramp)
    els = color_ramp.elements
    while len(els) > 1:
        els.remove(els[-1])
    els[0].position, els[0].color = stops[0]
    for pos, col in stops[1:]:
        els.new(pos).color = col


def attribute_ramp_nodes(tree, attribute, vmin, vmax, ramp, location=(-900, 0)):
    """Add ``Attribute -> Map Range -> Color Ramp`` to a node tree; returns the ramp node.

    Its ``Color`` output is the colour, its ``Alpha`` output the ramp's alpha.
    ``attribute`` may also be an output socket carrying the scalar.
    """
    x, y = location
    if hasattr(attribute, "is_output"):
        source = attribute
    else:
        attr = tree.nodes.new("ShaderNodeAttribute")
        attr.name = attr.label = "Nephele attribute"
        attr.attribute_name = attribute
        attr.location = (x, y)
        source = attr.outputs["Fac"]
    rng = tree.nodes.new("ShaderNodeMapRange")
    rng.name = rng.label = "Nephele range"
    rng.clamp = True
    rng.inputs["From Min"].default_value = float(vmin)
    rng.inputs["From Max"].default_value = float(vmax) if vmax != vmin else float(vmin) + 1.0
    rng.location = (x + 200, y)
    ramp_node = tree.nodes.new("ShaderNodeValToRGB")
    ramp_node.name = ramp_node.label = "Nephele ramp"
    set_ramp(ramp_node.color_ramp, ramp)
    ramp_node.location = (x + 400, y)
    tree.links.new(source, rng.inputs["Value"])
    tree.links.new(rng.outputs["Result"], ramp_node.inputs["Fac"])
    return ramp_node


def attribute_material(name, attribute, vmin, vmax, ramp="altitude", *, roughness=0.7, alpha=1.0,
                       emission=0.0):
    """A Principled BSDF material coloured by ``attribute`` through a colour ramp.

    Parameters
    ----------
    name : str
        Material name (a new material; an existing one of that name is reused and rebuilt).
    attribute : str
        Mesh attribute (point domain) giving the scalar, e.g. ``"altitude"`` in metres.
    vmin, vmax : float
        Attribute values mapped to the ends of the ramp (clamped outside).
    ramp : str or list
        A key of :data:`RAMPS` or a list of ``(position, (r, g, b))``.
    roughness, alpha : float
        Principled BSDF roughness and alpha (alpha < 1 blends).
    emission : float
        Strength of emission in the ramp colour (0: none), to lift dark sides.
    """
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    enable_nodes(mat)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (0, 0)
    ramp_node = attribute_ramp_nodes(tree, attribute, vmin, vmax, ramp, location=(-800, 0))
    tree.links.new(ramp_node.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Alpha"].default_value = alpha
    if emission > 0:
        tree.links.new(ramp_node.outputs["Color"], bsdf.inputs["Emission Color"])
        bsdf.inputs["Emission Strength"].default_value = emission
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    mat["nephele_attribute"] = attribute
    return mat


def set_attribute_range(mat, attribute=None, vmin=None, vmax=None, ramp=None):
    """Change what a material from :func:`attribute_material` shows, in place."""
    nodes = mat.node_tree.nodes
    if attribute is not None:
        nodes["Nephele attribute"].attribute_name = attribute
        mat["nephele_attribute"] = attribute
    rng = nodes["Nephele range"]
    if vmin is not None:
        rng.inputs["From Min"].default_value = float(vmin)
    if vmax is not None:
        rng.inputs["From Max"].default_value = float(vmax)
    if ramp is not None:
        set_ramp(nodes["Nephele ramp"].color_ramp, ramp)


def assign(obj, mat):
    """Make ``mat`` the object's only material."""
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    return obj
