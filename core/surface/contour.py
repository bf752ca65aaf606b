"""Contour (iso-)surfaces of a scalar field on a curvilinear grid.

:func:`isosurface` is marching cubes (Lorensen & Cline 1987) written as whole
array operations: the configuration byte of every cell from the sign of each
corner, then, for the cells the surface crosses only, a table lookup that
gives triangles in terms of the cell's edges.  Every crossed grid edge gets
exactly one vertex, found by linear interpolation of the values along the
edge, and neighbouring cells refer to it by the same arithmetic edge number,
so the surface comes out welded: a closed surface is watertight.
``method="tetra5"`` instead splits every cell into the five tetrahedra of the
paper (Max & Crawfis) and contours the linear interpolant on each.

Hard cases, handled so that the result stays a clean, consistently wound
surface:

* values exactly at the level count as above it (``>=`` throughout), and
  vertices keep a margin of 0.1 % of their edge from the grid points
  (:data:`EDGE_MARGIN`), so no triangle collapses to zero area;
* cells with a NaN corner are skipped (no NaN vertex can appear);
* ``periodic_lon=True`` closes the longitude ring: the last column's cells
  join column 0 (any number of longitudes; with ``tetra5`` and an odd number
  the seam column uses a 6-tetrahedron split, see :mod:`._mc_tables`);
* rows of grid points that coincide (the poles of a longitude-latitude grid)
  are one point: their values are averaged, their vertices merged, so no
  degenerate triangle or crack remains there; the cells on such a row use
  tables whose fans draw no diagonal inside a face shared with the next cell,
  so that merging never makes an edge shared by more than two triangles.

References
----------
.. [1] W. E. Lorensen and H. E. Cline, "Marching cubes: a high resolution 3D
   surface construction algorithm", SIGGRAPH 1987, Computer Graphics 21(4).
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (contour surfaces of 15% cloudiness from cells split into 5 tetrahedra).
"""

from functools import lru_cache

import numpy as np

from ..errors import DataError
from ..memory import check_memory
from . import _mc_tables as tables
from .mesh import Mesh, vertex_normals

METHODS = ("cubes", "tetra5")

EDGE_MARGIN = 1e-3
"""Vertices stay at least this fraction of their edge away from the grid
points.  Where a value equals the level (or lies within this margin of it)
the vertex moves by at most 0.1 % of the edge; in exchange every vertex is
distinct, so the topology is exactly that of the ``>=`` classification and no
triangle has zero area."""


BYTES_PER_CELL = {"cubes": 450, "tetra5": 900}
"""Peak memory of :func:`isosurface` per grid cell where every cell is crossed (random values; tracemalloc:
cubes 438 and 445 B at 64k and 512k cells, tetra5 857 and 858 B at 27k and 125k cells)."""


def regular_points(shape, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), dtype=np.float32):
    """Vertex positions ``(nk, nj, ni, 3)`` of a regular grid.

    ``spacing`` and ``origin`` are ``(x, y, z)`` with x along the fastest
    axis ``i`` and z along ``k``, so ``isosurface(regular_points(v.shape), v, ...)``
    contours a plain 3-D array.
    """
    nk, nj, ni = shape
    sx, sy, sz = spacing
    ox, oy, oz = origin
    out = np.empty((nk, nj, ni, 3), dtype=dtype)
    out[..., 0] = ox + sx * np.arange(ni)[None, None, :]
    out[..., 1] = oy + sy * np.arange(nj)[None, :, None]
    out[..., 2] = oz + sz * np.arange(nk)[:, None, None]
    return out


@lru_cache(maxsize=None)
def _cube_lookup():
    """Cube tables (plain; for cells on a south / north pole row; centre-fanned)
    and per local edge: family (i/j/k), lower-corner offset."""
    tabs = (tables.cube_table(), tables.polar_table(0), tables.polar_table(1), tables.cube_centre_table())
    pairs = np.array(tables.PAIRS)
    lower = tables.CORNERS[pairs[:, 0]]
    family = np.argmax(tables.CORNERS[pairs[:, 1]] - lower, axis=1)
    return tabs, family, lower


@lru_cache(maxsize=None)
def _tet_lookup():
    table, ntri = tables.tet_tables()
    return table, ntri, np.array(tables.PAIRS)


def isosurface(points, values, level, *, periodic_lon=False, method="cubes", attributes=None, close_poles=False):
    """The surface where ``values == level``.

    Parameters
    ----------
    points : (nk, nj, ni, 3) array
        Vertex positions of a curvilinear (or regular, see
        :func:`regular_points`) grid.
    values : (nk, nj, ni) array
        The scalar field at the vertices; NaN marks missing data.
    level : float
        The contour value.
    periodic_lon : bool
        Close the grid along ``i`` (longitude): column ``ni - 1`` joins column 0.
    method : {"cubes", "tetra5"}
        Marching cubes, or the paper's split of every cell into 5 tetrahedra.
    attributes : dict of str to (nk, nj, ni) arrays, optional
        Fields interpolated to the vertices with the same edge weights.
    close_poles : bool
        For a periodic longitude-latitude grid centred on the origin whose
        first and last latitude rows stop short of the poles (cell-centred
        latitudes such as ±89.44°): add the pole, on the ring's axis at the
        ring's mean distance from the origin, with the ring's mean value, so
        that surfaces reaching the pole are closed there instead of keeping a
        hole the size of the polar cap.  Rows already at a pole, and rows more
        than 10° from one (a latitude band), are left alone.

    Returns
    -------
    Mesh
        Vertices on grid edges (and, for ``tetra5``, face diagonals), faces
        counter-clockwise seen from the side where ``values < level``, unit
        normals pointing there (out of the region above the level), and the
        interpolated attributes.  ``Mesh.empty()`` when nothing crosses.

    References
    ----------
    .. [1] W. E. Lorensen and H. E. Cline, "Marching cubes", SIGGRAPH 1987.
    .. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
    """
    points, values, level, attributes = _check_inputs(points, values, level, periodic_lon, method, attributes)
    dtype = values.dtype if values.dtype in (np.float32, np.float64) else np.float64
    values = values.astype(dtype, copy=False)
    # The level in the values' precision: a float32 value that reads 0.15 is at the level 0.15.
    level = dtype.type(level)
    attributes = {k: np.asarray(a) for k, a in attributes.items()}

    if close_poles:
        if not periodic_lon:
            raise DataError("closing the poles needs periodic_lon=True (rings of longitudes)", field="close_poles")
        points, values, attributes = _add_poles(points, values, attributes)
    pole_rows = _collapsed_rows(points)
    if pole_rows is not None:
        values = _average_rows(values, pole_rows)
        attributes = {k: _average_rows(a.astype(np.float64), pole_rows) for k, a in attributes.items()}

    above = values >= level
    nan = np.isnan(values)
    has_nan = bool(nan.any())

    if method == "cubes":
        a, b, faces, ncentre = _cubes(above, nan if has_nan else None, periodic_lon, pole_rows)
    else:
        a, b, faces = _tetra(above, nan if has_nan else None, periodic_lon)
        ncentre = 0
    if len(faces) == 0:
        return Mesh.empty(attributes)

    vertices, attrs = _edge_vertices(points, values, level, attributes, a, b, faces, ncentre)
    faces, keep = _weld(a, b, faces, values.shape, pole_rows, len(vertices), drop_unused=has_nan or ncentre > 0)
    if len(faces) == 0:
        return Mesh.empty(attributes)
    if keep is not None:
        vertices = vertices[keep]
        attrs = {name: x[keep] for name, x in attrs.items()}
    vertices = vertices.astype(np.float32)
    attrs = {name: x.astype(np.float32) for name, x in attrs.items()}
    return Mesh(vertices, faces, vertex_normals(vertices, faces), attrs)


def _check_inputs(points, values, level, periodic_lon, method, attributes):
    """:func:`isosurface`'s arguments as arrays, each bad one a :class:`DataError` naming it."""
    points = np.asarray(points)
    values = np.asarray(values)
    if values.ndim != 3 or min(values.shape) < 2:
        raise DataError(f"needs shape (nk, nj, ni) with every size >= 2, got {values.shape}", field="values")
    if points.shape != values.shape + (3,):
        raise DataError(f"shape {points.shape} does not match values {values.shape} + (3,)", field="points")
    if not np.all(np.isfinite(points)):
        raise DataError("has NaN or infinite positions", field="points")
    if periodic_lon and values.shape[2] < 3:
        raise DataError(f"a periodic ring needs at least 3 longitudes, got {values.shape[2]}", field="values")
    if method not in METHODS:
        raise DataError(f"unknown method {method!r}; use one of {', '.join(METHODS)}", field="method")
    level = float(level)
    if not np.isfinite(level):
        raise DataError(f"must be finite, got {level}", field="level")
    check_memory(BYTES_PER_CELL[method] * values.size, f"contouring a {'x'.join(map(str, values.shape[::-1]))} grid "
                 f"({method})", hint="contour a coarser grid or a part of it", field="values")
    attributes = dict(attributes or {})
    for name, a in attributes.items():
        if np.shape(a) != values.shape:
            raise DataError(f"shape {np.shape(a)} does not match values {values.shape}", field=name)
    return points, values, level, attributes


def _edge_vertices(points, values, level, attributes, a, b, faces, ncentre):
    """Vertices (float64) and attributes interpolated on the cut edges ``(a, b)``, then the ``ncentre``
    loop centres the cube cases' fans need (:func:`_with_centres`)."""
    vflat = values.reshape(-1)
    va = vflat[a].astype(np.float64)
    vb = vflat[b].astype(np.float64)
    # Keep vertices off the grid points (see EDGE_MARGIN): a value exactly at
    # the level would otherwise put several vertices on one point and leave
    # zero-area triangles.
    t = np.clip((np.float64(level) - va) / (vb - va), EDGE_MARGIN, 1.0 - EDGE_MARGIN)

    pflat = points.reshape(-1, 3)
    pa = np.take(pflat, a, axis=0).astype(np.float64)  # take: rows gathered ~4x faster than fancy indexing
    vertices = pa + t[:, None] * (np.take(pflat, b, axis=0) - pa)
    attrs = {}
    for name, arr in attributes.items():
        f = arr.reshape(-1)
        fa = f[a].astype(np.float64)
        attrs[name] = fa + t * (f[b] - fa)
    if ncentre:
        vertices = _with_centres(vertices, faces, ncentre)
        attrs = {name: _with_centres(x, faces, ncentre) for name, x in attrs.items()}
    return vertices, attrs


def _with_centres(x, faces, ncentre):
    """Append the loop-centre values: the mean over each centre's triangles of their second vertex
    (every loop vertex is the second vertex of exactly one triangle of its fan)."""
    n = len(x)
    fan = np.flatnonzero(faces[:, 0] >= n)
    centre = faces[fan, 0] - n
    count = np.bincount(centre, minlength=ncentre)
    rim = x[faces[fan, 1]]
    cols = rim.reshape(len(rim), int(np.prod(x.shape[1:]))).T
    mean = np.stack([np.bincount(centre, c, ncentre).astype(np.float64) for c in cols], axis=1)
    mean = (mean / np.maximum(count, 1)[:, None]).reshape((ncentre,) + x.shape[1:])
    return np.concatenate([x, mean])


def _collapsed_rows(points):
    """Boolean (nk, nj) mask of rows whose ``ni`` points coincide (poles), or None."""
    first = points[:, :, 0, :].astype(np.float64)
    mid = points[:, :, points.shape[2] // 2, :].astype(np.float64)
    scale = max(np.abs(first).max(), np.abs(mid).max(), np.finfo(np.float64).tiny)
    tol = 1e-6 * scale
    cand = np.abs(first - mid).max(axis=-1) <= tol
    if not cand.any():
        return None
    kk, jj = np.nonzero(cand)
    rows = points[kk, jj].astype(np.float64)  # (n, ni, 3)
    ok = np.abs(rows - rows[:, :1]).max(axis=(1, 2)) <= tol
    mask = np.zeros(cand.shape, bool)
    mask[kk[ok], jj[ok]] = True
    return mask if mask.any() else None


POLE_RING = np.sin(np.deg2rad(10.0))
"""``close_poles`` closes a last row only if it lies within 10° of the pole."""


def _add_poles(points, values, attributes):
    """Add a pole row before row 0 and after row nj-1 where those rows are open rings."""
    collapsed = _collapsed_rows(points)
    poles = []
    for j in (0, points.shape[1] - 1):
        if collapsed is not None and collapsed[:, j].all():
            poles.append(None)
            continue
        ring = points[:, j].astype(np.float64)  # (nk, ni, 3)
        centre = ring.mean(axis=1, keepdims=True)
        size = np.linalg.norm(ring, axis=-1).mean(axis=1)
        spread = np.linalg.norm(ring - centre, axis=-1).mean(axis=1)
        if np.any(spread > POLE_RING * size):
            poles.append(None)  # a ring far from any pole (a latitude band): leave it open
            continue
        centre = centre[:, 0]
        poles.append(centre * (size / np.linalg.norm(centre, axis=-1))[:, None])  # (nk, 3)
    if poles[0] is None and poles[1] is None:
        return points, values, attributes

    def extend(field, pole_row):
        parts = [field]
        if poles[0] is not None:
            parts.insert(0, pole_row(0, field[:, :1]))
        if poles[1] is not None:
            parts.append(pole_row(1, field[:, -1:]))
        return np.concatenate(parts, axis=1)

    def ring_mean(end, row):
        return np.broadcast_to(row.mean(axis=2, keepdims=True), row.shape)

    def pole_point(end, row):
        return np.broadcast_to(poles[end][:, None, None, :], row.shape).astype(points.dtype)

    attributes = {k: extend(a, ring_mean) for k, a in attributes.items()}
    return extend(points, pole_point), extend(values, ring_mean), attributes


def _average_rows(field, rows):
    """One value per collapsed row: the mean along ``i`` (NaN if any is NaN)."""
    out = field.copy()
    out[rows] = field[rows].mean(axis=-1, keepdims=True)
    return out


def _cell_config(above, nan, periodic):
    """Configuration byte per cell, 0 for cells touching NaN; shape (nk-1, nj-1, nci).

    Built axis by axis (2 bits along i, then 4 along j, then 8 along k), so
    corner ``c = di + 2 dj + 4 dk`` lands on bit ``c``.
    """
    if periodic:
        above = np.concatenate([above, above[:, :, :1]], axis=2)
    x = above.view(np.uint8)
    x = x[:, :, :-1] | (x[:, :, 1:] << 1)
    x = x[:, :-1] | (x[:, 1:] << 2)
    cfg = x[:-1] | (x[1:] << 4)
    if nan is not None:
        if periodic:
            nan = np.concatenate([nan, nan[:, :, :1]], axis=2)
        bad = nan[:, :, :-1] | nan[:, :, 1:]
        bad = bad[:, :-1] | bad[:, 1:]
        cfg[bad[:-1] | bad[1:]] = 0
    return cfg


def _expand(active, cfg, ntri):
    """Cells repeated once per triangle, and each triangle's slot in the table."""
    counts = ntri[cfg[active]]
    cells = np.repeat(active, counts)
    starts = np.cumsum(counts) - counts
    slot = np.arange(len(cells)) - np.repeat(starts, counts)
    return cells, slot


def _cell_ijk(cells, cfg_shape):
    nci = cfg_shape[2]
    i = cells % nci
    r = cells // nci
    return r // cfg_shape[1], r % cfg_shape[1], i


def _cubes(above, nan, periodic, pole_rows):
    """Marching cubes.

    Returns the grid points ``(a, b)`` at the ends of each crossed edge (one
    vertex each), the faces, and the number of loop-centre vertices numbered
    after them (cells where a pole collapses at one level only; each centre
    triangle starts with its centre).
    """
    nk, nj, ni = above.shape
    nv = nk * nj * ni
    idx = np.int32 if 3 * nv < 2**31 else np.int64
    tabs, family, lower = _cube_lookup()
    cfg = _cell_config(above, nan, periodic)
    flat = cfg.reshape(-1)
    active = np.flatnonzero((flat != 0) & (flat != 255)).astype(idx)
    if len(active) == 0:
        return None, None, np.zeros((0, 3), np.int64), 0
    groups = [active]
    if pole_rows is not None:
        # Cells on a pole row (both levels) use the polar tables; cells touching
        # one in some other way (a pole at one level only) fan from centres.
        k, j, _ = _cell_ijk(active, cfg.shape)
        south = pole_rows[k, j] & pole_rows[k + 1, j]
        north = pole_rows[k, j + 1] & pole_rows[k + 1, j + 1] & ~south
        touch = pole_rows[k, j] | pole_rows[k, j + 1] | pole_rows[k + 1, j] | pole_rows[k + 1, j + 1]
        other = touch & ~south & ~north
        groups = [active[~touch], active[south], active[north], active[other]]

    # Arithmetic edge number: family * nv + flat index of the edge's lower corner.
    stride = np.array([1, ni, nj * ni])
    delta = np.zeros(tables.CENTRE + 4, idx)
    delta[: tables.CENTRE] = family * nv + lower @ stride
    wraps = np.zeros(tables.CENTRE + 4, idx)
    wraps[: tables.CENTRE] = ni * lower[:, 0]

    parts = []
    ncentre = 0
    for cells, (tab, counts) in zip(groups, tabs):
        cells, slot = _expand(cells, flat, counts)
        k, j, i = _cell_ijk(cells, cfg.shape)
        local = tab[flat[cells], slot]  # (T, 3) local edge numbers
        edge = ((k * nj + j) * ni + i)[:, None] + delta[local]
        if periodic:
            # Corners in the column after the last one are column 0.
            seam = np.flatnonzero(i == ni - 1)
            edge[seam] -= wraps[local[seam]]
        centre = None
        if (local >= tables.CENTRE).any():
            # Centre vertex ids: 4 per cell of the group, after the crossed-edge vertices.
            owners = np.unique(cells)
            centre = ncentre + np.searchsorted(owners, cells)[:, None] * 4 + (local - tables.CENTRE)
            ncentre += 4 * len(owners)
        parts.append((local, edge, centre))

    # Crossed edges, family by family, numbered in order: vertex id = lut[edge].
    ia = np.zeros((nk, nj, ni), bool)
    if periodic:
        np.not_equal(above, np.roll(above, -1, axis=2), out=ia)
    else:
        np.not_equal(above[:, :, :-1], above[:, :, 1:], out=ia[:, :, :-1])
    ja = np.zeros((nk, nj, ni), bool)
    np.not_equal(above[:, :-1], above[:, 1:], out=ja[:, :-1])
    ka = np.zeros((nk, nj, ni), bool)
    np.not_equal(above[:-1], above[1:], out=ka[:-1])
    if nan is not None:
        ia &= ~(nan | np.roll(nan, -1, axis=2))
        ja[:, :-1] &= ~(nan[:, :-1] | nan[:, 1:])
        ka[:-1] &= ~(nan[:-1] | nan[1:])
    lut = np.empty(3 * nv, idx)
    a_parts, b_parts = [], []
    n = 0
    for f, mask in enumerate((ia, ja, ka)):
        ids = np.flatnonzero(mask)
        lut[f * nv + ids] = np.arange(n, n + len(ids), dtype=idx)
        n += len(ids)
        b = ids + stride[f]
        if f == 0 and periodic:
            b -= ni * (ids % ni == ni - 1)
        a_parts.append(ids)
        b_parts.append(b)
    faces = []
    for local, edge, centre in parts:
        if centre is None:
            faces.append(lut[edge])
        else:
            is_centre = local >= tables.CENTRE
            faces.append(np.where(is_centre, n + centre, lut[np.where(is_centre, 0, edge)]))
    faces = faces[0] if len(faces) == 1 else np.concatenate(faces)
    return np.concatenate(a_parts), np.concatenate(b_parts), faces, ncentre


def _tetra(above, nan, periodic):
    """5-tetrahedra contouring: vertices on cube edges, face and body diagonals."""
    nk, nj, ni = above.shape
    nv = nk * nj * ni
    idx = np.int32 if 7 * nv < 2**31 else np.int64
    table, ntri, pairs = _tet_lookup()
    cfg = _cell_config(above, nan, periodic).reshape(-1)
    nci = ni if periodic else ni - 1
    active = np.flatnonzero((cfg != 0) & (cfg != 255)).astype(idx)
    if len(active) == 0:
        return None, None, np.zeros((0, 3), np.int64)
    k, j, i = _cell_ijk(active, (nk - 1, nj - 1, nci))
    # The split alternates with (i + j + k) % 2; seam column of an odd ring: flipped variant.
    case = ((k + j + i) & 1) * 256 + cfg[active]
    seam = i == ni - 1 if periodic else np.zeros(len(active), bool)
    if periodic and ni % 2:
        case[seam] += 2 * 256
    counts = ntri.reshape(-1)[case]
    width = table.shape[2]
    slot = np.arange(counts.sum(), dtype=idx) - np.repeat(np.cumsum(counts, dtype=idx) - counts, counts)
    local = table.reshape(-1, 3)[np.repeat(case, counts) * width + slot]  # (T, 3) local edges
    base = np.repeat((k * nj + j) * ni + i, counts)
    seam = np.repeat(seam, counts)

    # Every edge used is named arithmetically, without sorting: its kind
    # (3 axes, diagonal of an x-, y- or z-face, body diagonal) and the
    # lowest corner of the face or cell it lies in.  A face has one diagonal
    # (the split is consistent), a cell at most one body diagonal.
    c0, c1 = tables.CORNERS[pairs[:, 0]], tables.CORNERS[pairs[:, 1]]
    stride = np.array([1, ni, nj * ni])
    low = np.minimum(c0, c1)
    span = np.abs(c1 - c0)
    kind = np.select(
        [span.sum(axis=1) == 1, span.sum(axis=1) == 2], [np.argmax(span, axis=1), 3 + np.argmin(span, axis=1)], 6
    )
    key = base[:, None] + (kind * nv + low @ stride).astype(idx)[local]
    if periodic:
        rows = np.flatnonzero(seam)
        key[rows] -= (ni * low[local[rows], 0]).astype(idx)  # corners past the last column are column 0
    key = key.reshape(-1)
    # One representative triangle corner per key (whichever write lands), numbered in order.
    lut = np.empty(7 * nv, idx)
    lut[key] = np.arange(len(key), dtype=idx)
    rep = lut[key]
    first = np.flatnonzero(rep == np.arange(len(key), dtype=idx))
    number = np.empty(len(key), idx)
    number[first] = np.arange(len(first), dtype=idx)
    faces = number[rep].reshape(-1, 3)

    # Grid points at the ends of each vertex's edge.
    e = local.reshape(-1)[first]
    row = first // 3
    ends = []
    for c in (c0, c1):
        g = base[row] + (c @ stride)[e]
        if periodic:
            g = np.where(seam[row], g - ni * c[e, 0], g)
        ends.append(g.astype(np.int64))
    return ends[0], ends[1], faces


def _weld(a, b, faces, shape, pole_rows, n, drop_unused):
    """Merge the vertices that coincide along a pole and drop the triangles that collapse.

    ``a``, ``b``: grid points at the ends of the edge of each of the first
    ``len(a)`` vertices; vertices ``len(a)..n-1`` (loop centres) are never
    merged.  Returns the new faces and the indices of the vertices kept
    (None: all, in order).
    """
    nk, nj, ni = shape
    if pole_rows is not None:
        rows = pole_rows.reshape(-1)
        pa, pb = rows[a // ni], rows[b // ni]
        near = np.flatnonzero(pa | pb)
        if len(near):
            # All longitudes of a pole row are one point: name every edge end
            # there by its column-0 twin, so that coinciding edges (a pole
            # edge per longitude, or an edge and a face diagonal of a
            # collapsed face) share one vertex.
            nv = nk * nj * ni
            na, nb = a[near], b[near]
            na = np.where(pa[near], na - na % ni, na)
            nb = np.where(pb[near], nb - nb % ni, nb)
            key = np.minimum(na, nb) * nv + np.maximum(na, nb)
            _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
            rep = np.arange(n)
            rep[near] = near[first[inverse.reshape(-1)]]
            f = rep[faces]
            good = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
            return _compact(f[good], n)
    if drop_unused:
        return _compact(faces, n)
    return faces, None


def _compact(faces, n):
    """Renumber so that only vertices some face uses remain."""
    used = np.zeros(n, bool)
    used[faces.reshape(-1)] = True
    keep = np.flatnonzero(used)
    remap = np.full(n, -1, np.int64)
    remap[keep] = np.arange(len(keep))
    return remap[faces], keep
