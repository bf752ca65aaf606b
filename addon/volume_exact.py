"""Exact volume shading in Blender: the node graph that evaluates the atlases.

:mod:`nephele.core.volume.volume_atlas` describes the program and
:mod:`nephele.volume_files` writes its data where Blender loads it natively
(the heights and values atlases as EXR images, the ``support`` grid per frame
as the volume object's ``.vdb`` sequence: it bounds where Cycles looks and
masks the density); this module builds the same program from shader nodes.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

import math

from ..core.volume.volume_atlas import INDEX_EDGE, PAD, VALID, tf_ramps
from ..volume_files import SUPPORT
from .nodes import Nodes


class _Nodes(Nodes):
    """:class:`.nodes.Nodes` plus the atlas program's piecewise maps and image lookups."""

    def piecewise(self, x, runs, label):
        """Σ of clamped ramps (:func:`nephele.core.volume.volume_atlas.axis_runs`)."""
        return self.add_all([self.map_range(x, x0, x1, 0.0, i1 - i0, label=label) for x0, x1, i0, i1 in runs],
                            label=label)

    def lookup(self, image, u, v, periodic, label):
        """Linear lookup of ``image`` at ``(u, v)``: ``(r, g, b, a)`` sockets."""
        uv = self._place(self.tree.nodes.new("ShaderNodeCombineXYZ"))
        self._set(uv.inputs["X"], u)
        self._set(uv.inputs["Y"], v)
        tex = self._place(self.tree.nodes.new("ShaderNodeTexImage"), label)
        tex.name = label
        tex.image = image
        tex.interpolation = "Linear"
        tex.extension = "REPEAT" if periodic else "EXTEND"
        self.tree.links.new(uv.outputs["Vector"], tex.inputs["Vector"])
        sep = self._place(self.tree.nodes.new("ShaderNodeSeparateColor"))
        self.tree.links.new(tex.outputs["Color"], sep.inputs["Color"])
        return sep.outputs[0], sep.outputs[1], sep.outputs[2], tex.outputs["Alpha"]


def field_nodes(tree, layout, values_image, heights_image, *, below, color_altitude, index_image=None,
                location=(-3200, 0)):
    """The program of :meth:`nephele.core.volume.volume_atlas.AtlasLayout.shade` as shader nodes.

    ``layout``: :meth:`AtlasLayout.to_dict`; ``index_image``: a curvilinear
    grid's :class:`~nephele.core.volume.volume_atlas.IndexMap` image.  Returns
    sockets ``(value, colour, ok)``; ``ok`` is 1 where the density may be
    non-zero (inside the grid, all corners present, in the support), else 0.
    """
    L = layout
    g = _Nodes(tree, *location)
    coord = g._place(tree.nodes.new("ShaderNodeTexCoord"))
    sep = g._place(tree.nodes.new("ShaderNodeSeparateXYZ"))
    tree.links.new(coord.outputs["Object"], sep.inputs["Vector"])
    x, y, z = sep.outputs["X"], sep.outputs["Y"], sep.outputs["Z"]
    deg = 180.0 / math.pi
    lon = g.math("MULTIPLY_ADD", g.math("ARCTAN2", y, x), deg, -L["lon0"], label="longitude")
    rxy = g.math("SQRT", g.math("MULTIPLY_ADD", x, x, g.math("MULTIPLY", y, y)))
    lat = g.math("MULTIPLY", g.math("ARCTAN2", z, rxy), deg, label="latitude")
    length = g._place(tree.nodes.new("ShaderNodeVectorMath"))
    length.operation = "LENGTH"
    tree.links.new(coord.outputs["Object"], length.inputs[0])
    a = 6_371_000.0 / (L["radius"] * L["exaggeration"])
    h = g.math("MULTIPLY_ADD", length.outputs["Value"], a, -6_371_000.0 / L["exaggeration"], label="height")
    inside = []
    W, nk, tile = L["width"], L["nk"], L["rows"] + 2 * PAD
    if L.get("index"):
        col, row, front = _index_nodes(g, coord.outputs["Object"], L["index"], index_image)
        e = INDEX_EDGE
        inside += [front, g.math("GREATER_THAN", col, -e), g.math("LESS_THAN", col, W - 1 + e),
                   g.math("GREATER_THAN", row, -e), g.math("LESS_THAN", row, L["rows"] - 1 + e)]
        # Outside, the clamp keeps the lookups below inside their own tiles.
        col = g.math("MINIMUM", g.math("MAXIMUM", col, 0.0), W - 1, label="column")
        row = g.math("MINIMUM", g.math("MAXIMUM", row, 0.0), L["rows"] - 1, label="row")
    else:
        # Relative longitude in [0, 360) for every grid: a regional grid may straddle ±180°.
        lon = g.math("FLOORED_MODULO", lon, 360.0)
        if not L["periodic"]:
            inside += [g.math("GREATER_THAN", lon, L["lon_range"][0]), g.math("LESS_THAN", lon, L["lon_range"][1])]
        if not (L["lat_range"][0] <= -90.0 and L["lat_range"][1] >= 90.0):
            inside += [g.math("GREATER_THAN", lat, L["lat_range"][0]), g.math("LESS_THAN", lat, L["lat_range"][1])]
        col = g.piecewise(lon, L["lon_runs"], "column")
        row = g.piecewise(lat, L["lat_runs"], "row")
    periodic = L["periodic"]
    u = g.math("MULTIPLY_ADD", col, 1.0 / W, 0.5 / W, label="u")
    hrows = ((nk + 3) // 4) * tile
    levels = []
    for m in range((nk + 3) // 4):
        v = g.math("MULTIPLY_ADD", row, 1.0 / hrows, (m * tile + PAD + 0.5) / hrows)
        levels.extend(g.lookup(heights_image, u, v, periodic, f"Nephele heights {m}"))
    levels = levels[:nk]
    index = g.add_all([g.map_range(h, levels[k], levels[k + 1], 0.0, 1.0, label="level") for k in range(nk - 1)],
                      label="level")
    inside += [g.math("GREATER_THAN", h, g.math("SUBTRACT", levels[0], below)), g.math("LESS_THAN", h, levels[-1])]
    k0 = g.math("MINIMUM", g.math("FLOOR", index), nk - 2)
    f = g.math("SUBTRACT", index, k0, label="level fraction")
    vrows = nk * tile
    t = g.math("MULTIPLY_ADD", row, 1.0 / vrows, (PAD + 0.5) / vrows)
    va = g.math("MULTIPLY_ADD", k0, tile / vrows, t)
    vb = g.math("ADD", va, tile / vrows)
    A = g.lookup(values_image, u, va, periodic, "Nephele values below")
    B = g.lookup(values_image, u, vb, periodic, "Nephele values above")
    value = g.math("MULTIPLY_ADD", f, g.math("SUBTRACT", B[0], A[0]), A[0], label="value")
    color = h if color_altitude else g.math("MULTIPLY_ADD", f, g.math("SUBTRACT", B[1], A[1]), A[1], label="colour")
    inside.append(g.math("GREATER_THAN", g.math("MINIMUM", A[2], B[2]), VALID))
    attr = g._place(tree.nodes.new("ShaderNodeAttribute"), "support")
    attr.attribute_name = SUPPORT
    inside.append(g.math("GREATER_THAN", attr.outputs["Fac"], 0.0))
    ok = inside[0]
    for m in inside[1:]:
        ok = g.math("MULTIPLY", ok, m, label="inside")
    return value, color, ok


def _index_nodes(g, position, index, image):
    """:meth:`IndexMap.lookup` as nodes: ``(column, row, front)`` sockets."""
    q = [g.vmath("DOT_PRODUCT", position, tuple(b)) for b in index["basis"]]
    front = g.math("GREATER_THAN", q[2], 0.0)
    z = g.math(
        "MULTIPLY_ADD", g.math("SUBTRACT", 1.0, front), 1.0, g.math("MULTIPLY", q[2], front)
    )  # 1 behind the globe
    (x0, y0), (x1, y1) = index["lo"], index["hi"]
    u = g.math("MULTIPLY_ADD", g.math("DIVIDE", q[0], z), 1.0 / (x1 - x0), -x0 / (x1 - x0))
    v = g.math("MULTIPLY_ADD", g.math("DIVIDE", q[1], z), 1.0 / (y1 - y0), -y0 / (y1 - y0))
    col, row, _, _ = g.lookup(image, u, v, False, "Nephele column index")
    return col, row, front


def tf_nodes(tree, value, tf, location=(-600, 300)):
    """The transfer function of ``value`` as clamped ramps and steps: the opacity socket."""
    g = _Nodes(tree, *location)
    offset, parts = tf_ramps(tf)
    # A step takes its upper value at the step (value >= a), as np.interp does.
    terms = [g.math("MULTIPLY", g.math("SUBTRACT", 1.0, g.math("LESS_THAN", value, a)), rise, label="transfer function")
             if kind == "step"
             else g.map_range(value, a, b, 0.0, rise, label="transfer function") for kind, a, b, rise in parts]
    if not terms:
        return g.math("ADD", offset, 0.0, label="transfer function")
    total = g.add_all(terms, label="transfer function")
    return g.math("ADD", total, offset, label="transfer function") if offset else total


__all__ = ["field_nodes", "tf_nodes"]
