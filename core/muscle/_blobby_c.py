"""The call sites of the compiled blobby kernels (``native/src/blobby_*.c``, through :mod:`..native`).

Each ``*_kernel()`` is the kernel with its ctypes signature, or None where the
``nephele_native`` wheel is not installed (then :mod:`.blobby` runs the NumPy twin in
:mod:`._blobby_numpy`); each call site lays the arrays out as the C side reads them.

References
----------
.. [1] W. E. Lorensen and H. E. Cline, "Marching cubes", SIGGRAPH 1987.
"""

import ctypes

import numpy as np

from .. import native
from ..surface.contour import EDGE_MARGIN
from ..threads import thread_map
from ._blobby_base import _F32, BLOCK, NEWTON_STEPS, SETTLE_STEP, _Chunk, _chunks


def _c_arrays(*arrays):
    """The arrays as C-contiguous int64 or float64 (copies where needed), for the compiled kernels."""
    return [np.ascontiguousarray(x, np.int64 if x.dtype.kind in "iub" else np.float64) for x in arrays]


def _block_pairs_kernel():
    return native.kernel("blobby_block_pairs", ctypes.c_int64, [ctypes.c_int64] * 2 + [ctypes.c_void_p] * 8
                         + [ctypes.c_double] * 2 + [ctypes.c_void_p] * 2 + [ctypes.c_int64] + [ctypes.c_void_p] * 5)


def _block_pairs_c(kernel, b, lo, cnt, tot, ra, size, index, cut, cut_fine):
    """``run(span)``: :func:`._blobby_numpy._block_pairs_run` by the compiled kernel (native/src/blobby_blocks.c)."""
    arrays = _c_arrays(lo, cnt, b.c, b.a, b.lnw, b.smax, ra, size, index.lo, index.dims)

    def run(span):
        start, stop = span
        m = int(tot[start:stop].sum())
        out = (np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.bool_), np.empty(m), np.empty(m))
        ptrs = [x.ctypes.data for x in arrays + list(out)]
        n = kernel(start, stop, *ptrs[:8], cut, cut_fine, *ptrs[8:10], index.box, *ptrs[10:])
        return tuple(x[:n] for x in out)

    return run


def _group_count_kernel():
    return native.kernel("blobby_group_count", None, [ctypes.c_int64] + [ctypes.c_void_p] * 3 + [ctypes.c_int64]
                         + [ctypes.c_void_p] * 2)


def _group_pairs_c(count, slot, cls, g, on_grid, na):
    """:func:`._blobby_numpy._group_pairs` by the compiled kernels (a counting sort, native/src/blobby_blocks.c)."""
    fill = native.kernel("blobby_group_fill", None, [ctypes.c_int64] + [ctypes.c_void_p] * 4 + [ctypes.c_int64]
                         + [ctypes.c_void_p] * 6)
    held = [*_c_arrays(slot, cls), np.ascontiguousarray(on_grid, np.bool_), *_c_arrays(g)]
    slot_p, cls_p, on_p, g_p = (x.ctypes.data for x in held)
    fine_start, grid_start = np.empty(na + 1, np.int64), np.empty(na + 1, np.int64)
    count(len(slot), slot_p, cls_p, on_p, na, fine_start.ctypes.data, grid_start.ctypes.data)
    fine_g, grid_g = np.empty(fine_start[-1], np.int64), np.empty(grid_start[-1], np.int64)
    first, cursor = np.empty(na, np.int64), np.empty(2 * na, np.int64)
    fill(len(slot), slot_p, cls_p, on_p, g_p, na, fine_start.ctypes.data, grid_start.ctypes.data, fine_g.ctypes.data,
         grid_g.ctypes.data, first.ctypes.data, cursor.ctypes.data)
    return fine_start, fine_g, grid_start, grid_g, first


def _node_values_kernel():
    return native.kernel("blobby_node_values", None, [ctypes.c_int64] + [ctypes.c_void_p] * 10)


def _node_values_c(kernel, b, grid, blocks, threads, act):
    """:func:`._blobby_numpy._node_values` by the compiled kernel (native/src/blobby_nodes.c), runs of blocks
    on threads."""
    values = np.empty((len(act), BLOCK, BLOCK, BLOCK), _F32)
    act, *arrays = _c_arrays(act, blocks.grid_start, blocks.grid_g, blocks.q, b.c, b.a, b.lnw, grid.h, grid.size)
    ptrs = [x.ctypes.data for x in arrays]
    step = 1024  # blocks per call: a few ms, shared out to the threads as they come free

    def run(lo):
        kernel(min(step, len(act) - lo), act[lo:].ctypes.data, *ptrs, values[lo:].ctypes.data)

    thread_map(run, range(0, len(act), step), threads)
    return values


def _march_count_kernel():
    return native.kernel(
        "blobby_march_count", None, [ctypes.c_int64, ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p]
    )


_CHUNK_FIELDS = (  # the _Chunk arrays the march kernel writes (in struct march_out's order): dtype, row shape, size
    ("blk", np.int32, (), "v"), ("axis", np.int8, (), "v"), ("node", np.uint8, (3,), "v"), ("t", np.float64, (), "v"),
    ("curv", _F32, (), "v"), ("a_above", np.bool_, (), "v"), ("faces", np.int32, (3,), "tri"),
    ("ref_owner", np.int32, (), "ghost"), ("ref_slot", np.int32, (), "ghost"), ("ref_shift", np.int8, (3,), "ghost"),
    ("dup_key", np.int64, (), "dup"), ("dup_shift", np.int64, (3,), "dup"), ("face_key", np.int64, (), "face"),
    ("face_vid", np.int32, (), "face"),
)

def _march_c(count, values, blocks, grid, level, bl, et, loc):
    """:func:`._blobby_numpy._march` by the compiled kernel (native/src/blobby_march.c): one pass counts, the
    next writes."""
    emit = native.kernel("blobby_march_emit", None, [ctypes.c_int64, ctypes.c_double, ctypes.c_double, ctypes.c_int64]
                         + [ctypes.c_void_p] * 3)
    ext = np.empty((len(bl), (BLOCK + 1) ** 3), _F32)  # scratch: the blocks' extended nodes
    # struct march_in, in its order (int64 but values, table and kind)
    held = [x if x is None else np.ascontiguousarray(x) for x in (
        bl.astype(np.int64), values, None if loc is None else loc.astype(np.int64), blocks.nbr, blocks.q,
        None if grid.box is None else grid.nb.astype(np.int64), blocks.node_lo, blocks.node_dims, et.table, et.ntri,
        et.kind, et.face_index, ext)]
    march_in = (ctypes.c_void_p * len(held))(*(x if x is None else x.ctypes.data for x in held))
    n = np.zeros(5, np.int64)  # owned vertices, ghost edges, duplicates, triangles, face vertices
    count(len(bl), level, march_in, n.ctypes.data)
    size = {"v": n[0] + n[2], "ghost": n[1], "dup": n[2], "tri": n[3], "face": n[4]}
    out = {name: np.empty((int(size[k]),) + shape, dt) for name, dt, shape, k in _CHUNK_FIELDS}
    march_out = (ctypes.c_void_p * len(out))(*(x.ctypes.data for x in out.values()))
    emit(len(bl), level, EDGE_MARGIN, len(et.face_slots), march_in, n.ctypes.data, march_out)
    return _Chunk(n_owned=int(n[0]), **out)

def _project_kernel():
    """native/src/blobby_project.c's ``blobby_project`` with its argument types, or None."""
    i8, u8, b8, i32, i64, f32, f64 = (
        np.ctypeslib.ndpointer(k, flags="C_CONTIGUOUS")
        for k in (np.int8, np.uint8, np.bool_, np.int32, np.int64, np.float32, np.float64)
    )
    n, x = ctypes.c_int64, ctypes.c_double
    return native.kernel("blobby_project", ctypes.c_int, [
        n, i64, i32, i8, u8, f64, f32, b8,  # vertices
        i64, i64, i64, f64, f64, f64, i64, n,  # blocks, Gaussians
        f64, f64, i64, n, x, x, x, x, n,  # grid, rules
        f32, f32, b8, i32])  # outputs

_PROJECT_CHUNK = 1 << 15
"""Vertices per call of the compiled projection (a few ms), handed to the threads as they come free."""

def _project_c(kernel, refiner, grid, blk, axis, node, t, curv, a_above, level, tol, threads):
    """:func:`._blobby_numpy._project` by the compiled kernel: chunks of the vertices sorted by block (each call
    gathers a block's Gaussians once) on threads."""
    b, blocks, n = refiner.b, refiner.blocks, len(t)
    order = np.argsort(blk, kind="stable").astype(np.int64, copy=False)
    c = np.ascontiguousarray
    periodic = grid.box is not None
    args = (c(blk, np.int32), c(axis, np.int8), c(node, np.uint8), c(t, np.float64), c(curv, _F32), c(a_above, bool),
            c(blocks.q, np.int64), c(blocks.fine_start, np.int64), c(blocks.fine_g, np.int64), c(b.c, np.float64),
            c(b.a, np.float64), c(b.lnw, np.float64), c(b.src, np.int64), int(refiner.count.max()),
            c(grid.h, np.float64), c(grid.box, np.float64) if periodic else np.zeros(3),
            # per axis the node lying at exactly L (periodic), else none
            c(BLOCK * grid.nb, np.int64) if periodic else np.full(3, np.iinfo(np.int64).max),
            BLOCK, level, tol, SETTLE_STEP, EDGE_MARGIN, NEWTON_STEPS)
    out = (np.empty((n, 3), _F32), np.empty((n, 3), _F32), np.empty(n, bool), np.empty(n, np.int32))

    def run(span):
        if kernel(span[1] - span[0], order[span[0] : span[1]], *args, *out):
            raise MemoryError("blobby: no memory for a block's Gaussian columns")

    thread_map(run, _chunks(n, _PROJECT_CHUNK), threads)
    return out
