"""The blobby mesher's compiled kernels (native/src/blobby_nodes.c: node values and block search;
native/src/blobby_march.c: marching cubes) against their NumPy twins, and the mesh by either path."""

import dataclasses

import numpy as np
import pytest
from blob_scenes import edges, rotations

from nephele.core import native
from nephele.core.muscle import _blobby_base, _blobby_numpy, level_distance
from nephele.core.muscle import blobby as bb

pytestmark = pytest.mark.skipif(native.identity() == "numpy", reason="no compiled kernels")

LEVEL, H = 0.3, 0.125


def scene(seed, n, side):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, side, (n, 3)), rotations(rng, n), rng.uniform(0.4, 1.2, (n, 3)), rng.uniform(0.6, 1.4, n)


def thin(seed):
    """A 20:1 Gaussian along a random axis."""
    rot = rotations(np.random.default_rng(seed), 1)
    return np.array([[1.0, 2.0, 3.0]]), rot, np.array([[4.0, 0.2, 0.2]]), np.array([1.0])


def sheared():
    """A Gaussian thin along (1, 0, -1): its x-z table reaches exp(100), its node values do not."""
    s2 = np.sqrt(0.5)
    rot = np.array([[[s2, 0, s2], [0, 1, 0], [-s2, 0, s2]]])
    return np.array([[0.4, 0.5, 0.45]]), rot, np.array([[0.06, 1.0, 1.0]]), np.array([1.5])


def setup(c, r, s, w, h=H, box=None):
    box = None if box is None else np.array(box)
    b = bb._blobs(*bb._check(c, r, s, w))
    if box is not None:
        b = bb._images(b, box, 5.0)
    grid = bb._grid(h, box)
    return b, grid, bb._find_blocks(b, grid, LEVEL, 4.0, 5.0, 1)


def numpy_path(monkeypatch):
    monkeypatch.setattr(native, "_module", lambda: None)


CASES = {
    "plain": (scene(1, 300, 20.0), H, None),
    "periodic": (scene(2, 300, 20.0), H, (20.0, 21.0, 19.0)),
    "thin": (thin(3), 0.05, None),
    "sheared": (sheared(), H, None),
}


@pytest.mark.parametrize("case", list(CASES))
def test_node_values_match_numpy(case, monkeypatch):
    blobs, h, box = CASES[case]
    b, grid, blocks = setup(*blobs, h=h, box=box)
    if case == "sheared":  # the large-exponent case is exercised: -u_x u_z a_xz > 40 at a block corner
        assert (-(7 * h) ** 2 * b.a[:, 4]).max() > 2 * _blobby_numpy._EXP_MAX
    got = bb._node_values(b, grid, blocks, 2)
    numpy_path(monkeypatch)
    want = bb._node_values(b, grid, blocks, 2)
    assert got.shape == want.shape and got.dtype == want.dtype == np.float32
    # Same float32 operations but the exp (libm's against NumPy's): a few ulps.
    assert np.all(np.abs(got.astype(float) - want) <= 2e-6 * want + 1e-37)
    assert np.mean(got == want) > 0.2
    assert (want >= LEVEL).any() and (want < LEVEL).any()


def test_node_values_same_bits_in_any_subset():
    b, grid, blocks = setup(*scene(4, 300, 20.0))
    full = bb._node_values(b, grid, blocks, 2)
    rng = np.random.default_rng(0)
    for some in (rng.permutation(len(blocks.q))[: len(blocks.q) // 3], np.arange(len(blocks.q))[::-5], np.array([7])):
        assert np.array_equal(bb._node_values(b, grid, blocks, 2, some), full[some])
        assert np.array_equal(bb._node_values(b, grid, blocks, 1, some), full[some])


def watertight(mesh):
    once, _, cnt = edges(mesh.faces)
    assert once  # consistent winding
    assert np.all(cnt == 2)


@pytest.mark.parametrize("native_on", [True, False])
def test_whole_mesh_both_paths(native_on, monkeypatch):
    if not native_on:
        numpy_path(monkeypatch)
    c, r, s, w = scene(5, 150, 15.0)
    mesh = bb.blobby_surface(c, r, s, w, LEVEL, H, threads=2)
    assert len(mesh.vertices) > 10000
    watertight(mesh)
    assert level_distance(mesh.vertices, c, r, s, w, LEVEL).max() < 0.01 * s.min()


def chunks_equal(a, e):
    for f in dataclasses.fields(_blobby_base._Chunk):
        x, y = getattr(a, f.name), getattr(e, f.name)
        if isinstance(y, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f.name
        else:
            assert x == y, f.name


@pytest.mark.parametrize("box", [None, (15.0, 16.0, 14.0)])
@pytest.mark.parametrize("batched", [False, True])
def test_march_chunks_match_numpy(box, batched, monkeypatch):
    # Same node values in, the same chunks out, field by field: owned and duplicate vertices,
    # references across blocks and the periodic seam, triangles.
    b, grid, blocks = setup(*scene(6, 150, 15.0), box=box)
    et = bb._edge_tables()
    values, loc = bb._node_values(b, grid, blocks, 2), None
    if batched:  # values of a subset (one batch and its +1 neighbours), rows found through loc
        sel = np.arange(len(blocks.q) // 2)
        nb = blocks.nbr[sel, 1:]
        need = np.union1d(sel, nb[nb >= 0])
        loc = np.full(len(blocks.q), -1, np.int64)
        loc[need] = np.arange(len(need))
        values = values[need]
    # Some neighbours made inactive (below or above): their +1 layers are guesses and edges they would own
    # become duplicate vertices.
    rng = np.random.default_rng(1)
    cut_off = rng.random(blocks.nbr.shape) < 0.02
    cut_off[:, 0] = False
    blocks.nbr[cut_off] = rng.choice([-1, -2], cut_off.sum())
    values.reshape(-1)[rng.random(values.size) < 0.01] = LEVEL  # nodes at the level: edge parameters at the margins
    crossed = bb._crossed(values, blocks, LEVEL, None if loc is None else np.arange(len(blocks.q) // 2), loc)
    runs = [crossed[i : i + 97] for i in range(0, len(crossed), 97)] + [crossed[:0]]
    got = [bb._march(values, blocks, grid, LEVEL, r, et, loc=loc) for r in runs]
    numpy_path(monkeypatch)
    want = [bb._march(values, blocks, grid, LEVEL, r, et, loc=loc) for r in runs]
    assert sum(c.n_owned for c in want) > 50000 and sum(len(c.dup_key) for c in want) > 100
    for a, e in zip(got, want):
        chunks_equal(a, e)


@pytest.mark.parametrize("box,far", [(None, False), ((20.0, 21.0, 19.0), False), (None, True)])
def test_block_search_matches_numpy(box, far, monkeypatch):
    # The same (block, Gaussian) bounds, the same active blocks and lists (ties at the level aside,
    # which random scenes do not hit: the bounds differ at most by the exp's last bit).
    c, r, s, w = scene(7, 300, 20.0)
    if far:  # a blob 500 blocks away: the block index is sorted keys, not a dense table
        c[0] = 500.0
    got = setup(c, r, s, w, box=box)[2]
    numpy_path(monkeypatch)
    want = setup(c, r, s, w, box=box)[2]
    assert len(want.q) > 5000
    for f in dataclasses.fields(bb._Blocks):
        x, y = getattr(got, f.name), getattr(want, f.name)
        assert x.dtype == y.dtype and np.array_equal(x, y), f.name
