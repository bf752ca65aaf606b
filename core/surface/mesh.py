"""Triangle meshes as plain arrays: what contouring produces and Blender consumes.

A :class:`Mesh` holds float32 vertices, int32 triangles, unit vertex normals
and per-vertex attributes.  It converts to :mod:`trimesh` (imported lazily)
for export, and caches itself as a plain ``.npz`` (no pickle).
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..files import atomic_write

EXPORT_FORMATS = (".ply", ".glb", ".obj")
_ATTR_PREFIX = "attr__"


@dataclass(eq=False)
class Mesh:
    """A triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float32 array
    faces : (m, 3) int32 array
        Counter-clockwise seen from the side the normals point to.
    normals : (n, 3) float32 array
        Unit, area-weighted vertex normals.
    attributes : dict of str to (n,) or (n, k) arrays
        Per-vertex values (for example a second variable sampled on the surface).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    attributes: dict = field(default_factory=dict)

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32).reshape(-1, 3)
        self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
        n = len(self.vertices)
        if len(self.normals) != n:
            raise DataError(f"{len(self.normals)} normals for {n} vertices", field="normals")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= n):
            raise DataError("face indices out of range", field="faces")
        attrs = {}
        for name, a in dict(self.attributes).items():
            a = np.asarray(a)
            if a.shape[:1] != (n,):
                raise DataError(f"has {a.shape[:1]} values for {n} vertices", field=name)
            attrs[str(name)] = a
        self.attributes = attrs

    @classmethod
    def empty(cls, attribute_names=()):
        """A mesh with no vertices (attributes named but empty)."""
        z = np.zeros((0, 3), np.float32)
        return cls(z, np.zeros((0, 3), np.int32), z.copy(), {a: np.zeros(0, np.float32) for a in attribute_names})

    @property
    def is_empty(self):
        return len(self.faces) == 0

    def __repr__(self):
        return f"Mesh({len(self.vertices)} vertices, {len(self.faces)} faces, attributes={sorted(self.attributes)})"

    def area(self):
        """Total surface area (float64)."""
        return float(triangle_areas(self.vertices, self.faces).sum())

    def to_trimesh(self):
        """A :class:`trimesh.Trimesh` sharing these arrays (no merging or repair)."""
        import trimesh

        return trimesh.Trimesh(
            vertices=self.vertices,
            faces=self.faces,
            vertex_normals=self.normals,
            vertex_attributes=dict(self.attributes),
            process=False,
            validate=False,
        )

    def save(self, path):
        """Export to ``.ply``, ``.glb`` or ``.obj`` (via trimesh), atomically."""
        path = Path(path)
        ext = path.suffix.lower()
        if ext not in EXPORT_FORMATS:
            raise DataError(f"unsupported mesh format {ext!r}; use one of {', '.join(EXPORT_FORMATS)}", path=path)
        try:
            tm = self.to_trimesh()
        except ImportError:
            raise DataError(f"writing {ext} needs the trimesh package (pip install trimesh)", path=path) from None
        data = tm.export(file_type=ext[1:])
        if isinstance(data, str):
            data = data.encode()
        with atomic_write(path) as tmp:
            tmp.write_bytes(data)
        return path

    def save_npz(self, path):
        """Cache as a plain ``.npz`` (atomic; loads with ``allow_pickle=False``)."""
        arrays = {"vertices": self.vertices, "faces": self.faces, "normals": self.normals}
        arrays.update({_ATTR_PREFIX + k: np.asarray(v) for k, v in self.attributes.items()})
        with atomic_write(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, **arrays)
        return Path(path)

    def to_arrays(self):
        """The mesh as a flat dict of arrays (for :mod:`nephele.core.pipeline.cache`)."""
        arrays = {"vertices": self.vertices, "faces": self.faces, "normals": self.normals}
        arrays.update({_ATTR_PREFIX + k: v for k, v in self.attributes.items()})
        return arrays

    @classmethod
    def from_arrays(cls, arrays):
        """Inverse of :meth:`to_arrays`."""
        attrs = {k[len(_ATTR_PREFIX) :]: arrays[k] for k in arrays if k.startswith(_ATTR_PREFIX)}
        return cls(arrays["vertices"], arrays["faces"], arrays["normals"], attrs)

    @classmethod
    def load_npz(cls, path):
        """Read a mesh written by :meth:`save_npz`."""
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise DataError(f"cannot read mesh cache: {exc}", path=path) from None
        missing = {"vertices", "faces", "normals"} - set(arrays)
        if missing:
            raise DataError(f"not a mesh cache (missing {', '.join(sorted(missing))})", path=path)
        return cls.from_arrays(arrays)


def triangle_areas(vertices, faces):
    """Area of every triangle, float64."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if len(f) == 0:
        return np.zeros(0)
    c = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return 0.5 * np.sqrt(np.einsum("ij,ij->i", c, c))


def vertex_normals(vertices, faces):
    """Unit area-weighted vertex normals (float32); zero where no face touches a vertex."""
    n = len(vertices)
    out = np.zeros((n, 3), np.float32)
    if len(faces) == 0:
        return out
    # Component planes: cheaper gathers and cross products than (n, 3) rows.
    x, y, z = np.asarray(vertices, dtype=np.float32).T.copy()
    f0, f1, f2 = np.asarray(faces).T.copy()
    x0, y0, z0 = x[f0], y[f0], z[f0]
    ux, uy, uz = x[f1] - x0, y[f1] - y0, z[f1] - z0
    wx, wy, wz = x[f2] - x0, y[f2] - y0, z[f2] - z0
    # The cross product's length is twice the area: area weighting for free.
    fn = (uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx)
    for c in range(3):
        w = fn[c].astype(np.float64)
        out[:, c] = np.bincount(f0, w, n) + np.bincount(f1, w, n) + np.bincount(f2, w, n)
    length = np.sqrt(np.einsum("ij,ij->i", out, out))
    np.divide(out, length[:, None], out=out, where=length[:, None] > 0)
    return out
