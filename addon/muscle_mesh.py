"""Blobby molecule meshes and tail cylinders into Blender meshes.

Core meshes are in nanometres; :data:`SCALE` Blender units per nanometre puts
a 214.5 nm cell at about 21 m, a size at which Cycles' ray offsets and the
viewport clip range need no tuning.  Vertices and triangles go in with
``foreach_set`` (:mod:`.mesh`); the analytic normals of the Gaussian sum
become custom normals, and the per-vertex ids (``blob``, ``part``,
``molecule``) integer point attributes a material can colour by.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (molecules as contour surfaces of sums of Gaussian ellipsoids).
"""

import bpy
import numpy as np

from .mesh import fill_mesh

SCALE = 0.1
"""Blender units per nanometre."""


def fill_blobby(me, mesh, *, scale=SCALE):
    """Replace ``me``'s geometry by the core blobby ``mesh`` (nm), scaled to Blender units.

    Integer per-vertex attributes stay integers (``INT`` point attributes);
    float ones become float attributes as in :func:`.mesh.fill_mesh`.  The
    normals are the field's analytic gradient directions, set as custom normals.
    """
    ints = {k: v for k, v in mesh.attributes.items() if np.asarray(v).dtype.kind in "iub" and np.ndim(v) == 1}
    floats = {k: v for k, v in mesh.attributes.items() if k not in ints}
    fill_mesh(me, (np.asarray(mesh.vertices, np.float32) * np.float32(scale), mesh.faces, floats), smooth=True)
    for name, values in ints.items():
        old = me.attributes.get(name)
        if old is not None:
            me.attributes.remove(old)
        attr = me.attributes.new(name, "INT", "POINT")
        attr.data.foreach_set("value", np.ascontiguousarray(values, dtype=np.int32))
    if len(mesh.vertices):
        me.normals_split_custom_set_from_vertices(np.ascontiguousarray(mesh.normals, dtype=np.float32))
    return me


def blobby_object(name, mesh, *, scale=SCALE, collection=None, material=None):
    """A new object holding the blobby ``mesh`` (see :func:`fill_blobby`), linked into ``collection``."""
    me = fill_blobby(bpy.data.meshes.new(name), mesh, scale=scale)
    if material is not None:
        me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def int_attribute(me, name):
    """An ``INT`` point attribute of ``me`` as an int32 array."""
    attr = me.attributes[name]
    out = np.empty(len(attr.data), np.int32)
    attr.data.foreach_get("value", out)
    return out


def custom_normals(me):
    """Per-corner normals of ``me`` (m*3, 3), custom ones where set."""
    out = np.empty(len(me.loops) * 3, np.float32)
    me.corner_normals.foreach_get("vector", out)
    return out.reshape(-1, 3)
