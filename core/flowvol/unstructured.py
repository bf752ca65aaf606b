"""A steady velocity on an unstructured hexahedral grid (VTK XML ``.vtu``), interpolated in its cells.

Blender ships no VTK, so the file is read here with the standard library
and NumPy (:func:`read_vtu`: inline or appended data, raw or base64,
optionally zlib-compressed) and the point vectors are interpolated in each
hexahedron with its trilinear shape functions: the cell is found among the
nearest cell centres (scipy ``cKDTree``) by Newton inversion of the
trilinear map.  Points outside every cell get NaN, which
:func:`~nephele.core.flowvol.flow_volume` reports as a :class:`DataError`
naming the field.

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
.. [2] Kitware, "VTK File Formats" (XML formats: appended data, compressed
   blocks; cell type 12 = VTK_HEXAHEDRON and its node order).
"""

import base64
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..errors import DataError

VTK_HEXAHEDRON = 12
_DTYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
           "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
# Parametric corners (r, s, t) of VTK's hexahedron, in its node order.
_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=np.float64)


def _decode(raw, binary, header, compressed, order):
    """Bytes of one data array: ``raw`` is base64 text (``binary`` False) or bytes, with its size header."""
    hsize = np.dtype(header).itemsize

    def take(n_bytes, text_pos):
        # Base64 headers and data are encoded separately: read exactly the characters needed.
        if binary:
            return raw[text_pos:text_pos + n_bytes], text_pos + n_bytes
        chars = 4 * -(-n_bytes // 3)
        return base64.b64decode(raw[text_pos:text_pos + chars])[:n_bytes], text_pos + chars

    if not compressed:
        head, pos = take(hsize, 0)
        n = int(np.frombuffer(head, dtype=order + header)[0])
        if binary:
            return raw[hsize:hsize + n]
        return base64.b64decode(raw[:4 * -(-(hsize + n) // 3)])[hsize:hsize + n]
    first, _ = take(hsize, 0)
    nblocks = int(np.frombuffer(first, dtype=order + header)[0])
    head, pos = take(hsize * (3 + nblocks), 0)
    h = np.frombuffer(head, dtype=order + header).astype(np.int64)
    data, _ = take(int(h[3:].sum()), pos)
    out, start = [], 0
    for size in h[3:]:
        out.append(zlib.decompress(data[start:start + size]))
        start += size
    return b"".join(out)


def read_vtu(path):
    """Points, cells and point arrays of a VTK XML unstructured grid.

    Returns
    -------
    dict
        ``points`` (n, 3) float64, ``connectivity``, ``offsets``, ``types``
        (int64) and ``point_data`` (name -> array, (n,) or (n, c)), each in
        the file's own dtype promoted to 64 bits.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("no such file", path=str(path))
    blob = path.read_bytes()
    cut = blob.find(b"<AppendedData")
    appended = b""
    if cut >= 0:
        start = blob.index(b">", cut) + 1
        end = blob.rindex(b"</AppendedData>")
        appended = blob[start:end].strip()
        if not appended.startswith(b"_"):
            raise DataError("appended data does not start with '_'", path=str(path))
        appended = appended[1:]
        text = blob[:start] + b"</AppendedData></VTKFile>"
    else:
        text = blob
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise DataError(f"is not VTK XML ({err})", path=str(path)) from None
    if root.tag != "VTKFile" or root.get("type") != "UnstructuredGrid":
        raise DataError("is not a VTK XML unstructured grid", path=str(path))
    order = "<" if root.get("byte_order", "LittleEndian") == "LittleEndian" else ">"
    header = {"UInt32": "u4", "UInt64": "u8"}[root.get("header_type", "UInt32")]
    compressed = root.get("compressor") is not None
    if compressed and root.get("compressor") != "vtkZLibDataCompressor":
        raise DataError(f"unsupported compressor {root.get('compressor')}", path=str(path))
    app = root.find("AppendedData")
    app_binary = app is not None and app.get("encoding") == "raw"
    piece = root.find("UnstructuredGrid/Piece")
    if piece is None:
        raise DataError("has no unstructured grid piece", path=str(path))

    def array(el):
        dtype = np.dtype(order + _DTYPES[el.get("type")])
        fmt = el.get("format")
        if fmt == "appended":
            raw = appended[int(el.get("offset")):]
            data = _decode(raw, app_binary, header, compressed, order)
        elif fmt == "binary":
            data = _decode("".join((el.text or "").split()).encode(), False, header, compressed, order)
        elif fmt == "ascii":
            return np.array((el.text or "").split(), dtype=dtype.newbyteorder("="))
        else:
            raise DataError(f"unknown data format {fmt!r}", path=str(path), field=el.get("Name"))
        a = np.frombuffer(data, dtype=dtype)
        c = int(el.get("NumberOfComponents", "1"))
        return a.reshape(-1, c) if c > 1 else a

    cells = {el.get("Name"): array(el).astype(np.int64) for el in piece.findall("Cells/DataArray")}
    points = piece.find("Points/DataArray")
    if points is None or not {"connectivity", "offsets", "types"} <= set(cells):
        raise DataError("lacks points or cells", path=str(path))
    return {
        "points": array(points).astype(np.float64).reshape(-1, 3),
        **cells,
        "point_data": {el.get("Name"): array(el) for el in piece.findall("PointData/DataArray")},
    }


def trilinear(rst):
    """Shape functions (n, 8) of VTK's hexahedron at parametric points (n, 3), and their derivatives (n, 8, 3)."""
    c = _CORNERS[None]
    p = rst[:, None, :]
    f = np.where(c == 1, p, 1 - p)  # (n, 8, 3) factors
    w = f.prod(axis=2)
    sign = 2 * c - 1
    d = np.stack([sign[..., 0] * f[..., 1] * f[..., 2], sign[..., 1] * f[..., 0] * f[..., 2], sign[..., 2] * f[..., 0] * f[..., 1]], axis=2)
    return w, d


class UnstructuredVelocity:
    """``velocity(points (n, 3), t) -> (n, 3)`` from the point vectors ``field`` of a hexahedral ``.vtu`` file.

    Parameters
    ----------
    path : str or Path
    field : str
        A 3-component point array.
    candidates : int
        Nearest cell centres tried for each point.
    """

    def __init__(self, path, field="uvw", candidates=8):
        self.path, self.field = str(path), field
        grid = read_vtu(path)
        types = grid["types"]
        if len(types) == 0:
            raise DataError("is not a VTK XML unstructured grid with cells", path=self.path)
        if np.any(types != VTK_HEXAHEDRON) or np.any(np.diff(np.concatenate([[0], grid["offsets"]])) != 8):
            raise DataError(f"has cells other than hexahedra (types {sorted(set(types.tolist()))}); only type 12 is interpolated", path=self.path)
        arr = grid["point_data"].get(field)
        if arr is None or arr.ndim != 2 or arr.shape[1] != 3:
            raise DataError("is not a 3-component point array of the grid", path=self.path, field=field)
        self.points = grid["points"]
        self.vectors = arr.astype(np.float64)
        self.cells = grid["connectivity"].reshape(-1, 8)
        self.bounds = np.stack([self.points.min(axis=0), self.points.max(axis=0)], axis=1)
        corners = self.points[self.cells]
        self._tree = cKDTree(corners.mean(axis=1))
        # A trilinear cell lies in the box of its corners: only candidates whose box holds the point are inverted.
        pad = 1e-9 * np.ptp(self.points, axis=0).max()
        self._lo, self._hi = corners.min(axis=1) - pad, corners.max(axis=1) + pad
        self._k = min(int(candidates), len(self.cells))

    def locate(self, points, tol=1e-7, iterations=12):
        """Cell index (-1 outside) and parametric coordinates of each point."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cell = np.full(len(p), -1, dtype=np.int64)
        rst = np.full((len(p), 3), np.nan)
        if len(p) == 0:
            return cell, rst
        _, near = self._tree.query(p, k=self._k)
        near = near.reshape(len(p), -1)
        holds = np.all((p[:, None] >= self._lo[near]) & (p[:, None] <= self._hi[near]), axis=2)
        near = np.take_along_axis(near, np.argsort(~holds, axis=1, kind="stable"), axis=1)
        count = holds.sum(axis=1)
        todo = np.nonzero(count > 0)[0]
        for c in range(near.shape[1]):
            todo = todo[count[todo] > c]
            if len(todo) == 0:
                break
            idx = near[todo, c]
            x = self.points[self.cells[idx]]  # (m, 8, 3)
            q = np.full((len(todo), 3), 0.5)
            step = np.full((len(todo), 3), np.inf)
            live = np.arange(len(todo))
            for _ in range(iterations):
                w, d = trilinear(q[live])
                r = np.einsum("mk,mkj->mj", w, x[live]) - p[todo[live]]
                jac = np.einsum("mki,mkj->mji", d, x[live])  # d position_j / d q_i
                ok = np.abs(np.linalg.det(jac)) > 0
                s = np.zeros((len(live), 3))
                s[ok] = np.linalg.solve(jac[ok], r[ok][..., None])[..., 0]
                q[live] = np.clip(q[live] - s, -1.0, 2.0)  # far-off candidates stay bounded
                step[live] = s
                # Converged, or far outside the cell after a few steps: stop iterating on it.
                live = live[(np.abs(s).max(axis=1) >= 1e-12) & ok]
                if len(live) == 0:
                    break
            inside = np.all((q >= -tol) & (q <= 1 + tol), axis=1) & (np.abs(step).max(axis=1) < 1e-9)
            cell[todo[inside]] = idx[inside]
            rst[todo[inside]] = np.clip(q[inside], 0.0, 1.0)
            todo = todo[~inside]
        return cell, rst

    def __call__(self, points, t=None):
        cell, rst = self.locate(points)
        out = np.full((len(cell), 3), np.nan)
        ok = cell >= 0
        w, _ = trilinear(rst[ok])
        out[ok] = np.einsum("mk,mkj->mj", w, self.vectors[self.cells[cell[ok]]])
        return out

    def updraft(self, height=0.1, margin=0.3):
        """A generator place: ``height`` above the fastest rising (+z) grid point in the lower half, ``margin`` from the side walls.

        Above a fire this is its plume, so the smoke is seeded where the hot air rises.
        """
        lo, hi = self.bounds[:, 0] + margin, self.bounds[:, 1] - margin
        p = self.points
        inside = np.all((p[:, :2] >= lo[:2]) & (p[:, :2] <= hi[:2]), axis=1) & (p[:, 2] < self.bounds[2].mean())
        if not inside.any():
            raise DataError(f"no grid point lies {margin} inside the side walls in the lower half", path=self.path)
        i = np.argmax(np.where(inside, self.vectors[:, 2], -np.inf))
        return p[i] + [0.0, 0.0, float(height)]
