"""Core meshes into Blender meshes, fast: bulk ``foreach_set`` on attribute arrays.

``from_pydata`` builds Python tuples for every vertex and corner and takes
~4 s for a million triangles; writing the ``position`` and ``.corner_vert``
attributes and the ``loop_start`` of the faces straight from NumPy buffers and
letting Blender derive the edges takes well under a second (see
docs/benchmarks.md, section ``mesh_transfer``).
"""

import bpy
import numpy as np

_VECTOR_TYPES = {1: ("FLOAT", "value"), 2: ("FLOAT2", "vector"), 3: ("FLOAT_VECTOR", "vector"),
                 4: ("FLOAT_COLOR", "color")}


def _as_arrays(mesh):
    """``(vertices, faces, attributes)`` from a core ``Mesh`` or a plain tuple."""
    if isinstance(mesh, tuple):
        vertices, faces, *rest = mesh
        attributes = rest[0] if rest else {}
    else:
        vertices, faces = mesh.vertices, mesh.faces
        attributes = getattr(mesh, "attributes", None) or {}
    vertices = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"face indices outside 0..{len(vertices) - 1}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("vertices contain NaN or infinite coordinates")
    return vertices, faces, attributes


def fill_mesh(me, mesh, *, smooth=True):
    """Replace the geometry of the Blender mesh ``me`` by ``mesh``, keeping its materials.

    Parameters
    ----------
    me : bpy.types.Mesh
    mesh : nephele.core.surface.mesh.Mesh or tuple
        ``vertices`` (n, 3), ``faces`` (m, 3) triangles and ``attributes``
        (name -> (n,) or (n, k) per-vertex arrays), or a tuple
        ``(vertices, faces[, attributes])``.
    smooth : bool
        Smooth shading (vertex normals interpolated across faces).

    Returns
    -------
    bpy.types.Mesh
        ``me``.  Per-vertex attributes become point-domain attributes: (n,)
        floats, (n, 2) ``FLOAT2``, (n, 3) ``FLOAT_VECTOR``, (n, 4)
        ``FLOAT_COLOR``; other widths are split into ``name_0``, ``name_1``...
    """
    vertices, faces, attributes = _as_arrays(mesh)
    me.clear_geometry()
    nv, nf = len(vertices), len(faces)
    if nv:
        me.vertices.add(nv)
        me.attributes["position"].data.foreach_set("vector", vertices.ravel())
    if nf:
        me.loops.add(3 * nf)
        me.polygons.add(nf)
        me.attributes[".corner_vert"].data.foreach_set("value", faces.ravel())
        me.polygons.foreach_set("loop_start", np.arange(0, 3 * nf, 3, dtype=np.int32))
    for name, values in attributes.items():
        set_point_attribute(me, name, values)
    me.update(calc_edges=True)
    if nf:
        # Meshes built this way are smooth already (no "sharp_face" attribute);
        # shade_flat() adds it.
        if smooth:
            me.shade_smooth()
        else:
            me.shade_flat()
    return me


def set_point_attribute(me, name, values):
    """Store per-vertex ``values`` ((n,) or (n, k)) as float attribute(s) on ``me``."""
    values = np.asarray(values, dtype=np.float32)
    n = len(me.vertices)
    if values.shape[0] != n:
        raise ValueError(f"attribute {name!r} has {values.shape[0]} values for {n} vertices")
    values = values.reshape(n, 1) if values.ndim == 1 else values.reshape(n, int(np.prod(values.shape[1:])))
    k = values.shape[1]
    if k not in _VECTOR_TYPES:
        for c in range(k):
            set_point_attribute(me, f"{name}_{c}", values[:, c])
        return
    kind, key = _VECTOR_TYPES[k]
    old = me.attributes.get(name)
    if old is not None:
        me.attributes.remove(old)
    attr = me.attributes.new(name, kind, "POINT")
    attr.data.foreach_set(key, np.ascontiguousarray(values).ravel())


def point_attribute(me, name):
    """A point attribute of ``me`` as a NumPy array ((n,) or (n, k))."""
    attr = me.attributes[name]
    kind, key = {v[0]: v for v in _VECTOR_TYPES.values()}[attr.data_type]
    k = {v[0]: w for w, v in _VECTOR_TYPES.items()}[kind]
    out = np.empty(len(attr.data) * k, dtype=np.float32)
    attr.data.foreach_get(key, out)
    return out if k == 1 else out.reshape(-1, k)


def mesh_arrays(me):
    """``(vertices (n, 3) float32, faces (m, 3) int32)`` of a triangle mesh ``me``."""
    v = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.attributes["position"].data.foreach_get("vector", v)
    f = np.empty(len(me.loops), dtype=np.int32)
    me.attributes[".corner_vert"].data.foreach_get("value", f)
    return v.reshape(-1, 3), f.reshape(-1, 3)


def new_mesh(name, mesh, *, smooth=True):
    """A new ``bpy.types.Mesh`` named ``name`` holding ``mesh`` (see :func:`fill_mesh`)."""
    return fill_mesh(bpy.data.meshes.new(name), mesh, smooth=smooth)


def new_object(name, mesh, *, collection=None, smooth=True):
    """A new object with a new mesh, linked into ``collection`` (default: the scene's)."""
    obj = bpy.data.objects.new(name, new_mesh(name, mesh, smooth=smooth))
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def select_only(context, obj):
    """Blender's convention: the new object alone selected and active."""
    for o in list(context.view_layer.objects.selected):
        if o is not None:  # None: an object this operator replaced
            o.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
