"""Lookup tables for contouring a hexahedral cell, generated (not typed in).

Local corner ``c = di + 2*dj + 4*dk`` sits at offset ``(di, dj, dk)`` along
the grid axes ``(i, j, k)``.  A local *edge* is one of the 28 corner pairs
(:data:`PAIRS`): the 12 cube edges, 12 face diagonals and 4 body diagonals.
A cell's configuration is ``sum(2**c for corners with value >= level)``.

Marching cubes (Lorensen & Cline 1987) needs a rule for the ambiguous faces
(two diagonal corners above the level, two below).  The tables here use one
rule that depends only on the face, "the corners above the level are kept
apart", so both cells sharing a face cut it the same way and the surface has
no holes.  Per configuration, every face contributes directed segments between
the crossing points on its edges; the segments chain into closed loops, which
are fanned into triangles.  The direction is chosen so that the triangles are
counter-clockwise seen from the side below the level (normals point toward
decreasing values) and the two cells sharing a face run along their common
segment in opposite directions (consistent winding).

The tetrahedral tables split each cell into the paper's five tetrahedra
(a central one on the corners of one parity and four corner ones), the
parity alternating with ``(i + j + k) % 2`` so that face diagonals match.  A
periodic ring of an odd number of cells cannot alternate, so the seam column
uses a six-tetrahedron split whose face diagonal toward the seam is flipped
(see :data:`SEAM_EVEN`).
"""

import functools
import itertools

import numpy as np

CORNERS = np.array([(c & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8)], dtype=np.int64)
PAIRS = tuple(itertools.combinations(range(8), 2))
PAIR_INDEX = {p: n for n, p in enumerate(PAIRS)}
CUBE_EDGES = tuple(p for p in PAIRS if bin(p[0] ^ p[1]).count("1") == 1)


def _edge(a, b):
    return PAIR_INDEX[(a, b) if a < b else (b, a)]


def _faces():
    """The 6 faces, each as 4 corners counter-clockwise seen from outside the cell."""
    faces = []
    centre = np.full(3, 0.5)
    for axis in range(3):
        for side in (0, 1):
            cs = [c for c in range(8) if CORNERS[c][axis] == side]
            # Order cyclically: (0,0), (1,0), (1,1), (0,1) in the two other axes.
            u, v = [a for a in range(3) if a != axis]
            cyc = sorted(cs, key=lambda c: {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}[(CORNERS[c][u], CORNERS[c][v])])
            p = CORNERS[cyc].astype(float)
            normal = np.cross(p[1] - p[0], p[2] - p[0])
            if np.dot(normal, p[0] - centre) < 0:
                cyc = cyc[::-1]
            faces.append(cyc)
    return faces


FACES = _faces()


def _cube_loops(config):
    above = [(config >> c) & 1 for c in range(8)]
    nxt = {}
    for face in FACES:
        crossings = []  # (edge, entering?) in walk order
        for m in range(4):
            a, b = face[m], face[(m + 1) % 4]
            if above[a] != above[b]:
                crossings.append((_edge(a, b), bool(above[b])))
        # Keep the corners above apart: pair each entering crossing with the
        # leaving crossing that follows it along the walk.
        n = len(crossings)
        for s in range(n):
            e, entering = crossings[s]
            if entering:
                leave = crossings[(s + 1) % n][0]
                nxt[leave] = e
    loops = []
    while nxt:
        start = next(iter(nxt))
        loop = [start]
        cur = nxt.pop(start)
        while cur != start:
            loop.append(cur)
            cur = nxt.pop(cur)
        loops.append(loop)
    return loops


def _table(tri_lists):
    ntri = np.array([len(t) for t in tri_lists], dtype=np.int64)
    table = np.zeros((len(tri_lists), max(1, ntri.max()), 3), dtype=np.int64)
    for c, tris in enumerate(tri_lists):
        if tris:
            table[c, : len(tris)] = tris
    return table, ntri


def cube_table():
    """``(table, ntri)``: table[config, n] = three local edges of triangle n."""
    tris = []
    for config in range(256):
        t = []
        for loop in _cube_loops(config):
            for m in range(1, len(loop) - 1):
                # The loop runs so that the fan is counter-clockwise seen from below the level.
                t.append((loop[0], loop[m + 1], loop[m]))
        tris.append(t)
    return _table(tris)


CENTRE = len(PAIRS)
"""Local ids ``CENTRE + q``: a vertex at the centre of the cell's loop ``q``."""


def _centre_fan(q, loop):
    n = len(loop)
    return [(CENTRE + q, loop[(m + 1) % n], loop[m]) for m in range(n)]


def cube_centre_table():
    """Like :func:`cube_table` but each loop fanned from a vertex at its centre
    (a vertex of the cell's own: its spokes are shared with no other cell)."""
    return _table([[t for q, loop in enumerate(_cube_loops(c)) for t in _centre_fan(q, loop)] for c in range(256)])


def _faces_of(a, b):
    return {f for f, face in enumerate(FACES) if a in face and b in face}


def polar_table(side):
    """Cube table for a cell whose corners with ``dj == side`` sit on a pole.

    Those corners coincide pairwise (``2 ≡ 3, 6 ≡ 7`` for ``side = 1``), carry
    one value, and the vertices on the two pole edges merge into one.  Each
    loop is contracted accordingly and fanned from a vertex whose diagonals
    never lie in a face of the cell (a diagonal there could meet its twin from
    the neighbouring cell once the pole vertices merge); a loop with no such
    vertex is fanned from a centre vertex instead (ids ``CENTRE + q``).
    """
    pole = [c for c in range(8) if CORNERS[c][1] == side]
    ka, kb = sorted(_edge(c, c | 4) for c in pole if not CORNERS[c][2])  # the two pole edges along k
    collapsed = next(f for f, face in enumerate(FACES) if all(CORNERS[c][1] == side for c in face))
    # Faces (other than the collapsed one) each vertex lies on; the merged pole vertex on both edges' faces.
    where = {e: _faces_of(*PAIRS[e]) - {collapsed} for e in range(len(PAIRS))}
    where[ka] = where[ka] | where[kb]

    def risky(e1, e2):
        return bool(where[e1] & where[e2])

    tris = []
    for config in range(256):
        t = []
        for q, loop in enumerate(_cube_loops(config)):
            c = [ka if e == kb else e for e in loop]
            c = [e for m, e in enumerate(c) if e != c[m - 1]]  # merge the pole pair (cyclic)
            n = len(c)
            if n < 3:
                continue
            for a in range(n):
                if not any(risky(c[a], c[(a + m) % n]) for m in range(2, n - 1)):
                    t += [(c[a], c[(a + m + 1) % n], c[(a + m) % n]) for m in range(1, n - 1)]
                    break
            else:
                t += _centre_fan(q, c)
        tris.append(t)
    return _table(tris)


def _five(central):
    others = [c for c in range(8) if c not in central]
    tets = [tuple(central)]
    for c in others:
        tets.append((c,) + tuple(c ^ (1 << a) for a in range(3)))
    return tets


EVEN = _five((0, 3, 5, 6))
"""The paper's split: central tetrahedron on the even corners."""
ODD = _five((1, 2, 4, 7))
SEAM_EVEN = [(1, 7, 3, 0), (1, 7, 5, 0), (7, 3, 0, 6), (7, 5, 0, 6), (2, 0, 3, 6), (4, 0, 5, 6)]
"""Six tetrahedra with the even face diagonals except on face ``di = 1``,
which is cut along 1–7 instead of 3–5 (the corner tetrahedra at 1 and 7 and
the central one re-split around the flipped diagonal)."""
SEAM_ODD = [tuple(c ^ 2 for c in t) for t in SEAM_EVEN]
"""Mirror of :data:`SEAM_EVEN` in ``j``: odd diagonals, flipped on face ``di = 1``."""
SPLITS = (EVEN, ODD, SEAM_EVEN, SEAM_ODD)


def _sub(p, q):
    return (p[0] - q[0], p[1] - q[1], p[2] - q[2])


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _centroid(corners):
    pts = [_XYZ[c] for c in corners]
    return tuple(sum(p[a] for p in pts) / len(pts) for a in range(3))


_XYZ = [tuple(int(x) for x in c) for c in CORNERS]


def _tet_triangles(tet, config):
    """Triangles (local edges) of the linear interpolant's level set in one tetrahedron,
    counter-clockwise seen from the corners below the level."""
    return _tet_case(tuple(tet), tuple(c for c in tet if (config >> c) & 1))


@functools.lru_cache(maxsize=None)
def _tet_case(tet, above):
    below = [c for c in tet if c not in above]
    if not above or not below:
        return []
    if len(above) == 1 or len(below) == 1:
        lone, rest = (above[0], below) if len(above) == 1 else (below[0], above)
        poly = [_edge(lone, r) for r in rest]
    else:
        a0, a1 = above
        b0, b1 = below
        poly = [_edge(a0, b0), _edge(a0, b1), _edge(a1, b1), _edge(a1, b0)]
    pts = [_centroid(PAIRS[e]) for e in poly]
    normal = (0.0, 0.0, 0.0)
    for m in range(1, len(pts) - 1):
        c = _cross(_sub(pts[m], pts[0]), _sub(pts[m + 1], pts[0]))
        normal = (normal[0] + c[0], normal[1] + c[1], normal[2] + c[2])
    down = _sub(_centroid(below), _centroid(above))
    if sum(n * d for n, d in zip(normal, down)) < 0:
        poly = poly[::-1]
    return [(poly[0], poly[m], poly[m + 1]) for m in range(1, len(poly) - 1)]


def tet_tables():
    """``(table, ntri)`` with a leading axis over :data:`SPLITS`."""
    tables = [_table([[t for tet in split for t in _tet_triangles(tet, c)] for c in range(256)]) for split in SPLITS]
    width = max(t.shape[1] for t, _ in tables)
    table = np.zeros((len(SPLITS), 256, width, 3), dtype=np.int64)
    ntri = np.zeros((len(SPLITS), 256), dtype=np.int64)
    for s, (t, n) in enumerate(tables):
        table[s, :, : t.shape[1]] = t
        ntri[s] = n
    return table, ntri
