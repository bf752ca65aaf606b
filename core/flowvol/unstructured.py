"""A steady velocity on an unstructured hexahedral grid (VTK XML ``.vtu``), interpolated in its cells.

Blender ships no VTK, so the file is read here with the standard library
and NumPy (:func:`read_vtu`: inline or appended data, raw or base64,
optionally zlib-compressed) and the point vectors are interpolated in each
hexahedron with its trilinear shape functions: the cell is found through a
uniform bucket grid of cell boxes (built once per file) and the trilinear
map inverted exactly where it is affine, by Newton's method elsewhere.
Points outside every cell get NaN: a flow volume's points stop where they
leave the grid (a wall or an outlet); a generator outside it is a
:class:`DataError` naming the field.

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
.. [2] Kitware, "VTK File Formats" (XML formats: appended data, compressed
   blocks; cell type 12 = VTK_HEXAHEDRON and its node order).
"""

import base64
import math
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..memory import check_memory

VTK_HEXAHEDRON = 12
_DTYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
           "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
# Parametric corners (r, s, t) of VTK's hexahedron, in its node order.
_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
                    dtype=np.float64)
# The corners in (t, s, r) lattice order: corner (r, s, t) at [t, s, r] after a reshape to (2, 2, 2).
_LATTICE = np.array([0, 1, 3, 2, 4, 5, 7, 6])


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

    Raises
    ------
    DataError
        A missing or damaged file (bad XML, base64, zlib data or sizes).
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("no such file", path=str(path))
    try:
        return _parse_vtu(path, path.read_bytes())
    except (DataError, MemoryError):
        raise
    except (ValueError, KeyError, IndexError, TypeError, OverflowError, zlib.error) as exc:
        # binascii.Error: a ValueError
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        raise DataError(f"is damaged ({type(exc).__name__}: {first})", path=str(path)) from exc


def _parse_vtu(path, blob):
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
            data = None
        else:
            raise DataError(f"unknown data format {fmt!r}", path=str(path), field=el.get("Name"))
        a = (np.array((el.text or "").split(), dtype=dtype.newbyteorder("=")) if data is None
             else np.frombuffer(data, dtype=dtype))
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
    f = np.where(c == 1, p, 1 - p)  # (n, 8) factors
    w = f.prod(axis=2)
    sign = 2 * c - 1
    d = np.stack([sign[..., 0] * f[..., 1] * f[..., 2], sign[..., 1] * f[..., 0] * f[..., 2],
                  sign[..., 2] * f[..., 0] * f[..., 1]], axis=2)
    return w, d


class UnstructuredVelocity:
    """``velocity(points (n, 3), t) -> (n, 3)`` from the point vectors ``field`` of a hexahedral ``.vtu`` file.

    Points are located with a uniform bucket grid built once per file: each
    bucket lists the cells whose bounding box overlaps it, so a point's
    candidates are one row of a table.  Cells whose trilinear map is affine
    (parallelepipeds, e.g. the fire's boxes) are inverted exactly with a
    stored inverse Jacobian; other cells by Newton's method.

    Parameters
    ----------
    path : str or Path
    field : str
        A 3-component point array.
    bucket_cells : float
        Buckets per cell along each axis (bucket edge = median cell extent / this).
    """

    bounded = True  # velocity is NaN outside the cells: flow volumes stop at the boundary instead of failing
    steady = True  # one snapshot: flow volumes integrate each streamline once (a stream tube)

    def __init__(self, path, field="uvw", bucket_cells=2.0):
        self.path, self.field = str(path), field
        grid = read_vtu(path)
        types = grid["types"]
        if len(types) == 0:
            raise DataError("is not a VTK XML unstructured grid with cells", path=self.path)
        if np.any(types != VTK_HEXAHEDRON) or np.any(np.diff(np.concatenate([[0], grid["offsets"]])) != 8):
            raise DataError(f"has cells other than hexahedra (types {sorted(set(types.tolist()))}); only type 12 is "
                            "interpolated", path=self.path)
        arr = grid["point_data"].get(field)
        if arr is None or arr.ndim != 2 or arr.shape[1] != 3:
            raise DataError("is not a 3-component point array of the grid", path=self.path, field=field)
        self.points = grid["points"]
        conn = grid["connectivity"]
        if (conn.size != 8 * len(types) or len(arr) != len(self.points)
                or (conn.size and not 0 <= conn.min() <= conn.max() < len(self.points))):
            raise DataError(f"has {conn.size} corner indices for {len(types)} hexahedra and {len(self.points)} points "
                            f"({len(arr)} vectors): they do not fit together", path=self.path)
        if not np.isfinite(np.ptp(self.points, axis=0)).all():
            raise DataError("has points that are not finite numbers", path=self.path)
        self.vectors = arr.astype(np.float64)
        self.cells = conn.reshape(-1, 8)
        self.bounds = np.stack([self.points.min(axis=0), self.points.max(axis=0)], axis=1)
        self._build_locator(float(bucket_cells))

    @property
    def vectors(self):
        return self._vectors

    @vectors.setter
    def vectors(self, value):
        # Corner vectors gathered per cell once: one gather per call instead of two.
        self._vectors = np.asarray(value, dtype=np.float64)
        if hasattr(self, "cells"):
            self._cell_vectors = self._vectors[self.cells]
            self._lattice_vectors = self._cell_vectors[:, _LATTICE].reshape(-1, 2, 2, 2, 3)

    def _build_locator(self, bucket_cells):
        corners = self.points[self.cells]  # (c, 8, 3)
        self._cell_vectors = self._vectors[self.cells]
        self._lattice_vectors = self._cell_vectors[:, _LATTICE].reshape(-1, 2, 2, 2, 3)
        ext = np.ptp(self.points, axis=0).max()
        pad = 1e-9 * ext
        self._lo, self._hi = corners.min(axis=1) - pad, corners.max(axis=1) + pad
        # The trilinear map x0 + a_r r + a_s s + a_t t + (bilinear and trilinear terms): affine when those vanish.
        x = corners
        twist = np.stack([x[:, 0] - x[:, 1] + x[:, 2] - x[:, 3], x[:, 0] - x[:, 1] + x[:, 5] - x[:, 4],
                          x[:, 0] - x[:, 3] + x[:, 7] - x[:, 4],
                          x[:, 1] - x[:, 0] - x[:, 2] + x[:, 3] + x[:, 4] - x[:, 5] + x[:, 6] - x[:, 7]], axis=1)
        jac = np.stack([x[:, 1] - x[:, 0], x[:, 3] - x[:, 0], x[:, 4] - x[:, 0]], axis=2)  # columns d x / d(r, s, t)
        det = np.linalg.det(jac)
        size = np.abs(self._hi - self._lo).max(axis=1)
        self._affine = (np.abs(twist).max(axis=(1, 2)) <= 1e-9 * size) & (np.abs(det) > 1e-12 * size**3)
        self._inv = np.zeros_like(jac)
        self._inv[self._affine] = np.linalg.inv(jac[self._affine])
        self._origin = x[:, 0]
        # Buckets: per axis the grid's own distinct corner coordinates where there are few of them (a
        # lattice-aligned mesh: one cell per bucket), else uniform about the median cell extent.
        # Each cell is listed in every bucket its box overlaps.
        clo, chi = corners.min(axis=1), corners.max(axis=1)
        h = np.maximum(np.median(chi - clo, axis=0) / bucket_cells, 1e-12 * max(ext, 1e-300))
        self.cell_size = float(np.median(chi - clo))  # a typical cell's extent: streamlines step about one cell
        self._edges = []
        counts = [max(float(np.ceil(np.ptp(corners[..., ax]) / h[ax])), 1.0) for ax in range(3)]
        check_memory(16 * math.prod(counts) + 8 * sum(counts), f"locating points in {len(self.cells):,} cells",
                     path=self.path, hint="their corners spread over far more cell sizes than cells (a stray point?)")
        for ax in range(3):
            lattice = np.unique(corners[..., ax])
            n = int(counts[ax])
            self._edges.append(lattice if len(lattice) - 1 <= 4 * n and len(lattice) > 1
                               else np.linspace(lattice[0], lattice[-1], n + 1))
        nb = np.array([len(e) - 1 for e in self._edges])
        self._nb = nb
        i0 = np.stack([np.searchsorted(e, clo[:, ax], "right") - 1 for ax, e in enumerate(self._edges)], axis=1)
        i1 = np.stack([np.searchsorted(e, chi[:, ax], "left") - 1 for ax, e in enumerate(self._edges)], axis=1)
        i0 = np.clip(i0, 0, nb - 1)
        i1 = np.clip(np.maximum(i1, i0), 0, nb - 1)
        span = (i1 - i0 + 1).max(axis=0)
        offs = np.stack(np.meshgrid(*[np.arange(s) for s in span], indexing="ij"), axis=-1).reshape(-1, 3)
        b = i0[:, None] + offs[None]  # (c, k, 3)
        ok = np.all(b <= i1[:, None], axis=2)
        flat = ((b[..., 0] * nb[1] + b[..., 1]) * nb[2] + b[..., 2])[ok]
        cell = np.broadcast_to(np.arange(len(self.cells))[:, None], ok.shape)[ok]
        bo = b[ok]
        blo = np.stack([e[bo[:, ax]] for ax, e in enumerate(self._edges)], axis=1)
        bhi = np.stack([e[bo[:, ax] + 1] for ax, e in enumerate(self._edges)], axis=1)
        # In each bucket the cells covering most of it come first: usually the first candidate holds the point.
        overlap = np.prod(np.clip(np.minimum(chi[cell], bhi) - np.maximum(clo[cell], blo), 0, None), axis=1)
        order = np.lexsort((-overlap, flat))
        flat, cell = flat[order], cell[order]
        counts = np.bincount(flat, minlength=int(np.prod(nb)))
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        table = np.full((len(counts), max(int(counts.max()), 1)), -1,
                        dtype=np.int32 if len(self.cells) < 2**31 else np.int64)
        table[flat, np.arange(len(flat)) - start[flat]] = cell
        self._table = table
        self._lo_all, self._hi_all = self._lo.min(axis=0), self._hi.max(axis=0)
        self._eps = 1e-9 * ext

    def locate(self, points, tol=1e-7, iterations=12):
        """Cell index (-1 outside) and parametric coordinates of each point."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cell = np.full(len(p), -1, dtype=np.int64)
        rst = np.full((len(p), 3), np.nan)
        todo = np.nonzero(np.all((p >= self._lo_all) & (p <= self._hi_all), axis=1))[0]  # also drops NaN
        if len(todo) == 0:
            return cell, rst
        q = p[todo]
        g = np.empty((len(todo), 3), dtype=np.int64)
        near = np.empty((len(todo), 3), dtype=bool)
        for ax, e in enumerate(self._edges):
            g[:, ax] = np.minimum(np.searchsorted(e, q[:, ax], "right") - 1, self._nb[ax] - 1)
            near[:, ax] = q[:, ax] - self._eps < e[g[:, ax]]
        np.maximum(g, 0, out=g)
        def rows(gg):
            return self._table[(gg[:, 0] * self._nb[1] + gg[:, 1]) * self._nb[2] + gg[:, 2]]
        left = self._in_rows(p, todo, rows(g), cell, rst, tol, iterations)
        # A point on a bucket face belongs to the bucket above it; if no cell there holds it
        # (a wall, an obstacle), the buckets below along the axes of the faces it lies on are tried.
        where = np.searchsorted(todo, left)
        keep = near[where].any(axis=1)
        left, where = left[keep], where[keep]
        for below in self._SHIFTS[1:]:
            if len(left) == 0:
                break
            try_ = np.nonzero(near[where][:, below == 1].all(axis=1))[0]
            if len(try_) == 0:
                continue
            gg = np.maximum(g[where[try_]] - below, 0)
            still = self._in_rows(p, left[try_], rows(gg), cell, rst, tol, iterations)
            stay = np.ones(len(left), dtype=bool)
            stay[try_[~np.isin(left[try_], still)]] = False  # located in this shift
            left, where = left[stay], where[stay]
        return cell, rst

    _SHIFTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1]])

    def _in_rows(self, p, todo, cand, cell, rst, tol, iterations):
        """Locate points ``p[todo]`` among their candidate cells ``cand`` (rows padded with -1); the points left."""
        # Affine cells: the bucket's first candidate (usually the one, the only one on a lattice-aligned grid).
        idx = cand[:, 0]
        safe = np.maximum(idx, 0)
        q = p[todo]
        r = np.einsum("mij,mj->mi", self._inv[safe], q - self._origin[safe])
        got = (idx >= 0) & self._affine[safe] & (r >= -tol).all(axis=1) & (r <= 1 + tol).all(axis=1)
        cell[todo[got]] = idx[got]
        rst[todo[got]] = np.clip(r[got], 0.0, 1.0)
        if got.all():
            return todo[:0]
        todo, cand, q = todo[~got], cand[~got], q[~got]
        if cand.shape[1] > 1:  # then all the others at once
            others = cand[:, 1:]
            safe = np.maximum(others, 0)
            r = np.einsum("mcij,mcj->mci", self._inv[safe], q[:, None] - self._origin[safe])
            ins = (others >= 0) & self._affine[safe] & np.all((r >= -tol) & (r <= 1 + tol), axis=2)
            first = np.argmax(ins, axis=1)
            got = ins[np.arange(len(todo)), first]
            cell[todo[got]] = others[got, first[got]]
            rst[todo[got]] = np.clip(r[got, first[got]], 0.0, 1.0)
            todo, cand = todo[~got], cand[~got]
        # General hexahedra: Newton's method in each candidate whose box holds the point.
        for c in range(cand.shape[1] if len(todo) and not self._affine.all() else 0):
            idx = cand[:, c]
            q = p[todo]
            safe = np.maximum(idx, 0)
            try_ = np.nonzero((idx >= 0) & ~self._affine[safe] & np.all((q >= self._lo[safe]) & (q <= self._hi[safe]),
                                                                        axis=1))[0]
            if len(try_) == 0:
                continue
            r, ins = self._newton(idx[try_], q[try_], tol, iterations)
            got = np.zeros(len(todo), dtype=bool)
            got[try_[ins]] = True
            cell[todo[got]] = idx[got]
            rst[todo[got]] = r[ins]
            todo, cand = todo[~got], cand[~got]
        return todo

    def _newton(self, idx, p, tol, iterations):
        """Parametric coordinates of ``p`` in general hexahedra ``idx`` by Newton's method, and whether inside."""
        x = self.points[self.cells[idx]]  # (m, 8, 3)
        q = np.full((len(idx), 3), 0.5)
        step = np.full((len(idx), 3), np.inf)
        live = np.arange(len(idx))
        for _ in range(iterations):
            w, d = trilinear(q[live])
            r = np.einsum("mk,mkj->mj", w, x[live]) - p[live]
            jac = np.einsum("mki,mkj->mji", d, x[live])  # d position_j / d q_i
            ok = np.abs(np.linalg.det(jac)) > 0
            s = np.zeros((len(live), 3))
            s[ok] = np.linalg.solve(jac[ok], r[ok][..., None])[..., 0]
            q[live] = np.clip(q[live] - s, -1.0, 2.0)  # far-off candidates stay bounded
            step[live] = s
            # Converged, or a singular map: stop iterating on it.
            live = live[(np.abs(s).max(axis=1) >= 1e-12) & ok]
            if len(live) == 0:
                break
        inside = np.all((q >= -tol) & (q <= 1 + tol), axis=1) & (np.abs(step).max(axis=1) < 1e-9)
        return np.clip(q, 0.0, 1.0), inside

    def __call__(self, points, t=None):
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cell, rst = self._first_candidate(p)
        miss = np.nonzero(cell < 0)[0]
        if len(miss):  # the full search (faces between buckets, other candidates, Newton) for the rest
            cell[miss], rst[miss] = self.locate(p[miss])
        out = np.full((len(cell), 3), np.nan)
        ok = np.nonzero(cell >= 0)[0]
        r, s, t = rst[ok].T
        v = self._lattice_vectors[cell[ok]]  # (m, t, s, r, 3): lerp along t, then s, then r
        v = v[:, 0] + t[:, None, None, None] * (v[:, 1] - v[:, 0])
        v = v[:, 0] + s[:, None, None] * (v[:, 1] - v[:, 0])
        out[ok] = v[:, 0] + r[:, None] * (v[:, 1] - v[:, 0])
        return out

    def _first_candidate(self, p, tol=1e-7):
        """Cell and parametric coordinates of points in their bucket's first cell when it is affine (else -1).

        The hot path of every velocity read: on a lattice-aligned grid of boxes it
        locates nearly every point with a few array operations (the same test as
        :meth:`locate`'s first pass, which handles the others).
        """
        # Small arrays (a front's points per RK stage): plain ufuncs, not np.clip's Python wrapper.
        flat = np.zeros(len(p), dtype=np.int64)
        for ax, e in enumerate(self._edges):
            g = np.searchsorted(e, p[:, ax], "right")
            g -= 1
            np.minimum(np.maximum(g, 0, out=g), self._nb[ax] - 1, out=g)
            flat *= self._nb[ax]
            flat += g
        cell = self._table[flat, 0].astype(np.int64)
        r = np.einsum("mij,mj->mi", self._inv[cell], p - self._origin[cell])
        ok = (cell >= 0) & self._affine[cell] & (np.abs(r - 0.5) <= 0.5 + tol).all(axis=1)
        ok &= np.all((p >= self._lo_all) & (p <= self._hi_all), axis=1)
        cell[~ok] = -1
        return cell, np.minimum(np.maximum(r, 0.0), 1.0)

    def updraft(self, height=0.1, margin=0.3):
        """A generator place: ``height`` above the fastest rising (+z) grid point in the lower half,
        ``margin`` from the side walls.

        Above a fire this is its plume, so the smoke is seeded where the hot air rises.
        """
        lo, hi = self.bounds[:, 0] + margin, self.bounds[:, 1] - margin
        p = self.points
        inside = np.all((p[:, :2] >= lo[:2]) & (p[:, :2] <= hi[:2]), axis=1) & (p[:, 2] < self.bounds[2].mean())
        if not inside.any():
            raise DataError(f"no grid point lies {margin} inside the side walls in the lower half", path=self.path)
        i = np.argmax(np.where(inside, self.vectors[:, 2], -np.inf))
        return p[i] + [0.0, 0.0, float(height)]
