"""The fire-in-a-room unstructured grid: cell interpolation against a linear field, a flow volume above the fire."""

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("vtk")

from nephele.core.errors import DataError  # noqa: E402
from nephele.core.flowvol import flow_volume  # noqa: E402
from nephele.core.flowvol.tets import face_use_counts, signed_volumes  # noqa: E402
from nephele.core.flowvol.unstructured import UnstructuredVelocity  # noqa: E402

FIRE = Path(__file__).resolve().parents[4] / "shared" / "data" / "flow" / "fire_ug.vtu"
if not FIRE.is_file():
    FIRE = Path("/work/shared/data/flow/fire_ug.vtu")
pytestmark = pytest.mark.skipif(not FIRE.is_file(), reason="fire_ug.vtu not available")


@pytest.fixture(scope="module")
def fire():
    return UnstructuredVelocity(FIRE)


def test_reads_the_grid_and_reproduces_vertex_vectors(fire):
    assert fire.points.shape == (12323, 3)
    assert np.allclose(fire.bounds, [[0, 6], [0, 2.5], [0, 2.4]], atol=1e-6)
    v = fire(fire.points[::50])
    assert np.allclose(v, fire.vectors[::50], atol=1e-6)


def test_cell_interpolation_is_exact_for_a_linear_field(fire):
    # Linear and trilinear cell functions both reproduce a linear field exactly.
    A = np.array([[0.3, -0.2, 0.1], [0.05, 0.4, -0.3], [-0.1, 0.2, 0.25]])
    saved = fire.vectors.copy()
    arr = fire.grid.GetPointData().GetArray("uvw")
    lin = fire.points @ A.T + [0.1, 0.2, 0.3]
    for i, row in enumerate(lin):
        arr.SetTuple3(i, *row)
    try:
        rng = np.random.default_rng(0)
        q = rng.uniform([0.1, 0.1, 0.1], [5.9, 2.4, 2.3], (300, 3))
        v = fire(q)
        ok = np.all(np.isfinite(v), axis=1)
        assert ok.mean() > 0.9
        assert np.allclose(v[ok], q[ok] @ A.T + [0.1, 0.2, 0.3], atol=1e-5)
    finally:
        for i, row in enumerate(saved):
            arr.SetTuple3(i, *row)


def test_flow_volume_above_the_fire(fire):
    up = (fire.points[:, 2] < 1.0) & (fire.points[:, 0] > 0.5) & (fire.points[:, 0] < 5.5) & (fire.points[:, 1] > 0.3) & (fire.points[:, 1] < 2.2)
    i = np.argmax(np.where(up, fire.vectors[:, 2], -np.inf))
    fv = flow_volume(str(FIRE), fire.points[i] + [0, 0, 0.1], 0.1, 1.0, sides=16, rings=1, steps=8, tol=0.05)
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
