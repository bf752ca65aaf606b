"""The compiled vertex projection (native/src/blobby_project.c) against its NumPy twin, the exact
Gaussian sum and numpy.exp (its fastexp.h)."""

import ctypes

import numpy as np
import pytest
from blob_scenes import rotations

from nephele.core import native
from nephele.core.muscle import _blobby_c, blobby, blobby_field, blobby_surface

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


@pytest.fixture(autouse=True)
def compiled():
    if blobby._project_kernel() is None:
        pytest.skip("the compiled kernels are not installed")


def test_fastexp_against_numpy():
    fn = native.kernel("blobby_fastexp", None, [ctypes.c_int64] + [np.ctypeslib.ndpointer(np.float64, flags="C")] * 2)
    rng = np.random.default_rng(0)
    x = np.concatenate([np.linspace(-708, 709, 1_000_003), rng.uniform(-60, 5, 1_000_000)])  # (the mesher: -60 .. ln w)
    y = np.empty_like(x)
    fn(len(x), x, y)
    assert np.abs(y / np.exp(x) - 1).max() < 1e-15  # measured 4.4e-16
    edge = np.array([-np.inf, -1000.0, -708.5, np.nan, 0.0])
    out = np.empty_like(edge)
    fn(len(edge), edge, out)
    assert np.array_equal(out[:3], np.zeros(3)) and np.isnan(out[3]) and out[4] == 1.0


def random_blobs(seed, n, hi):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, hi, (n, 3)), rotations(rng, n), rng.uniform(0.5, 1.2, (n, 3)), rng.uniform(0.6, 1.4, n)


def scenes():
    """test_blobby's scenes and ~300 random ellipsoids, plain and periodic."""
    c, r, s, w = random_blobs(2, 20, 7)
    c[0] = [0.05, 7.9, 3.0]  # straddles two faces
    touch = np.sqrt(2 * np.log(2))  # its surface touches x = 0
    lone = (np.array([[touch, 3.0, 3.0]]), np.eye(3)[None], np.ones((1, 3)), np.ones(1))
    fade = list(random_blobs(3, 6, 6))
    fade[3][0] = 1e-300
    rot = rotations(np.random.default_rng(4), 1)
    many = random_blobs(7, 300, 20)
    return {
        "random": (random_blobs(1, 25, 8), 0.3, 0.125, None),
        "periodic": ((c, r, s, w), 0.3, 0.125, np.array([7.0, 8.0, 6.0])),
        "touching face": (lone, 0.5, 0.25, np.array([6.0, 6.0, 6.0])),
        "vanishing weight": (tuple(fade), 0.3, 0.15, None),
        "anisotropy 20:1": ((np.array([[1.0, 2.0, 3.0]]), rot, np.array([[4.0, 0.2, 0.2]]), np.ones(1)), 0.5, 0.05,
                            None),
        "300": (many, 0.3, 0.125, None),
        "300 periodic": (many, 0.3, 0.125, np.array([20.0, 20.0, 20.0])),
    }


SCENES = scenes()


# "300 periodic" (15 CPU s: both meshers on 300 blobs and their images) is the full tier's; its two
# halves, "300" and "periodic", stay in the quick one.
@pytest.mark.parametrize("name",
                         [pytest.param(n, marks=pytest.mark.slow) if n == "300 periodic" else n for n in SCENES])
def test_against_the_numpy_projection_and_the_exact_field(name, monkeypatch):
    (c, r, s, w), level, h, box = SCENES[name]
    ours = blobby_surface(c, r, s, w, level, h, box=box)
    monkeypatch.setattr(blobby, "_project_kernel", lambda: None)
    twin = blobby_surface(c, r, s, w, level, h, box=box)
    smin = s[w > 0].min()
    assert len(ours.vertices) > 300 and np.array_equal(ours.faces, twin.faces)
    for x in (ours.vertices, ours.normals):
        assert np.isfinite(x).all()
    # Both stop within NEWTON_TOL sigma_min of the (cut) level set: across it they differ by at most
    # twice that (measured: 1.01x).  Along an edge nearly tangent to the surface that is much more.
    diff = (ours.vertices - twin.vertices).astype(float)
    across = np.abs(np.einsum("ij,ij->i", diff, ours.normals))
    assert across.max() <= 2 * blobby.NEWTON_TOL * smin
    # Elsewhere they agree to float32 rounding (measured: 4.8e-6 sigma_min at the 99.9th percentile).
    assert np.quantile(np.abs(diff).max(axis=1), 0.999) < 2e-5 * smin
    # Normals: the gradients where the last steps started, points within a settle step (SETTLE_STEP
    # NEWTON_TOL sigma_min) of each other (measured: 0.19 deg apart at most).
    cos = np.einsum("ij,ij->i", ours.normals.astype(float), twin.normals)
    assert np.degrees(np.arccos(np.minimum(cos, 1))).max() < 0.5
    assert np.mean(ours.attributes["blob"] == twin.attributes["blob"]) >= 0.999  # (ties)
    # Independent truth: the exact field (measured: 6.2e-4 sigma_min at most), at up to some 20,000
    # vertices and every one on a box face.
    v = ours.vertices
    sel = np.arange(0, len(v), max(1, len(v) // 20_000))
    if box is not None:
        sel = np.union1d(sel, np.flatnonzero(np.any((v == 0) | (v == box.astype(np.float32)), axis=1)))
    # (level_distance's |f - level| / |grad f| from one evaluation of the exact field, shared with the normals.)
    f, g = blobby_field(v[sel], c, r, s, w, box=box, gradient=True)
    assert (np.abs(f - level) / np.linalg.norm(g, axis=1)).max() < 0.01 * smin
    # Normals: the gradient where the last (short) step started (measured: 0.47 deg at most, as NumPy's).
    cos = np.einsum("ij,ij->i", -g / np.linalg.norm(g, axis=1)[:, None], ours.normals[sel])
    assert np.degrees(np.arccos(np.minimum(cos, 1))).max() < 1.0


def test_any_chunks_give_the_same_bits(monkeypatch):
    # A chunk may end inside a block and a vector lane take any vertex: each vertex's sums run over its
    # block's list in order all the same.
    (c, r, s, w), level, h, box = SCENES["periodic"]
    whole = blobby_surface(c, r, s, w, level, h, box=box)
    monkeypatch.setattr(_blobby_c, "_PROJECT_CHUNK", 7)
    for threads in (1, 3):
        cut = blobby_surface(c, r, s, w, level, h, box=box, threads=threads)
        assert np.array_equal(cut.vertices, whole.vertices)
        assert np.array_equal(cut.normals, whole.normals)
        assert np.array_equal(cut.attributes["blob"], whole.attributes["blob"])
