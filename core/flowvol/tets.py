"""Layered prisms split into tetrahedra with matching shared faces, and their closed boundary.

Each generator triangle swept from one layer to the next is a triangular
prism.  Every quadrilateral side is cut along the diagonal through its
smallest global vertex index, so the two prisms sharing a side cut it the
same way (Dompierre et al. 1999); each prism then splits into 3 tetrahedra.

References
----------
.. [1] J. Dompierre, P. Labbé, M.-G. Vallet and R. Camarero, "How to subdivide
   pyramids, prisms and hexahedra into tetrahedra", Proc. 8th International
   Meshing Roundtable (1999) 195-204.
.. [2] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
"""

import numpy as np

# Rotations of a prism (bottom 0,1,2 / top 3,4,5) that bring each of its vertices to position 0.
_ROT = np.array([
    [0, 1, 2, 3, 4, 5], [1, 2, 0, 4, 5, 3], [2, 0, 1, 5, 3, 4],
    [3, 5, 4, 0, 2, 1], [4, 3, 5, 1, 0, 2], [5, 4, 3, 2, 1, 0],
])


def split_prisms(prisms):
    """Split prisms (m, 6) of global vertex indices into tetrahedra (3m, 4).

    The side faces are cut along the diagonal through their smallest index,
    so neighbouring prisms agree on their shared face.
    """
    prisms = np.asarray(prisms, dtype=np.int64).reshape(-1, 6)
    if len(prisms) == 0:
        return np.zeros((0, 4), dtype=np.int64)
    v = np.take_along_axis(prisms, _ROT[np.argmin(prisms, axis=1)], axis=1)
    first = np.minimum(v[:, 1], v[:, 5]) < np.minimum(v[:, 2], v[:, 4])
    a = np.stack([v[:, [0, 1, 2, 5]], v[:, [0, 1, 5, 4]], v[:, [0, 4, 5, 3]]], axis=1)
    b = np.stack([v[:, [0, 1, 2, 4]], v[:, [0, 4, 2, 5]], v[:, [0, 4, 5, 3]]], axis=1)
    return np.where(first[:, None, None], a, b).reshape(-1, 4)


def signed_volumes(vertices, tets):
    """Signed volume of each tetrahedron (positive when (b-a, c-a, d-a) is right-handed)."""
    p = np.asarray(vertices, dtype=np.float64)[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def orient(vertices, tets):
    """The tetrahedra with two vertices swapped where needed so every signed volume is >= 0."""
    tets = np.array(tets, dtype=np.int64).reshape(-1, 4)
    neg = signed_volumes(vertices, tets) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3], tets[neg, 2].copy()
    return tets


# Faces of a positively oriented tetrahedron, counter-clockwise seen from outside.
_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def _face_ids(faces):
    """Inverse indices and use counts of the distinct faces (any winding) among ``faces`` (k, 3)."""
    key = np.sort(faces, axis=1)
    n = int(key.max()) + 1 if len(key) else 1
    if n < 2**21:  # one int64 per face: a 1-D unique instead of a row-wise one (several times faster)
        key = (key[:, 0] * n + key[:, 1]) * n + key[:, 2]
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def boundary_faces(tets):
    """Triangles (k, 3) used by exactly one tetrahedron: the closed outer surface, facing out."""
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    faces = tets[:, _FACES].reshape(-1, 3)
    inverse, counts = _face_ids(faces)
    return faces[counts[inverse] == 1]


def face_use_counts(tets):
    """How many tetrahedra use each distinct face (1: boundary, 2: shared)."""
    return _face_ids(np.asarray(tets, dtype=np.int64)[:, _FACES].reshape(-1, 3))[1]


def merge_vertices(tets, target, reference, max_rounds=8):
    """Tetrahedra after merging vertex ``i`` into ``target[i]``, degenerate ones dropped.

    Merging a vertex into a neighbour is an edge collapse: shared faces stay
    shared.  A merge that would invert a tetrahedron or fold two onto one
    face (checked on the ``reference`` positions) is undone, with every
    other merge into the same vertex.
    """
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    target = np.array(target, dtype=np.int64)
    for _ in range(max_rounds):
        t = target[tets]
        s = np.sort(t, axis=1)
        t = t[np.all(s[:, 1:] != s[:, :-1], axis=1)]
        vol = signed_volumes(reference, t)
        inverse, counts = _face_ids(t[:, _FACES].reshape(-1, 3))
        bad = (vol <= 0) | (counts[inverse] > 2).reshape(-1, 4).any(axis=1)
        if not bad.any():
            return t
        undo = np.isin(target, np.unique(t[bad])) & (target != np.arange(len(target)))
        target[undo] = np.nonzero(undo)[0]
    return tets
