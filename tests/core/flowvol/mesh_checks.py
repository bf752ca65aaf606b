"""Mesh checks shared by the flow volume tests."""

import numpy as np
import pytest
import trimesh

from nephele.core.flowvol.tets import face_use_counts, signed_volumes


def check_mesh(fv, positive=False):
    """Tetrahedra not inverted (``positive``: none flat either), shared faces matched, and a closed,
    consistently wound surface whose enclosed volume is the tetrahedra's; the tets' signed volumes."""
    vol = signed_volumes(fv.vertices, fv.tets)
    assert np.all(vol > 0) if positive else np.all(vol >= -1e-12 * max(vol.max(), 1e-300))
    assert np.all(face_use_counts(fv.tets) <= 2)
    f = fv.surface.faces.astype(np.int64)
    # Closed and consistently wound: every directed edge appears once and its reverse once
    # (edge (a, b) as the key a n + b: the sorted keys are distinct, and reversing every edge
    # gives the same set back).
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = int(f.max()) + 1
    key = np.sort(edges[:, 0] * n + edges[:, 1])
    assert np.all(key[1:] != key[:-1])
    assert np.array_equal(np.sort(key % n * n + key // n), key)
    # The divergence theorem on the surface gives the tets' volume back.
    v = fv.surface.vertices.astype(np.float64)[f]
    assert np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6 == pytest.approx(fv.volume, rel=1e-5)
    m = trimesh.Trimesh(v.reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3), process=False)
    m.merge_vertices()
    assert m.is_watertight and m.is_winding_consistent
    return vol
