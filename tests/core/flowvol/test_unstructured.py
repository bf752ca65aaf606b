"""The fire-in-a-room unstructured grid: our reader and trilinear cells against VTK, a linear field, a flow
volume above the fire."""

from pathlib import Path

import numpy as np
import pytest
from mesh_checks import check_mesh

from nephele.core.errors import DataError
from nephele.core.flowvol import flow_volume
from nephele.core.flowvol.tets import face_use_counts, signed_volumes
from nephele.core.flowvol.unstructured import UnstructuredVelocity, read_vtu

FIRE = Path(__file__).resolve().parents[2] / "data" / "flow" / "fire_ug.vtu"


@pytest.fixture(scope="module")
def fire():
    return UnstructuredVelocity(FIRE)


def test_reads_the_grid_and_reproduces_vertex_vectors(fire):
    assert fire.points.shape == (12323, 3)
    assert np.allclose(fire.bounds, [[0, 6], [0, 2.5], [0, 2.4]], atol=1e-6)
    v = fire(fire.points[::50])
    assert np.allclose(v, fire.vectors[::50], atol=1e-6)


def test_reader_equals_vtk_arrays_exactly():
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(FIRE))
    r.Update()
    grid, ours = r.GetOutput(), read_vtu(FIRE)
    assert len(ours["types"]) == 10462 and np.all(ours["types"] == 12)
    assert np.array_equal(ours["points"], vtk_to_numpy(grid.GetPoints().GetData()))
    assert np.array_equal(ours["connectivity"], vtk_to_numpy(grid.GetCells().GetConnectivityArray()))
    assert np.array_equal(ours["offsets"], vtk_to_numpy(grid.GetCells().GetOffsetsArray())[1:])
    for name in ("uvw", "t", "u", "v", "w", "mfrac"):
        ref = vtk_to_numpy(grid.GetPointData().GetArray(name))
        assert ours["point_data"][name].dtype == np.float32
        assert np.array_equal(ours["point_data"][name], ref)


def test_trilinear_cells_match_vtk_cell_location_and_shape_functions(fire):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import numpy_to_vtk

    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(FIRE))
    r.Update()
    grid = r.GetOutput()
    locator = vtk.vtkStaticCellLocator()
    locator.SetDataSet(grid)
    locator.BuildLocator()
    rng = np.random.default_rng(1)
    q = rng.uniform(fire.bounds[:, 0] - 0.1, fire.bounds[:, 1] + 0.1, (2000, 3))
    ref = np.full((len(q), 3), np.nan)
    cell = vtk.vtkGenericCell()
    for i, p in enumerate(q):
        pc, w = [0.0] * 3, [0.0] * 8
        if locator.FindCell(p, 0.0, cell, pc, w) >= 0:
            ref[i] = np.array(w) @ fire.vectors[[cell.GetPointId(j) for j in range(8)]]
    got = fire(q)
    inside = np.isfinite(ref).all(axis=1)
    assert np.array_equal(np.isfinite(got).all(axis=1), inside) and 0.5 < inside.mean() < 0.95
    rel = np.linalg.norm(got[inside] - ref[inside], axis=1) / np.maximum(np.linalg.norm(ref[inside], axis=1), 1e-3)
    assert rel.max() < 1e-5  # measured 2e-14
    # vtkProbeFilter searches cells with a tolerance and at a few points near cell faces
    # interpolates in a neighbouring cell (measured: 20 of 4097 points off by up to 2e-3).
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(q), deep=1))
    pd = vtk.vtkPolyData()
    pd.SetPoints(pts)
    probe = vtk.vtkProbeFilter()
    probe.SetInputData(pd)
    probe.SetSourceData(grid)
    probe.Update()
    from vtk.util.numpy_support import vtk_to_numpy

    pv = vtk_to_numpy(probe.GetOutput().GetPointData().GetArray("uvw")).astype(np.float64)[inside]
    prel = np.linalg.norm(got[inside] - pv, axis=1) / np.maximum(np.linalg.norm(pv, axis=1), 1e-3)
    assert np.mean(prel < 1e-5) > 0.99


def test_cell_interpolation_is_exact_for_a_linear_field(fire):
    # Trilinear cell functions reproduce a linear field exactly.
    A = np.array([[0.3, -0.2, 0.1], [0.05, 0.4, -0.3], [-0.1, 0.2, 0.25]])
    saved = fire.vectors
    fire.vectors = fire.points @ A.T + [0.1, 0.2, 0.3]
    try:
        rng = np.random.default_rng(0)
        q = rng.uniform([0.1, 0.1, 0.1], [5.9, 2.4, 2.3], (300, 3))
        v = fire(q)
        ok = np.all(np.isfinite(v), axis=1)
        assert ok.mean() > 0.9
        assert np.allclose(v[ok], q[ok] @ A.T + [0.1, 0.2, 0.3], atol=1e-9)
    finally:
        fire.vectors = saved


def test_flow_volume_above_the_fire(fire):
    up = ((fire.points[:, 2] < 1.2) & (fire.points[:, 0] > 0.3) & (fire.points[:, 0] < 5.7)
          & (fire.points[:, 1] > 0.3) & (fire.points[:, 1] < 2.2))
    i = np.argmax(np.where(up, fire.vectors[:, 2], -np.inf))
    assert np.allclose(fire.updraft(0.1), fire.points[i] + [0, 0, 0.1])
    fv = flow_volume(str(FIRE), fire.updraft(0.1), 0.1, 1.0, sides=16, rings=1, steps=8, tol=0.05)
    assert fv.complete and fv.volume > 0
    assert fv.normal[2] > 0.5  # the generator faces the rising plume
    assert np.all(signed_volumes(fv.vertices, fv.tets) > -1e-12)
    assert np.all(face_use_counts(fv.tets) <= 2)


def test_outside_the_room_and_bad_files_raise(fire, tmp_path):
    with pytest.raises(DataError, match="NaN"):
        flow_volume(fire, [10.0, 1.0, 1.0], 0.1, 1.0, normal=[1, 0, 0])
    with pytest.raises(DataError, match="no such file"):
        UnstructuredVelocity(tmp_path / "missing.vtu")
    with pytest.raises(DataError, match="nope"):
        UnstructuredVelocity(FIRE, field="nope")
    (tmp_path / "bad.vtu").write_text("<VTKFile type='PolyData'></VTKFile>")
    with pytest.raises(DataError, match="unstructured grid"):
        UnstructuredVelocity(tmp_path / "bad.vtu")
    (tmp_path / "junk.vtu").write_text("not xml")
    with pytest.raises(DataError, match="not VTK XML"):
        UnstructuredVelocity(tmp_path / "junk.vtu")


@pytest.mark.parametrize("steady", [False, True], ids=["per-layer", "stream-tube"])
def test_smoke_in_a_bounded_uniform_flow_stops_at_the_wall(steady):
    # Uniform flow along x in the box [0, 1]^3 (NaN outside): air released before t = 1.2 reaches x = 1.
    def box(p, t):
        v = np.tile([1.0, 0.0, 0.0], (len(p), 1))
        v[np.any((p < 0) | (p > 1), axis=1)] = np.nan
        return v

    box.bounded = True
    tol = 0.05
    fv = flow_volume(box, [0.2, 0.5, 0.5], 0.1, 2.0, normal=[1, 0, 0], sides=8, rings=1, steps=4, tol=tol,
                     steady=steady)
    assert fv.complete and fv.exited.any() and not fv.exited.all()
    assert np.allclose(fv.vertices[fv.exited, 0], 1.0, atol=1e-5)  # each rests at its exit point on the wall
    assert np.all(fv.vertices[fv.exited, 0] <= 1.0)
    assert np.all(fv.age[fv.exited] >= 0.8 - 1e-6)  # only air older than the way to the wall left
    assert not fv.exited[np.unique(fv.tets)].any()
    area = 0.5 * 8 * 0.1**2 * np.sin(2 * np.pi / 8)
    # The tube from the generator to the wall (0.8 long), ending one lattice step (< tol) before the last
    # layer inside: at worst 2 tol short (the stream tube's layers fall on 0.7 exactly; 1e-12 for rounding).
    assert area * (0.8 - 2 * tol) * (1 - 1e-12) <= fv.volume < area * 0.8
    check_mesh(fv, positive=True)


def test_smoke_that_leaves_the_room_stops_there(fire):
    # Three seconds of smoke above the fire: some of it leaves the room (refused before: NaN velocities).
    fv = flow_volume(fire, fire.updraft(0.1), 0.1, 3.0, sides=16, rings=1, steps=8, tol=0.1)
    assert fv.complete and fv.exited.any() and (~fv.exited).any() and fv.volume > 0
    lo, hi = fire.bounds[:, 0], fire.bounds[:, 1]
    assert np.all((fv.vertices >= lo) & (fv.vertices <= hi))
    assert np.all(np.isfinite(fire(fv.vertices)))  # every point, exit points too, lies in a cell of the grid
    assert not fv.exited[np.unique(fv.tets)].any()
    check_mesh(fv, positive=True)
    with pytest.raises(DataError, match="outside"):  # a generator outside the room is still refused
        flow_volume(fire, [10.0, 1.0, 1.0], 0.1, 1.0, normal=[1, 0, 0])


def test_newton_path_for_general_hexahedra_agrees_with_the_affine_inversion(fire):
    # The fire's cells are boxes (inverted exactly); treated as general hexahedra they take Newton's method.
    general = UnstructuredVelocity(FIRE)
    general._affine[:] = False
    q = np.random.default_rng(0).uniform(fire.bounds[:, 0] - 0.05, fire.bounds[:, 1] + 0.05, (2000, 3))
    (c1, r1), (c2, r2) = fire.locate(q), general.locate(q)
    ok = c1 >= 0
    assert np.array_equal(ok, c2 >= 0) and 0.5 < ok.mean() < 0.99
    assert np.array_equal(c1[ok], c2[ok]) and np.abs(r1[ok] - r2[ok]).max() < 1e-9
