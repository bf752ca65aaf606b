"""Curvilinear globe fields resampled into sparse Cartesian block volumes (VDB-style).

Blender renders volumes on regular grids; climate fields live on a
longitude × latitude × terrain-following-level grid.  :func:`resample`
bridges the two:

* the field is defined everywhere by trilinear interpolation in the
  curvilinear cell (:class:`~.curvilinear.CurvilinearField`): a Cartesian point is mapped
  back analytically to longitude, latitude and height, the longitude and
  latitude give the fractional column index (periodic longitude, the poles
  closed by a ring of the last row's mean), and the level is found by
  searching the column's bilinearly interpolated terrain-following heights;
* only blocks of ``block``³ voxels (8³, OpenVDB's leaf nodes) that may have a
  non-zero opacity are ever evaluated: grid cells whose value range meets the
  transfer function's non-zero range give Cartesian bounding boxes, and those
  give the block set — transparent space costs nothing, memory follows the
  cloudy volume;
* a voxel's density is the transfer function's opacity of the interpolated
  value (NaN, outside the grid and below the terrain are empty); a second
  grid carries a colour variable (or the altitude) for the colour map.

Voxel index ``(a, b, c)`` sits at world position ``voxel_size * (a, b, c)``
(OpenVDB's linear transform), block ``(A, B, C)`` holds indices
``block*A .. block*A+block-1`` along each axis, arrays ordered ``[x, y, z]``.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
.. [2] K. Museth, "VDB: High-resolution sparse volumes with dynamic
   topology", ACM Trans. Graph. 32(3), 2013 (8³ leaf nodes).
"""

from dataclasses import dataclass

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, height_from_radius, xyz_to_lonlat
from ..errors import DataError
from ..memory import check_memory
from ..threads import default_threads
from .curvilinear import CurvilinearField
from .transfer import TransferFunction

DEFAULT_VOXEL_SIZE = 0.0027
"""Scene units (the sea-level globe has radius 1): ~570 m of height at the
default exaggeration, 17 km across.  On the demo climate, rays of the Fig. 2
view have an opacity error of 1.5 % of full scale at the 99th percentile
(0.6 % rms); rays grazing the cloud layers (the limb) do much worse, up to
~60 % for a ray running along a layer at the threshold; one step resamples
in ~1.5 s on two threads (``benchmarks/bench_volume.py``)."""


DEFAULT_EXTINCTION = 300.0
"""Extinction per scene unit at opacity 1: a full cloud 0.0033 units thick
(~700 m at exaggeration 30) has optical depth 1."""


ALTITUDE = "altitude"
"""Colour-variable name meaning "the height above sea level in metres"."""


EXACT = "exact"
"""Volume mode: the renderer shades the curvilinear field itself
(:mod:`nephele.core.volume.volume_atlas`); opacity exact along every ray."""


VOXELS = "voxels"
"""Volume mode: opacity resampled into cubic voxels (:func:`resample`)."""


@dataclass(eq=False)
class SparseVolume:
    """Blocks of voxels: the output of :func:`resample`.

    Attributes
    ----------
    voxel_size : float
        Scene units between voxel centres.
    block : int
        Voxels per block edge (8).
    blocks : (n, 3) int32
        Block coordinates; voxel index = ``block * blocks[b] + local``.
    density : (n, block, block, block) float32
        Opacity from the transfer function, axes ``[x, y, z]``.
    color : (n, block, block, block) float32 or None
        The colour variable, NaN replaced by 0.
    color_name : str or None
    stats : dict
        ``candidate_cells``, ``boxed_blocks`` (sub-blocks meeting the
        candidate cells' boxes), ``candidate_blocks`` (those evaluated),
        ``blocks``, ``active_voxels``,
        ``bytes`` of the kept arrays.
    """

    voxel_size: float
    block: int
    blocks: np.ndarray
    density: np.ndarray
    color: np.ndarray = None
    color_name: str = None
    stats: dict = None

    @property
    def empty(self):
        return self.blocks.shape[0] == 0

    def arrays(self):
        """Plain arrays for ``np.savez`` / the cache (no pickle)."""
        out = {
            "voxel_size": np.float64(self.voxel_size),
            "block": np.int64(self.block),
            "blocks": self.blocks,
            "density": self.density,
        }
        if self.color is not None:
            out["color"] = self.color
        return out

    @classmethod
    def from_arrays(cls, d, color_name=None):
        return cls(
            float(d["voxel_size"]), int(d["block"]), np.asarray(d["blocks"]), np.asarray(d["density"]),
            np.asarray(d["color"]) if "color" in d else None, color_name, {},
        )

    def bounds(self):
        """World-space ``(min, max)`` corners of the voxel centres, or None if empty."""
        if self.empty:
            return None
        lo = self.blocks.min(axis=0) * self.block
        hi = (self.blocks.max(axis=0) + 1) * self.block - 1
        return lo * self.voxel_size, hi * self.voxel_size

    def sample(self, xyz, grid="density"):
        """Trilinear interpolation between voxel centres (zero outside blocks)."""
        data = self.density if grid == "density" else self.color
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(xyz.shape[0])
        if self.empty:
            return out
        B = self.block
        u = xyz / self.voxel_size
        base = np.floor(u).astype(np.int64)
        f = u - base
        keys = _block_keys(self.blocks)
        order = np.argsort(keys)
        skeys = keys[order]
        flat = data.reshape(data.shape[0], -1)
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    idx = base + (dx, dy, dz)
                    blk = np.floor_divide(idx, B)
                    loc = idx - blk * B
                    k = _block_keys(blk)
                    pos = np.clip(np.searchsorted(skeys, k), 0, skeys.size - 1)
                    hit = skeys[pos] == k
                    v = np.where(hit, flat[order[pos], (loc[:, 0] * B + loc[:, 1]) * B + loc[:, 2]], 0.0)
                    w = (
                        (f[:, 0] if dx else 1 - f[:, 0])
                        * (f[:, 1] if dy else 1 - f[:, 1])
                        * (f[:, 2] if dz else 1 - f[:, 2])
                    )
                    out += w * v
        return out


_KEY_OFFSET = 1 << 20
def _block_keys(b):
    """One int64 per block coordinate triple (|coordinate| < 2**20)."""
    b = np.asarray(b, dtype=np.int64) + _KEY_OFFSET
    return (b[..., 0] << 42) | (b[..., 1] << 21) | b[..., 2]


def _keys_to_blocks(k):
    m = (1 << 21) - 1
    return (np.stack([(k >> 42) & m, (k >> 21) & m, k & m], axis=-1) - _KEY_OFFSET).astype(np.int32)


def candidate_blocks(field, name, tf, voxel_size, block=8, *, pad=0.0, below=None):
    """Blocks that may hold a non-zero opacity, and the candidate cells.

    Returns ``(blocks (n, 3) int32, cells (nk-1, nj-1, ni-1) bool)``.

    A cell can be non-zero only when its corner values' range meets the
    transfer function's open non-zero range (trilinear values stay within the
    corners' range); its Cartesian bounding box, padded by how far the
    curved faces bulge past the corners, bounds its voxels.  ``pad`` (scene
    units) widens every box; ``below`` (scene units, default 1.75 voxels)
    how far boxes of the lowest cells reach into the ground.
    """
    support = tf.support()
    v = field.values[name]
    if support is None:
        return np.zeros((0, 3), np.int32), np.zeros(tuple(n - 1 for n in v.shape), bool)
    lo, hi = support
    cmax = v[:-1, :-1, :-1]
    cmin = cmax
    for dk in (0, 1):
        for dj in (0, 1):
            for di in (0, 1):
                if dk or dj or di:
                    s = v[dk : v.shape[0] - 1 + dk, dj : v.shape[1] - 1 + dj, di : v.shape[2] - 1 + di]
                    cmax = np.maximum(cmax, s)  # NaN propagates: cells touching NaN drop out
                    cmin = np.minimum(cmin, s)
    with np.errstate(invalid="ignore"):
        cand = (cmax > lo) & (cmin < hi)
    kk, jj, ii = np.nonzero(cand)
    if kk.size == 0:
        return np.zeros((0, 3), np.int32), cand
    pts = field.cell_corner_points()
    bmin = np.full((kk.size, 3), np.inf)
    bmax = np.full((kk.size, 3), -np.inf)
    for dk in (0, 1):
        for dj in (0, 1):
            for di in (0, 1):
                p = pts[kk + dk, jj + dj, ii + di]
                np.minimum(bmin, p, out=bmin)
                np.maximum(bmax, p, out=bmax)
    # Faces between corners are arcs: pad by the sagitta of the widest arc.
    widest = (
        field.columns.cell_degrees()
        if field.columns is not None
        else max(np.diff(field.lon).max(), np.diff(field.lat).max())
    )
    dang = np.deg2rad(widest)
    rmax = field.radius_range()[1]
    pad = rmax * (1 - np.cos(dang / 2)) + 1e-9 + pad
    # Cells on the lowest level also reach one voxel diagonal into the ground
    # (the resampler extends the field there, see CurvilinearField.locate).
    below = 1.75 * voxel_size if below is None else below
    pad = pad + np.where(kk == 0, below, 0.0)[:, None]
    first = np.ceil((bmin - pad) / voxel_size).astype(np.int64)
    last = np.floor((bmax + pad) / voxel_size).astype(np.int64)
    b0 = np.floor_divide(first, block)
    b1 = np.floor_divide(last, block)
    span = b1 - b0
    lo = b0.min(axis=0)
    shape = tuple(int(n) for n in b1.max(axis=0) - lo + 1)
    # Mark blocks in a dense boolean grid of blocks when it is small (sorted
    # and duplicate-free for free), else collect keys and sort them.
    mark = np.zeros(shape, bool) if np.prod(shape, dtype=np.float64) <= 64e6 else None
    keys = []
    # Offsets nested axis by axis, each level keeping only the cells that
    # reach that far (most boxes span one or two blocks).
    for ox in range(int(span[:, 0].max()) + 1):
        sx = np.flatnonzero(span[:, 0] >= ox)
        for oy in range(int(span[sx, 1].max()) + 1):
            sy = sx[span[sx, 1] >= oy]
            if not sy.size:
                continue
            for oz in range(int(span[sy, 2].max()) + 1):
                sel = sy[span[sy, 2] >= oz]
                if not sel.size:
                    continue
                off = np.array([ox, oy, oz])
                if mark is not None:
                    b = b0[sel] + (off - lo)
                    mark[b[:, 0], b[:, 1], b[:, 2]] = True
                else:
                    keys.append(_block_keys(b0[sel] + off))
    if mark is not None:
        return (np.argwhere(mark) + lo).astype(np.int32), cand
    return _keys_to_blocks(np.unique(np.concatenate(keys))), cand


def _near_candidates(field, table, blocks, sub, voxel_size):
    """Which blocks of ``sub``³ voxels can hold a located point: their
    bounding ball, seen from the globe's centre, is tested against the
    candidate height range of every grid column it may overlap (blocks near
    a pole or with a wide window are kept)."""
    n = blocks.shape[0]
    keep = np.ones(n, bool)
    if n == 0 or field.columns is not None:  # a curvilinear grid: no lon/lat axes to test against
        return keep
    c = (blocks.astype(np.float64) * sub + 0.5 * (sub - 1)) * voxel_size
    R = 0.5 * (sub - 1) * np.sqrt(3.0) * voxel_size * 1.001 + 1e-12
    lon, lat, r = xyz_to_lonlat(c if field.rotation is None else c @ field.rotation)
    h = height_from_radius(r, field.radius, field.exaggeration)
    dh = R / height_scale(field.exaggeration, field.radius)
    theta = np.rad2deg(np.arcsin(np.minimum(R / np.maximum(r, R), 1.0)))
    a = np.deg2rad(np.minimum(np.abs(lat) + theta, 90.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        tl = np.rad2deg(np.arcsin(np.minimum(np.sin(np.deg2rad(theta)) / np.cos(a), 1.0)))
    testable = (np.abs(lat) + theta < 90.0) & (tl < 45.0) & (r > R)
    ti, tj = field._index_tables
    nci = field.lon.size - 1
    periodic = field.lon[-1] == 360.0
    x = np.mod(lon - field.lon0, 360.0)
    x0, x1 = x - tl, x + tl
    if periodic:
        x0, x1 = np.mod(x0, 360.0), np.mod(x1, 360.0)
    i0, i1 = ti(x0), ti(x1)
    j0, j1 = tj(lat - theta), tj(lat + theta)
    wi = np.mod(i1 - i0, nci) if periodic else i1 - i0
    wj = j1 - j0
    widest = 2
    testable &= (wi <= widest) & (wj <= widest)
    hit = np.zeros(n, bool)
    for dj in range(widest + 1):
        for di in range(widest + 1):
            m = testable & (dj <= wj) & (di <= wi)
            cell = np.minimum(j0 + dj, field.lat.size - 2) * nci + (
                np.mod(i0 + di, nci) if periodic else np.minimum(i0 + di, nci - 1)
            )
            hit |= m & (table.hlo[cell] <= h + dh) & (table.hhi[cell] >= h - dh)
    keep[testable] = hit[testable]
    return keep


def scalar_field(grid, values, color_values=None, color_name=None, radius=1.0, exaggeration=DEFAULT_EXAGGERATION):
    """The :class:`CurvilinearField` of ``values`` (as ``"value"``) and, for a
    colour variable other than :data:`ALTITUDE`, ``color_values`` (as ``"color"``)."""
    arrays = {"value": values}
    if color_name is not None and color_name != ALTITUDE:
        if color_values is None:
            raise DataError("color_values are needed for a colour variable other than altitude", field=color_name)
        arrays["color"] = color_values
    return CurvilinearField.from_grid(grid, arrays, radius, exaggeration)


def resample(
    grid,
    values,
    tf,
    *,
    voxel_size=DEFAULT_VOXEL_SIZE,
    color_values=None,
    color_name=None,
    radius=1.0,
    exaggeration=DEFAULT_EXAGGERATION,
    block=8,
    chunk_blocks=1024,
    workers=None,
):
    """Resample one time step into a sparse block volume of opacity (and colour).

    Parameters
    ----------
    grid : GlobeGrid
    values : (nk, nj, ni) array
        The scalar behind the opacity (cloudiness); NaN = missing.
    tf : TransferFunction
        Opacity of the scalar; zero below its threshold.
    voxel_size : float
        Scene units between voxel centres.
    color_values : (nk, nj, ni) array, optional
        Second variable carried in the ``color`` grid.
    color_name : str, optional
        Its name; :data:`ALTITUDE` (``"altitude"``) stores each voxel's
        height in metres instead (``color_values`` then unused).
    radius, exaggeration : float
        The globe mapping, as in :meth:`GlobeGrid.points`.
    block : int
        Voxels per block edge.
    chunk_blocks : int
        Blocks evaluated per batch (bounds the temporary memory).
    workers : int, optional
        Threads evaluating batches (numpy releases the GIL in most of it);
        default :func:`nephele.core.threads.default_threads`.

    Returns
    -------
    SparseVolume
        Only blocks with some non-zero opacity.

    References
    ----------
    .. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
    """
    if not isinstance(tf, TransferFunction):
        raise DataError(f"needs a TransferFunction, got {type(tf).__name__}", field="transfer function")
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise DataError(f"must be a positive number of scene units, got {voxel_size}", field="voxel_size")
    if int(block) < 1:
        raise DataError(f"must be >= 1, got {block}", field="block")
    block = int(block)
    field = scalar_field(grid, values, color_values, color_name, radius, exaggeration)
    # Blocks further out than the whole globe would overflow the block keys.
    if field.radius_range()[1] / (voxel_size * block) > (_KEY_OFFSET - 2):
        raise DataError(f"voxel size {voxel_size} is too small for a globe of radius {radius}", field="voxel_size")
    # Evaluate in sub-blocks half a block wide (a thin cloud layer fills few
    # of them), then gather the non-empty ones into whole blocks.
    sub = block // 2 if block % 2 == 0 and block >= 4 else block
    blocks, table, stats = _sub_block_candidates(field, tf, voxel_size, sub, height_scale(exaggeration, radius))
    parts = _evaluate_sub_blocks(field, table, tf, blocks, sub, voxel_size, color_name, chunk_blocks,
                                 default_threads() if workers is None else workers)
    kb, kd, kc = _gather_blocks(parts, block, sub, color_name is not None)
    stats.update({
        "blocks": int(kb.shape[0]),
        "active_voxels": int(np.count_nonzero(kd)),
        "voxels": int(kb.shape[0]) * block**3,
        "bytes": int(kd.nbytes + (kc.nbytes if kc is not None else 0) + kb.nbytes),
    })
    return SparseVolume(float(voxel_size), block, kb, kd, kc, color_name, stats)


def _sub_block_candidates(field, tf, voxel_size, sub, metres_per_unit):
    """Sub-blocks of ``sub``³ voxels that may hold opacity, the columns' level table, and the first stats.

    Blocks come from the cells whose value range meets the transfer function's
    non-zero range (:func:`candidate_blocks`), then only those near a candidate
    cell (:func:`_near_candidates`); per column the levels searched are the
    candidate ones, padded by 1.75 voxels of height.
    """
    blocks, cells = candidate_blocks(field, "value", tf, voxel_size, sub)
    # Per column, the range of candidate levels: points elsewhere are transparent.
    nkc = cells.shape[0]
    has = cells.any(axis=0)
    levels = (
        np.where(has, np.argmax(cells, axis=0), 1),
        np.where(has, nkc - 1 - np.argmax(cells[::-1], axis=0), 0),
    )
    table = field.level_table(levels, 1.75 * voxel_size / metres_per_unit)
    near = blocks[_near_candidates(field, table, blocks, sub, voxel_size)]
    # ~20 bytes per voxel of the candidate blocks at the peak (tracemalloc on demo:small, voxel 0.0027:
    # 14.4 M block voxels, 284 MB; the add-on's BYTES_PER_VOXEL).
    check_memory(20.0 * near.shape[0] * sub**3, f"resampling {near.shape[0]:,} blocks of {sub}^3 voxels "
                 f"(voxel size {voxel_size:g})", hint="raise the voxel size or lower the exaggeration",
                 field="voxel_size")
    stats = {"candidate_cells": int(np.count_nonzero(cells)), "boxed_blocks": int(blocks.shape[0]),
             "candidate_blocks": int(near.shape[0])}
    return near, table, stats


def _evaluate_sub_blocks(field, table, tf, blocks, sub, voxel_size, color_name, chunk_blocks, workers):
    """Opacity (and colour) of the sub-blocks ``blocks``, ``chunk_blocks`` at a time on ``workers`` threads.

    Returns per chunk ``(kept sub-blocks, density, colour or None)``, only sub-blocks with some opacity.
    """
    with_color = color_name is not None

    def run(start):
        b = blocks[start : start + chunk_blocks].astype(np.int64)
        # Voxel centres per axis, broadcast to (block, x, y, z): longitude and
        # its cell depend on x and y only, so they are found once per column.
        X, Y, Z = ((b[:, a, None] * sub + np.arange(sub)) * voxel_size for a in range(3))
        X, Y, Z = X[:, :, None, None], Y[:, None, :, None], Z[:, None, None, :]
        full = (b.shape[0], sub, sub, sub)
        if field.columns is not None:  # a curvilinear grid: fractional column indices per voxel
            lon, i, fi, lat, h = field._column_coords(np.stack(np.broadcast_arrays(X, Y, Z), axis=-1).reshape(-1, 3))
        elif field.rotation is None:
            lon, i, fi = (np.broadcast_to(a, full).reshape(-1) for a in field._lon_index(X, Y))
            lat, h = (np.broadcast_to(a, full).reshape(-1) for a in field._lat_height(X * X + Y * Y, Z))
        else:  # a rotated-pole grid: locate in its own frame, where lon/lat no longer split by axis
            P = np.stack(np.broadcast_arrays(X, Y, Z), axis=-1).reshape(-1, 3) @ field.rotation
            lon, i, fi = field._lon_index(P[:, 0], P[:, 1])
            lat, h = field._lat_height(P[:, 0] ** 2 + P[:, 1] ** 2, P[:, 2])
        sel, flat, fk, fj, fi, h = field._locate_columns(lon, i, fi, lat, h, table)
        nvox = lat.size
        dens = np.zeros(nvox, dtype=np.float32)
        col = np.zeros(nvox, dtype=np.float32) if with_color else None
        if sel.size:
            dens[sel] = np.nan_to_num(tf(field._trilinear("value", flat, fk, fj, fi)), nan=0.0)
            if color_name == ALTITUDE:
                col[sel] = h[sel]
            elif with_color:
                col[sel] = np.nan_to_num(field._trilinear("color", flat, fk, fj, fi), nan=0.0)
        dens = dens.reshape(-1, sub, sub, sub)
        keep = dens.reshape(dens.shape[0], -1).max(axis=1) > 0
        return b[keep], dens[keep], None if col is None else col.reshape(-1, sub, sub, sub)[keep]

    starts = list(range(0, blocks.shape[0], chunk_blocks))
    if workers > 1 and len(starts) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=int(workers)) as ex:
            return list(ex.map(run, starts))
    return [run(s) for s in starts]


def _gather_blocks(parts, block, sub, with_color):
    """The evaluated sub-blocks gathered into whole ``block``³ blocks: ``(blocks, density, colour or None)``."""
    sb = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3), np.int64)
    keys, inverse = np.unique(_block_keys(np.floor_divide(sb, block // sub)), return_inverse=True)
    kb = _keys_to_blocks(keys)
    kd = np.zeros((keys.size, block, block, block), np.float32)
    kc = np.zeros_like(kd) if with_color else None
    if sb.shape[0]:
        inverse = inverse.reshape(-1)
        ratio = block // sub
        off = sb - np.floor_divide(sb, ratio) * ratio
        sd = np.concatenate([p[1] for p in parts])
        # Scatter every sub-block into its block: axes (block, ox, x, oy, y, oz, z),
        # contiguous runs of ``sub`` voxels per copy.
        view = (keys.size, ratio, sub, ratio, sub, ratio, sub)
        kd.reshape(view)[inverse, off[:, 0], :, off[:, 1], :, off[:, 2], :] = sd
        if with_color:
            kc.reshape(view)[inverse, off[:, 0], :, off[:, 1], :, off[:, 2], :] = np.concatenate([p[2] for p in parts])
    return kb, kd, kc


def height_scale(exaggeration=DEFAULT_EXAGGERATION, radius=1.0):
    """Scene units per metre of height."""
    return radius * exaggeration / EARTH_RADIUS


__all__ = [
    "ALTITUDE",
    "DEFAULT_EXTINCTION",
    "DEFAULT_VOXEL_SIZE",
    "EXACT",
    "VOXELS",
    "CurvilinearField",
    "SparseVolume",
    "candidate_blocks",
    "height_scale",
    "resample",
]
