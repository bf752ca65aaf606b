"""Exact volume shading in Blender: atlas images, a support VDB and the node graph.

:mod:`nephele.core.volume.volume_atlas` describes the program; this module writes
its data where Blender loads it natively and builds the same program from
shader nodes:

* ``<prefix>_heights.exr`` — the heights atlas (one file, the grid is fixed);
* ``<prefix>_0001.exr`` … — the values atlas per frame, an image sequence;
* ``<prefix>_0001.vdb`` … — the ``support`` grid per frame (1 in the voxels
  that may hold cloud), the volume object's sequence: it bounds where Cycles
  looks and masks the density.

Files are 32-bit float OpenEXR (OpenImageIO, bundled with Blender), written
to a temporary name and renamed.  Image rows are stored top-down in EXR and
bottom-up in Blender, so atlas row 0 is written last.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

import math
from pathlib import Path

import numpy as np

from ..core.volume.volume_atlas import INDEX_EDGE, PAD, VALID, tf_ramps
from ..fileio import block_grid, oiio, write_image, write_vdb
from .nodes import Nodes

SUPPORT = "support"
"""Name of the support grid."""


def write_exr(path, img, metadata=None):
    """Write an ``(h, w, 4)`` float32 atlas as a 32-bit float EXR (row 0 at the bottom, as Blender reads it)."""
    return write_image(path, np.asarray(img, np.float32)[::-1], pixel_type="float", metadata=metadata,
                       compression="zip")


def read_exr(path):
    """An atlas written by :func:`write_exr`, row 0 at the bottom, and its metadata."""
    io = oiio()
    inp = io.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"{path}: cannot read EXR: {io.geterror()}")
    spec = inp.spec()
    img = inp.read_image("float")
    meta = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    return np.asarray(img, np.float32)[::-1], meta


def exr_key(path):
    """The ``nephele_key`` metadata of an EXR (None if absent or unreadable)."""
    if not Path(path).is_file():
        return None
    try:
        io = oiio()
        inp = io.ImageInput.open(str(path))
        if inp is None:
            io.geterror()  # clear it: OpenImageIO complains at exit about unread errors
            return None
        key = inp.spec().get_string_attribute("nephele_key") or None
        inp.close()
        return key
    except (OSError, RuntimeError):
        return None


def write_support(path, support, support_size, metadata=None):
    """The ``support`` grid (1 in every voxel of ``support`` (n, 3)) as a ``.vdb``, atomically."""
    B = 8
    vox = np.asarray(support, np.int64).reshape(-1, 3)
    blocks, inverse = np.unique(np.floor_divide(vox, B), axis=0, return_inverse=True)
    data = np.zeros((blocks.shape[0], B, B, B), np.float32)
    loc = vox - blocks[inverse.reshape(-1)] * B
    data[inverse.reshape(-1), loc[:, 0], loc[:, 1], loc[:, 2]] = 1.0
    return write_vdb(path, [block_grid(SUPPORT, blocks, data, B, support_size)], metadata or {})


# ------------------------------------------------------------------ the node graph


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
    z = g.math("MULTIPLY_ADD", g.math("SUBTRACT", 1.0, front), 1.0, g.math("MULTIPLY", q[2], front))  # 1 behind the globe
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


__all__ = ["SUPPORT", "exr_key", "field_nodes", "read_exr", "tf_nodes", "write_exr", "write_support"]
