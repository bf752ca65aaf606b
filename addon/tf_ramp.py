"""A transfer function edited as a colour ramp: Blender's own ramp widget, no JSON.

The ramp lives in a small shader node group (a node tree is the one datablock
that owns a ``ColorRamp`` the panel can draw with ``template_color_ramp`` and
that is saved with the .blend).  Its positions 0..1 span the value range
``[lo, hi]``; an element's grey level is the opacity (black transparent, white
opaque).  Linear and constant ramps convert exactly: linear elements are the
transfer function's points, constant ones become steps.  The smooth modes are
sampled at 1/256 of the range, the resolution Cycles itself uses for ramps.
"""

import bpy

from ..core.volume.transfer import TransferFunction

NODE = "Opacity ramp"
SAMPLES = 257


def _opacity(color):
    return max(0.0, float(color[0] + color[1] + color[2]) / 3.0)


def ramp_node(tree):
    """The ramp node of a transfer-function tree (``None`` if the tree is not one)."""
    return None if tree is None else tree.nodes.get(NODE)


def new_tree(name, tf, lo, hi):
    """A node group whose ramp shows ``tf`` over ``[lo, hi]`` (the values outside are clipped)."""
    tree = bpy.data.node_groups.new(name, "ShaderNodeTree")
    node = tree.nodes.new("ShaderNodeValToRGB")
    node.name = node.label = NODE
    set_ramp(node, tf, lo, hi)
    return tree


def set_ramp(node, tf, lo, hi):
    """Make the ramp ``node`` show ``tf`` over ``[lo, hi]``, linearly."""
    ramp = node.color_ramp
    ramp.interpolation = "LINEAR"
    span = hi - lo if hi > lo else 1.0
    pts = [(min(max((v - lo) / span, 0.0), 1.0), o) for v, o in tf.points]
    if len(pts) == 1:
        pts.append((1.0, pts[0][1]))
    els = ramp.elements
    while len(els) > len(pts):
        els.remove(els[-1])
    while len(els) < len(pts):
        els.new(1.0)
    # Elements keep themselves sorted by position: assign from the end so none overtakes another.
    for el, (pos, o) in zip(reversed(els), reversed(pts)):
        el.position = pos
        el.color = (o, o, o, 1.0)


def ramp_tf(node, lo, hi):
    """The transfer function the ramp ``node`` shows over ``[lo, hi]``."""
    if not hi > lo:
        raise ValueError(f"the ramp's range must rise (from {lo:g} to {hi:g})")
    ramp = node.color_ramp
    span = hi - lo
    els = sorted(((e.position, _opacity(e.color)) for e in ramp.elements), key=lambda e: e[0])
    if ramp.interpolation == "LINEAR":
        pts = [(lo + p * span, o) for p, o in els]
    elif ramp.interpolation == "CONSTANT":
        # Each element's opacity holds from its position to the next element's.
        pts = [(lo + els[0][0] * span, els[0][1])]
        for (p, o), (_, o_prev) in zip(els[1:], els[:-1]):
            pts += [(lo + p * span, o_prev), (lo + p * span, o)]
    else:
        xs = [i / (SAMPLES - 1) for i in range(SAMPLES)]
        pts = [(lo + x * span, _opacity(ramp.evaluate(x))) for x in xs]
    return TransferFunction(points=tuple(pts))


__all__ = ["NODE", "new_tree", "ramp_node", "ramp_tf", "set_ramp"]
