"""The Mesh container: validation, normals, npz cache and exports."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.surface.contour import isosurface, regular_points
from nephele.core.surface.mesh import Mesh, triangle_areas, vertex_normals


def tetrahedron():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward
    return v, f


def test_vertex_normals_are_unit_area_weighted_and_outward():
    v, f = tetrahedron()
    n = vertex_normals(v, f)
    assert np.allclose(np.linalg.norm(n, axis=1), 1)
    # Corner at the origin: three faces of equal area, normals -x, -y, -z.
    assert np.allclose(n[0], -np.ones(3) / np.sqrt(3), atol=1e-6)
    # Vertex 1 touches faces -y, -z (area 1/2 each) and the slanted face (area sqrt(3)/2).
    expect = np.array([0, -0.5, -0.5]) + np.sqrt(3) / 2 * np.ones(3) / np.sqrt(3)
    assert np.allclose(n[1], expect / np.linalg.norm(expect), atol=1e-6)
    assert triangle_areas(v, f).sum() == pytest.approx(1.5 + np.sqrt(3) / 2)


def test_validation_and_empty():
    v, f = tetrahedron()
    with pytest.raises(DataError):
        Mesh(v, f + 1, vertex_normals(v, f))
    with pytest.raises(DataError):
        Mesh(v, f, np.zeros((3, 3)))
    with pytest.raises(DataError) as err:
        Mesh(v, f, vertex_normals(v, f), {"alt": np.zeros(5)})
    assert err.value.field == "alt"
    e = Mesh.empty(["alt"])
    assert e.is_empty and e.vertices.dtype == np.float32 and e.faces.dtype == np.int32
    assert e.attributes["alt"].shape == (0,)
    assert e.area() == 0.0


def test_npz_round_trip_without_pickle(tmp_path):
    p = regular_points((8, 9, 10), spacing=(0.2, 0.2, 0.2))
    v = np.linalg.norm(p - 0.8, axis=-1)
    mesh = isosurface(p, v, 0.5, attributes={"alt": p[..., 2]})
    path = mesh.save_npz(tmp_path / "m.npz")
    back = Mesh.load_npz(path)
    for name in ("vertices", "faces", "normals"):
        assert np.array_equal(getattr(back, name), getattr(mesh, name))
    assert np.array_equal(back.attributes["alt"], mesh.attributes["alt"])
    with np.load(path, allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["m.npz"]  # no temp file left
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(DataError):
        Mesh.load_npz(tmp_path / "other.npz")
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError):
        Mesh.load_npz(tmp_path / "broken.npz")


@pytest.mark.parametrize("ext", [".ply", ".glb", ".obj"])
def test_export_formats(tmp_path, ext):
    trimesh = pytest.importorskip("trimesh")
    p = regular_points((8, 9, 10), spacing=(0.2, 0.2, 0.2))
    mesh = isosurface(p, np.linalg.norm(p - 0.8, axis=-1), 0.5)
    out = mesh.save(tmp_path / f"cloud{ext}")
    assert [x.name for x in tmp_path.iterdir()] == [f"cloud{ext}"]
    back = trimesh.load(out, force="mesh", process=False)
    assert back.vertices.shape == mesh.vertices.shape
    assert np.array_equal(np.sort(back.faces, axis=None), np.sort(mesh.faces, axis=None))
    assert back.area == pytest.approx(mesh.area(), rel=1e-5)


def test_export_refuses_unknown_format(tmp_path):
    v, f = tetrahedron()
    with pytest.raises(DataError) as err:
        Mesh(v, f, vertex_normals(v, f)).save(tmp_path / "x.stl2")
    assert "x.stl2" in str(err.value)
    assert not list(tmp_path.iterdir())
