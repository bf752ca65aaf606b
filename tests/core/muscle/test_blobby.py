"""Blobby surfaces against independent truth: an exact Gaussian sum written out here,
closed forms, trimesh's topology checks and skimage's marching cubes on a dense grid."""

import itertools

import numpy as np
import pytest
import trimesh
from blob_scenes import edges, rotations
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from nephele.core.errors import DataError
from nephele.core.muscle import blobby_field, blobby_surface
from nephele.core.surface.mesh import Mesh, triangle_areas

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # no overflow in exp, no NaN


def exact(points, c, r, s, w, box=None, images=2, gradient=True):
    """f and grad f (None unless ``gradient``) by a plain loop over Gaussians (and periodic shifts
    -images..images)."""
    p = np.asarray(points, float)
    f = np.zeros(len(p))
    g = np.zeros((len(p), 3))
    shifts = (
        [np.zeros(3)]
        if box is None
        else [np.array(k) * box for k in itertools.product(range(-images, images + 1), repeat=3)]
    )
    for ci, ri, si, wi in zip(c, r, s, w):
        for sh in shifts:
            d = p - (ci + sh)
            y = d @ ri / si  # coordinates in the principal frame, in sigmas
            e = wi * np.exp(-0.5 * (y * y).sum(axis=1))
            f += e
            if gradient:
                g -= e[:, None] * ((y / si) @ ri.T)
    return f, (g if gradient else None)


def distance(mesh, c, r, s, w, level, box=None):
    f, g = exact(mesh.vertices.astype(float), c, r, s, w, box)
    return np.abs(f - level) / np.linalg.norm(g, axis=1)


def random_blobs(seed, n, lo, hi, smin=0.5, smax=1.2):
    rng = np.random.default_rng(seed)
    c = rng.uniform(lo, hi, (n, 3))
    return c, rotations(rng, n), rng.uniform(smin, smax, (n, 3)), rng.uniform(0.6, 1.4, n)


def closed_checks(mesh, components=None, spheres=True, outward=True):
    """Closed, consistently wound, Euler number 2 - 2 genus per component (trimesh agrees)."""
    f = mesh.faces.astype(np.int64)
    once, und, cnt = edges(f)
    assert once  # each directed edge once: consistent winding
    assert np.all(cnt == 2)  # watertight and manifold along edges
    used = np.unique(f)
    graph = coo_matrix((np.ones(len(und)), (und[:, 0], und[:, 1])), shape=(len(mesh.vertices),) * 2)
    ncomp, label = connected_components(graph, directed=False)
    parts = len(np.unique(label[used]))
    euler = len(used) - len(und) + len(f)
    if components is not None:
        assert parts == components
    assert euler % 2 == 0 and euler <= 2 * parts
    if spheres:  # lone blobs
        assert euler == 2 * parts
    t = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert t.is_watertight and t.is_winding_consistent
    assert t.euler_number == euler
    if outward:  # (a welded periodic mesh has no meaningful volume)
        assert t.volume > 0


def no_degenerate(mesh, h):
    a = triangle_areas(mesh.vertices, mesh.faces)
    assert a.min() > 1e-10 * h * h


def one(c, sig, w=1.0):
    return np.array([c], float), np.eye(3)[None], np.array([sig], float), np.array([w], float)


def test_single_sphere_radius_closed_form():
    c, r, s, w = one([0.3, -0.2, 0.1], [1.0, 1.0, 1.0], 2.0)
    level = 0.5
    mesh = blobby_surface(c, r, s, w, level, 0.25)
    radius = np.sqrt(2 * np.log(2.0 / level))
    rad = np.linalg.norm(mesh.vertices - c[0], axis=1)
    assert np.abs(rad - radius).max() < 0.01
    assert np.abs(rad - radius).max() < 5e-4  # the projection step, well below the 0.01 goal
    closed_checks(mesh, components=1)
    no_degenerate(mesh, 0.25)
    # Normals: radial, outward, unit.
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1, atol=1e-5)
    radial = (mesh.vertices - c[0]) / rad[:, None]
    assert np.einsum("ij,ij->i", radial, mesh.normals).min() > 1 - 1e-5


def test_random_ellipsoids_accuracy_watertight_normals():
    c, r, s, w = random_blobs(1, 25, 0, 8)
    level, h = 0.3, 0.5 / 4
    mesh = blobby_surface(c, r, s, w, level, h)
    assert len(mesh.vertices) > 1000
    d = distance(mesh, c, r, s, w, level)
    assert d.max() < 0.01 * s.min()
    closed_checks(mesh, spheres=False)  # random clusters may form handles
    no_degenerate(mesh, h)
    f, g = exact(mesh.vertices.astype(float), c, r, s, w)
    n = -g / np.linalg.norm(g, axis=1)[:, None]
    assert np.einsum("ij,ij->i", n, mesh.normals).min() > 1 - 1e-4
    # The module's own exact field agrees with the one written here.
    assert np.allclose(blobby_field(mesh.vertices[:500], c, r, s, w), f[:500], rtol=1e-9, atol=1e-12)


def seam_checks(mesh, box):
    """Vertices on opposite faces are the same set shifted by L; 2x2x2 copies join without cracks."""
    v = mesh.vertices
    L = box.astype(np.float32)
    for a in range(3):
        lo = v[v[:, a] == 0]
        hi = v[v[:, a] == L[a]]
        assert len(lo) == len(hi)
        hi = hi.copy()
        hi[:, a] = 0
        assert np.array_equal(np.unique(lo, axis=0), np.unique(hi, axis=0))
    assert v.min() >= 0 and np.all(v.max(axis=0) <= L)
    vv, ff, off = [], [], 0
    for k in itertools.product(range(2), repeat=3):
        vv.append(v + (np.array(k) * box).astype(np.float32))
        ff.append(mesh.faces + off)
        off += len(v)
    u, inv = np.unique(np.concatenate(vv), axis=0, return_inverse=True)
    faces = inv.reshape(-1)[np.concatenate(ff)]
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    ue, cnt = np.unique(e, axis=0, return_counts=True)
    assert cnt.max() == 2  # manifold
    open_pts = u[ue[cnt == 1].reshape(-1)]
    outer = np.any((open_pts == 0) | (open_pts == (2 * box).astype(np.float32)), axis=1)
    assert outer.all()  # only the big cube's outer faces are open


def periodic_weld(mesh, box):
    """The mesh on the 3-torus: vertices on x = L identified with those on x = 0 (per axis)."""
    v = mesh.vertices.copy()
    v[v == box.astype(np.float32)[None].repeat(len(v), 0)] = 0
    u, inv = np.unique(v, axis=0, return_inverse=True)
    return Mesh(u, inv.reshape(-1)[mesh.faces], np.zeros_like(u))


def test_periodic_box_exact_images_and_seamless_copies():
    box = np.array([7.0, 8.0, 6.0])
    c, r, s, w = random_blobs(2, 20, 0, 7)
    c[0] = [0.05, 7.9, 3.0]  # straddles two faces
    level, h = 0.3, 0.5 / 4
    mesh = blobby_surface(c, r, s, w, level, h, box=box)
    d = distance(mesh, c, r, s, w, level, box)
    assert d.max() < 0.01 * s.min()
    no_degenerate(mesh, h)
    seam_checks(mesh, box)
    closed_checks(periodic_weld(mesh, box), spheres=False, outward=False)
    # Centres given outside the box (shifted by whole periods) give the same mesh.
    moved = blobby_surface(c + np.array([1, -2, 3]) * box, r, s, w, level, h, box=box)
    assert len(moved.vertices) == len(mesh.vertices)
    assert np.abs(np.sort(moved.vertices, axis=0) - np.sort(mesh.vertices, axis=0)).max() < 1e-4


def test_blob_exactly_touching_the_box_face():
    level, h = 0.5, 0.25
    radius = np.sqrt(2 * np.log(1 / level))
    box = np.array([6.0, 6.0, 6.0])
    c, r, s, w = one([radius, 3.0, 3.0], [1, 1, 1])  # its surface touches x = 0 at one point
    mesh = blobby_surface(c, r, s, w, level, h, box=box)
    assert distance(mesh, c, r, s, w, level, box).max() < 0.01
    seam_checks(mesh, box)
    # The node at the touching point is exactly at the level, inside by the ">= level" rule
    # (as in the contours): a speck of the blob shows on the far face.  Glued across the
    # faces, the surface is one closed sphere.
    closed_checks(periodic_weld(mesh, box), components=1, outward=False)
    c2 = c.copy()
    c2[0, 0] = radius - 0.2  # crosses: open on x = 0 and closed through the seam
    mesh = blobby_surface(c2, r, s, w, level, h, box=box)
    seam_checks(mesh, box)
    closed_checks(periodic_weld(mesh, box), components=1, outward=False)
    assert np.any(mesh.vertices[:, 0] == 0) and np.any(mesh.vertices[:, 0] == np.float32(6))


@pytest.mark.parametrize("factor,parts", [(0.95, 1), (1.0, None), (1.05, 2)])
def test_two_blobs_just_fusing(factor, parts):
    level, h = 0.5, 0.25
    # Two unit Gaussians meet at the midpoint when 2 exp(-d^2 / 8) = level.
    d = factor * np.sqrt(8 * np.log(2 / level))
    c = np.array([[-d / 2, 0.1, 0.0], [d / 2, 0.1, 0.0]])
    r = np.repeat(np.eye(3)[None], 2, axis=0)
    s = np.ones((2, 3))
    w = np.ones(2)
    mesh = blobby_surface(c, r, s, w, level, h)
    dist = distance(mesh, c, r, s, w, level)
    assert dist.max() < 0.01
    no_degenerate(mesh, h)
    closed_checks(mesh, components=parts)


def test_vanishing_weight():
    c, r, s, w = random_blobs(3, 6, 0, 6)
    level = 0.3
    base = blobby_surface(c[1:], r[1:], s[1:], w[1:], level, 0.15)
    w2 = w.copy()
    w2[0] = 1e-300
    mesh = blobby_surface(c, r, s, w2, level, 0.15)
    assert np.array_equal(mesh.vertices, base.vertices)
    assert np.array_equal(mesh.attributes["blob"], base.attributes["blob"] + 1)
    # A lone Gaussian below the level, or of weight zero: nothing.
    assert blobby_surface(*one([0, 0, 0], [1, 1, 1], 0.29), level, 0.15).is_empty
    assert blobby_surface(*one([0, 0, 0], [1, 1, 1], 0.0), level, 0.15).is_empty


def test_anisotropy_20_to_1():
    rng = np.random.default_rng(4)
    rot = rotations(rng, 1)
    c = np.array([[1.0, 2.0, 3.0]])
    s = np.array([[4.0, 0.2, 0.2]])
    w = np.array([1.0])
    level, h = 0.5, 0.2 / 4
    mesh = blobby_surface(c, rot, s, w, level, h)
    assert distance(mesh, c, rot, s, w, level).max() < 0.01 * 0.2
    closed_checks(mesh, components=1)
    no_degenerate(mesh, h)
    # Semi-axes: sqrt(2 ln(w / level)) sigma along each principal axis.
    y = (mesh.vertices - c[0]) @ rot[0]
    semi = np.sqrt(2 * np.log(1 / level)) * s[0]
    assert np.abs(y).max(axis=0) == pytest.approx(semi, rel=0.01, abs=0.01 * 0.2)


def test_empty_inputs_and_bad_input():
    z = np.zeros((0, 3))
    mesh = blobby_surface(z, np.zeros((0, 3, 3)), z, np.zeros(0), 0.5, 0.1, attributes={"mol": np.zeros(0)})
    assert mesh.is_empty and set(mesh.attributes) == {"blob", "mol"}
    c, r, s, w = one([0, 0, 0], [1, 1, 1])
    with pytest.raises(DataError) as err:
        blobby_surface(np.full((1, 3), np.nan), r, s, w, 0.5, 0.1)
    assert err.value.field == "centers"
    with pytest.raises(DataError) as err:
        blobby_surface(c, 2 * r, s, w, 0.5, 0.1)
    assert err.value.field == "rotations"
    with pytest.raises(DataError) as err:
        blobby_surface(c, r, -s, w, 0.5, 0.1)
    assert err.value.field == "sigmas"
    with pytest.raises(DataError) as err:
        blobby_surface(c, r, s, w, 0.0, 0.1)
    assert err.value.field == "level"
    with pytest.raises(DataError) as err:
        blobby_surface(c, r, s, w, 0.5, 0.1, box=(1, 0, 1))
    assert err.value.field == "box"


def test_attributes_follow_the_nearest_gaussian():
    c = np.array([[0.0, 0, 0], [6.0, 0, 0], [3.0, 4.0, 0]])
    r = np.repeat(np.eye(3)[None], 3, axis=0)
    s = np.ones((3, 3))
    w = np.ones(3)
    mol = np.array([10, 20, 30])
    mesh = blobby_surface(c, r, s, w, 0.5, 0.2, attributes={"mol": mol})
    near = np.argmin(np.linalg.norm(mesh.vertices[:, None, :] - c[None], axis=2), axis=1)
    assert np.array_equal(mesh.attributes["blob"], near)
    assert np.array_equal(mesh.attributes["mol"], mol[near])


def test_against_skimage_marching_cubes_on_a_dense_grid():
    measure = pytest.importorskip("skimage.measure")
    c, r, s, w = random_blobs(5, 12, 0, 5)
    level, h = 0.3, 0.5 / 4
    mesh = blobby_surface(c, r, s, w, level, h)
    # The grid reaches 4 (sigma <= 1.2) past every centre: there the sum is at most
    # sum(w) exp(-4^2 / (2 1.2^2)) = 0.065 < level, so the grid holds the whole surface and skimage's mesh
    # is the one of any larger grid (checked below: every boundary node is below the level).
    lo = c.min(axis=0) - 4
    n = np.ceil((c.max(axis=0) + 4 - lo) / h).astype(int) + 1
    axes = [lo[a] + h * np.arange(n[a]) for a in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    vol = exact(pts, c, r, s, w, gradient=False)[0].reshape(n)
    assert max(np.moveaxis(vol, a, 0)[[0, -1]].max() for a in range(3)) < level
    v, f, _, _ = measure.marching_cubes(vol, level, spacing=(h, h, h))
    ref = trimesh.Trimesh(v + lo, f, process=False)
    ours = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert abs(ours.area / ref.area - 1) < 0.01
    assert abs(abs(ours.volume) / abs(ref.volume) - 1) < 0.01
    # Ours lies on the exact surface; skimage's linear interpolation is off by a few hundredths of sigma.
    ref_err = np.abs(exact(ref.vertices, c, r, s, w, gradient=False)[0] - level)
    ours_err = np.abs(exact(mesh.vertices.astype(float), c, r, s, w, gradient=False)[0] - level)
    assert ours_err.max() < ref_err.max()
    from scipy.spatial import cKDTree

    gap = cKDTree(ref.vertices).query(mesh.vertices)[0]
    assert gap.max() < h


def test_same_mesh_with_any_number_of_threads():
    # Blocks are meshed and projected in batches spread over threads: the result must not depend on them.
    c, r, s, w = random_blobs(6, 40, 0, 9)
    level, h = 0.3, 0.5 / 4
    one_thread = blobby_surface(c, r, s, w, level, h, threads=1)
    three = blobby_surface(c, r, s, w, level, h, threads=3)
    assert len(one_thread.vertices) > 1000
    assert np.array_equal(one_thread.vertices, three.vertices)
    assert np.array_equal(one_thread.faces, three.faces)
    assert np.array_equal(one_thread.normals, three.normals)
    assert np.array_equal(one_thread.attributes["blob"], three.attributes["blob"])
    assert distance(one_thread, c, r, s, w, level).max() < 0.01 * s.min()


def test_edge_guess_against_a_lone_gaussian():
    # The vertex's start on its edge: the cubic through the node values along the edge (quadratic at a
    # block's edge), against the closed-form root of w exp(-x^2/2) = level and its second derivative.
    from nephele.core.muscle._blobby_numpy import EDGE_MARGIN, _edge_guess

    w, level, h = 2.0, 0.5, 0.25
    root = np.sqrt(2 * np.log(w / level))
    off = np.linspace(0.01, 0.99, 50)  # the root's place along each edge
    x0 = root - off * h
    vals = (w * np.exp(-0.5 * (x0[:, None] + np.arange(-1, 3) * h) ** 2)).astype(np.float32)  # nodes -1 .. 2
    flat = np.concatenate([vals, np.zeros_like(vals)], axis=1).reshape(-1)  # 8 values per edge, stride 1
    at = np.arange(len(off)) * 8 + 1
    t_lin = np.clip((level - vals[:, 1]) / (vals[:, 2] - vals[:, 1]), EDGE_MARGIN, 1 - EDGE_MARGIN).astype(float)
    axis, beyond = np.zeros(len(off), int), np.zeros(len(off), bool)
    lin_err = np.abs(x0 + t_lin * h - root).max()
    for coord, err_max, curv_tol in [(3, 5e-4, 0.1), (0, 1e-3, 0.25), (6, 1e-3, 0.25)]:  # cubic, quadratics
        t, curv = _edge_guess(flat, at, axis, np.full(len(off), coord), beyond, level, t_lin)
        x = x0 + t * h
        assert np.abs(x - root).max() < min(err_max, 0.1 * lin_err)
        d2 = w * (x**2 - 1) * np.exp(-0.5 * x**2) * h * h  # d^2 f / dt^2
        assert np.abs(curv / d2 - 1).max() < curv_tol
    # The last node of a block with no active block beyond: the linear guess, no curvature.
    t, curv = _edge_guess(flat, at, axis, np.full(len(off), 7), beyond, level, t_lin)
    assert np.array_equal(t, t_lin) and np.isnan(curv).all()


def test_refiner_batches_cover_every_vertex_once():
    # Vertices go to the projection in padded batches of blocks with one number of Gaussians; small
    # bands merge (few batches) but a batch stays within the budget unless it is a single block.
    from nephele.core.muscle import blobby as bb

    c, r, s, w = random_blobs(7, 30, 0, 8)
    grid = bb._grid(0.5 / 4, None)
    b = bb._blobs(c, r, s, w)
    blocks = bb._find_blocks(b, grid, 0.3, 4.0, 5.0, 1)
    refiner = bb._Refiner(b, grid, blocks)
    rng = np.random.default_rng(0)
    blk = np.sort(rng.integers(0, len(blocks.q), 20000))
    for order in (np.arange(len(blk)), np.sort(rng.choice(len(blk), 300, replace=False))):
        seen = []
        for vid, nv, ub in refiner.batches(blk, order):
            assert len(np.unique(refiner.count[ub])) == 1
            assert vid.size * refiner.count[ub[0]] <= refiner.BUDGET or len(ub) == 1
            valid = np.arange(vid.shape[1]) < nv[:, None]
            assert np.all(blk[vid] == ub[:, None])  # padding repeats a vertex of the same block
            seen.append(vid[valid])
        assert np.array_equal(np.sort(np.concatenate(seen)), order)


@pytest.mark.parametrize("box", [None, (7.0, 8.0, 6.0)])
def test_blocks_left_out_of_the_march_cut_no_edge(box):
    # The march skips active blocks whose nodes and +1 neighbours' lie on one side of the level
    # (from block extremes); marched anyway, every one of them must give no vertex and no face.
    from nephele.core.muscle import blobby as bb

    c, r, s, w = random_blobs(3, 40, 0, 7)
    level, h = 0.3, 0.5 / 4
    grid = bb._grid(h, None if box is None else np.array(box))
    b = bb._blobs(c, r, s, w)
    if box is not None:
        b = bb._images(b, np.array(box), 5.0)
    blocks = bb._find_blocks(b, grid, level, 4.0, 5.0, 1)
    values = bb._node_values(b, grid, blocks, 1)
    kept = bb._crossed(values, blocks, level)
    left = np.setdiff1d(np.arange(len(blocks.q)), kept)
    assert 0 < len(left) < len(blocks.q)  # the case is exercised
    part = bb._march(values, blocks, grid, level, left, bb._edge_tables())
    assert len(part.t) == 0 and len(part.faces) == 0 and len(part.ref_owner) == 0
    # An inactive neighbour counts by its class: below (-1) next to a block all above is a crossing.
    values[0] = 2 * level
    for cls, kept0 in ((-1, True), (-2, False)):
        blocks.nbr[0, 1:] = cls
        assert (0 in bb._crossed(values, blocks, level)) == kept0


@pytest.mark.parametrize("box", [None, (9.0, 8.0, 7.0)])
def test_march_batches_give_the_unbatched_mesh(box, monkeypatch):
    # Node values and the march run MARCH_BATCH active blocks at a time (memory), each batch with its
    # +1 neighbours' values made again: the mesh must be the one-batch mesh, bit for bit. A seam vertex
    # between batches lost or made twice would change the vertex count and break the closed checks.
    from nephele.core.muscle import blobby as bb

    c, r, s, w = random_blobs(6, 40, 0, 9)
    level, h = 0.3, 0.5 / 4
    box = None if box is None else np.array(box)
    attrs = {"id": np.arange(len(c)) * 10 + 1}
    whole = blobby_surface(c, r, s, w, level, h, box=box, attributes=attrs, threads=2)
    grid = bb._grid(h, box)
    b = bb._blobs(c, r, s, w)
    if box is not None:
        b = bb._images(b, box, 5.0)
    blocks = bb._find_blocks(b, grid, level, 4.0, 5.0, 1)
    assert len(blocks.q) < bb.MARCH_BATCH  # (one batch above)
    # A block's values are the same bits made in any subset of blocks.
    full = bb._node_values(b, grid, blocks, 2)
    some = np.sort(np.random.default_rng(0).choice(len(blocks.q), len(blocks.q) // 3, replace=False))
    assert np.array_equal(bb._node_values(b, grid, blocks, 2, some), full[some])
    for batch in (len(blocks.q) // 3 + 1, 97):
        monkeypatch.setattr(bb, "MARCH_BATCH", batch)
        split = blobby_surface(c, r, s, w, level, h, box=box, attributes=attrs, threads=2)
        assert len(split.vertices) == len(whole.vertices) > 1000
        for name in ("vertices", "faces", "normals"):
            a, e = getattr(split, name), getattr(whole, name)
            assert a.dtype == e.dtype and np.array_equal(a, e), name
        for name in ("blob", "id"):
            assert np.array_equal(split.attributes[name], whole.attributes[name]), name
    if box is None:
        closed_checks(split, spheres=False, outward=False)
    else:
        seam_checks(split, box)
        closed_checks(periodic_weld(split, box), spheres=False, outward=False)


@pytest.mark.parametrize("top", [1, 300, 1 << 16, (1 << 16) + 1, 5_000_000, 1 << 32, (1 << 32) + 5])
def test_argsort_small_is_numpys_stable_argsort(top):
    # Block indices are sorted by 16-bit radix passes: the same permutation as NumPy's stable sort,
    # ties (one block's Gaussians) kept in their order, for every range (one pass, two, or fallback).
    from nephele.core.muscle import _blobby_numpy

    rng = np.random.default_rng(top % 1000)
    x = rng.integers(0, top, 20000)
    x[:50] = top - 1  # the largest value, tied
    x[50:100] = 0
    assert np.array_equal(_blobby_numpy._argsort_small(x, top), np.argsort(x, kind="stable"))
