"""Core meshes into Blender through foreach_set: same result as from_pydata, attributes, refills."""

import bpy
import numpy as np
import pytest

from nephele.addon import mesh as bmesh_io
from nephele.core.surface.contour import isosurface, regular_points


def sphere_mesh(n=24):
    x = np.linspace(-1.0, 1.0, n)
    values = (x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2).astype(np.float32)
    pts = regular_points(values.shape, spacing=(x[1] - x[0],) * 3, origin=(-1.0, -1.0, -1.0))
    m = isosurface(pts, values, 0.6, attributes={"r2": values})
    m.attributes["p"] = m.vertices.copy()
    return m


def test_matches_from_pydata():
    m = sphere_mesh()
    me = bmesh_io.new_mesh("fast", m)
    ref = bpy.data.meshes.new("ref")
    ref.from_pydata(m.vertices.tolist(), [], m.faces.tolist())
    ref.update()
    v, f = bmesh_io.mesh_arrays(me)
    rv, rf = bmesh_io.mesh_arrays(ref)
    np.testing.assert_array_equal(v, rv)
    np.testing.assert_array_equal(f, rf)
    assert len(me.edges) == len(ref.edges)
    assert {tuple(sorted(e.vertices)) for e in me.edges} == {tuple(sorted(e.vertices)) for e in ref.edges}
    assert me.validate(verbose=False) is False  # False: nothing had to be fixed
    # A closed sphere: Euler characteristic 2.
    assert len(me.vertices) - len(me.edges) + len(me.polygons) == 2
    assert all(p.use_smooth for p in me.polygons)


def test_attributes():
    m = sphere_mesh()
    n = len(m.vertices)
    m.attributes["rgba"] = np.tile(np.array([0.1, 0.2, 0.3, 1.0], np.float32), (n, 1))
    m.attributes["five"] = np.arange(5 * n, dtype=np.float32).reshape(n, 5)
    me = bmesh_io.new_mesh("attrs", m)
    assert me.attributes["r2"].data_type == "FLOAT" and me.attributes["r2"].domain == "POINT"
    np.testing.assert_allclose(bmesh_io.point_attribute(me, "r2"), m.attributes["r2"])
    assert me.attributes["p"].data_type == "FLOAT_VECTOR"
    np.testing.assert_allclose(bmesh_io.point_attribute(me, "p"), m.vertices, atol=1e-6)
    assert me.attributes["rgba"].data_type == "FLOAT_COLOR"
    for c in range(5):
        np.testing.assert_array_equal(bmesh_io.point_attribute(me, f"five_{c}"), m.attributes["five"][:, c])


def test_refill_keeps_materials_and_drops_old_geometry():
    me = bmesh_io.new_mesh("refill", sphere_mesh(24))
    mat = bpy.data.materials.new("keep")
    me.materials.append(mat)
    small = sphere_mesh(10)
    bmesh_io.fill_mesh(me, small)
    assert len(me.vertices) == len(small.vertices) and len(me.polygons) == len(small.faces)
    assert me.materials[0] == mat
    assert "r2" in me.attributes
    bmesh_io.fill_mesh(me, (small.vertices, small.faces))  # no attributes this time
    assert "r2" not in me.attributes
    bmesh_io.fill_mesh(me, (np.zeros((0, 3)), np.zeros((0, 3), int)))
    assert len(me.vertices) == 0 and len(me.polygons) == 0 and me.materials[0] == mat


def test_flat_shading_and_bad_input():
    m = sphere_mesh(10)
    me = bmesh_io.new_mesh("flat", m, smooth=False)
    assert not any(p.use_smooth for p in me.polygons)
    bad = m.vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        bmesh_io.new_mesh("nan", (bad, m.faces))
    faces = m.faces.copy()
    faces[0, 0] = len(m.vertices)
    with pytest.raises(ValueError, match="outside"):
        bmesh_io.new_mesh("idx", (m.vertices, faces))
    with pytest.raises(ValueError, match="values for"):
        bmesh_io.set_point_attribute(me, "short", np.zeros(3))
