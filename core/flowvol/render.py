"""Reference compositing of constant-colour smoke tetrahedra: exact ray–tetrahedron lengths.

With one colour ``C`` and extinction ``τ`` everywhere, a ray crossing total
smoke length ``L`` gets ``C (1 - exp(-τ L))`` over black, whatever order the
tetrahedra are composited in (the sum of lengths commutes), which is why
the paper needs no back-to-front sorting.

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
"""

import numpy as np

from ..errors import DataError
from .tets import signed_volumes

_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def ray_lengths(vertices, tets, origins, directions, chunk=256):
    """Total length of each ray ``origin + t·direction`` (t >= 0) inside the tetrahedra.

    Tetrahedra are clipped exactly by their four face planes; ``directions``
    need not be unit (lengths are in scene units).  A ray lying exactly in a
    face shared by two tetrahedra is counted in both (measure zero; no
    tie-breaking rule yet).
    """
    v = np.asarray(vertices, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(tets) and np.any(signed_volumes(v, tets) < 0):
        raise DataError("tetrahedra must be positively oriented", field="tets")
    out = np.zeros(len(o))
    if len(tets) == 0:
        return out
    p = v[tets[:, _FACES]]  # (m, 4, 3 corners, 3)
    n = np.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0])  # outward normals
    c = np.einsum("mfk,mfk->mf", n, p[:, :, 0])
    # Tie-break for a ray lying in a face plane: the two tets sharing the face have opposite
    # normals; only the one whose normal's first non-zero component is negative keeps the ray.
    first = np.take_along_axis(n, np.argmax(n != 0, axis=2)[..., None], axis=2)[..., 0]
    keeps_tie = first < 0
    speed = np.linalg.norm(d, axis=1)
    for s in range(0, len(o), chunk):
        oo, dd = o[s:s + chunk], d[s:s + chunk]
        num = c[None] - np.einsum("mfk,rk->rmf", n, oo)  # n·(o + t d) <= c  <=>  t (n·d) <= num
        den = np.einsum("mfk,rk->rmf", n, dd)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / den
        t_in = np.max(np.where(den < 0, t, -np.inf), axis=2)
        t_out = np.min(np.where(den > 0, t, np.inf), axis=2)
        parallel_out = np.any((den == 0) & ((num < 0) | ((num == 0) & ~keeps_tie[None])), axis=2)
        t_in = np.maximum(t_in, 0.0)
        length = np.where(parallel_out, 0.0, np.clip(t_out - t_in, 0.0, None))
        out[s:s + chunk] = np.sum(np.where(np.isfinite(length), length, 0.0), axis=1) * speed[s:s + chunk]
    return out


def composite(vertices, tets, origins, directions, color, tau):
    """Constant-colour smoke over black: ``C (1 - exp(-τ L))`` per ray, (r, 3)."""
    length = ray_lengths(vertices, tets, origins, directions)
    return np.asarray(color, dtype=np.float64)[None] * (1.0 - np.exp(-float(tau) * length))[:, None]
