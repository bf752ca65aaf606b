"""The scattering solve's compiled kernels (native/src/scatter_sweep.c, scatter_shoot.c) against their
NumPy twins: one sweep at a time on every kind of beam (sun, sky, emission with and without
profiles, P2 terms, moments, cached escapes, periodic sides, shifts over a cell per layer), the
shooting step, and whole solves; the float32 exponentials of native/src/scatter_math.h."""

import numpy as np
import pytest

from nephele.core import native
from nephele.core.light import _native, phase, scatter
from nephele.core.light import _passes as passes
from nephele.core.light import _sweep as sweeps

pytestmark = pytest.mark.skipif(native.identity() == "numpy", reason="no compiled kernels")


def numpy_twin(monkeypatch):
    monkeypatch.setattr(native, "_module", lambda: None)


def both(monkeypatch, fn):
    """``fn()`` by the compiled kernels, then by the NumPy twins."""
    c = fn()
    with monkeypatch.context() as m:
        numpy_twin(m)
        n = fn()
    return c, n


def close(a, b, rel, what=""):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(np.abs(b).max(), 1e-30)
    assert np.abs(a - b).max() <= rel * scale, (what, np.abs(a - b).max() / scale)


def random_profile(rng, shape, second):
    kap = rng.uniform(-6, 6, (3,) + shape).astype(np.float32)
    kap[:, 0, 0, 0] = (300.0, -250.0, 0.0)  # steep: the overflow-safe forms
    dlt = np.clip(rng.uniform(-0.3, 0.3, (3,) + shape), -0.49, 0.49).astype(np.float32)
    m2 = (1 / 12 + dlt * dlt).astype(np.float32)
    q = rng.uniform(-0.5, 0.5, (3,) + shape).astype(np.float32) if second else None
    return kap, dlt, m2, q


def sweep_case(axis, kind, shape=(7, 9, 8)):
    """A sweep of one group of bins along ``axis`` with beams of ``kind``: the call, returning its outputs."""
    rng = np.random.default_rng(axis * 10 + len(kind))
    sigma = rng.uniform(0.0, 3.0, shape) * (rng.random(shape) > 0.2)
    sigma[:, 0, :] = 0.0  # rectangles smaller than the planes
    sigma[3] = 0.0  # an empty layer along z
    h = np.array([0.11, 0.09, 0.13])
    _, _, dirs, w = phase.bins(2)
    comp = 2 - axis
    bs = np.flatnonzero((np.abs(phase.bins(1)[2][:, 0, comp]) >= np.abs(phase.bins(1)[2][:, 0]).max(1))
                        & (phase.bins(1)[2][:, 0, comp] < 0))[:5]
    d, ws = dirs[bs], (w[bs] / w[bs].sum(1, keepdims=True)).astype(np.float32)
    g, ns = ws.shape
    periodic = (axis != 2, False, False)
    emis = profile = moments = None
    inflow = np.zeros((g, ns))
    second = kind == "p2"
    if kind in ("sun", "sky"):
        inflow = rng.uniform(0.5, 1.0, (g, ns))
    else:
        emis = rng.uniform(0.0, 1.0, (g,) + shape).astype(np.float32) * (sigma > 0)
    if kind in ("profile", "p2", "per_sub"):
        profile = random_profile(rng, shape, second)
    if kind != "sun":
        mw = rng.uniform(0, 1, (3, g)).astype(np.float32)
        moments = (mw, np.zeros((3, 1 + (second or kind == "sky"), 3) + shape), 0.9)

    def run():
        mom = None if moments is None else (moments[0], moments[1].copy(), moments[2])
        r, tot, ex = sweeps._sweep(sigma, h, d, ws, emis, inflow, periodic, axis, per_sub=kind == "per_sub",
                                   profile=profile, moments=mom)
        return r.copy(), tot.copy(), ex.copy(), None if mom is None else mom[1]

    return run


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("kind", ["sun", "sky", "plain", "profile", "p2", "per_sub"])
def test_sweep_matches_numpy(monkeypatch, axis, kind):
    c, n = both(monkeypatch, sweep_case(axis, kind))
    # the moments within 1e-4 of the largest: in a thin voxel (tau ~ 0.01) what a source keeps,
    # 1 - esc, loses most of its digits, and its centroid (vs - esc) / (1 - esc) moves by a few
    # 1e-4 between two float32 exponentials an ulp apart (measured: 3.0e-5)
    for name, a, b in zip(("received", "total", "exit", "moments"), c, n):
        if b is not None:
            close(a, b, 1e-4 if name == "moments" else 2e-5, name)


def test_sweep_shifts_over_a_cell_and_periodic_sides(monkeypatch):
    # flat voxels: beams move several cells sideways per layer, wrapping on periodic sides
    rng = np.random.default_rng(4)
    shape = (6, 5, 7)
    sigma = rng.uniform(0.1, 2.0, shape)
    h = np.array([0.1, 0.1, 0.5])
    _, _, dirs, w = phase.bins(2)
    cen = phase.bins(1)[2][:, 0]
    bs = np.flatnonzero(cen[:, 2] < -0.3)
    emis = rng.uniform(0, 1, (len(bs),) + shape).astype(np.float32)
    for periodic in ((True, True, False), (False, False, False), (True, False, False)):
        def run(periodic=periodic):
            r, tot, ex = sweeps._sweep(sigma, h, dirs[bs], w[bs] / w[bs].sum(1, keepdims=True), emis,
                                       rng.uniform(0, 1, (len(bs), 4)) * 0 + 0.3, periodic, 0)
            return r.copy(), tot.copy(), ex.copy()

        c, n = both(monkeypatch, run)
        for a, b in zip(c, n):
            close(a, b, 2e-5, periodic)


def test_cached_escapes_are_reused_as_numpy_reuses_them(monkeypatch):
    # profile_every > 1 keeps the profiles' escapes between passes: the solve by either path
    sig = np.full((8, 1, 1), 1.0)
    kw = dict(albedo=0.99, g=0.8, sun_dir=(0.5, 0, 0.8), tol=1e-5, periodic=(True, True, False), profile_every=3,
              max_passes=300)
    c, n = both(monkeypatch, lambda: scatter.solve(sig, (1, 1, 1), **kw))
    assert c.passes == n.passes
    close(scatter.slab_reflectance(c), scatter.slab_reflectance(n), 1e-5)
    close(c.received, n.received, 1e-5)  # measured 6.0e-7


@pytest.mark.parametrize("g,shape,nb", [(16, (40, 50, 61), 96), (100, (9, 10, 11), 96), (256, (5, 7, 9), 96),
                                        (7, (3, 1, 1), 96), (600, (4, 5, 7), 50)])
def test_scatter_into_matches_the_direct_product(g, shape, nb):
    # (600 columns: three chunks of rows of recv, the last short; 50 bins: rows left after blocks of 3)
    rng = np.random.default_rng(3)
    r = rng.random((g,) + shape).astype(np.float32)
    m = rng.random((nb, g))
    u = rng.random((nb,) + shape).astype(np.float32)
    want = u + 0.9 * np.einsum("ij,j...->i...", m, r.astype(np.float64))
    passes._scatter_into(u, m, r, 0.9)
    np.testing.assert_allclose(u, want, rtol=2e-6)


def test_scatter_into_where_little_is_caught():
    """Empty voxels catch nothing: the kernel skips groups of 8 voxels whose every row is zero.
    Lone lit voxels at group edges, one lit row of k, lit groups far apart (one block of four lit
    groups), a number of lit groups no multiple of four, and the last voxels (fewer than a group)
    still count, and the unshot light of voxels that caught nothing is left exactly as it was."""
    rng = np.random.default_rng(5)
    k, n = 16, 16 * 70 + 9
    r = np.zeros((k, n), np.float32)
    r[:, 32:48] = rng.random((k, 16))  # 16 voxels in a row: two groups
    r[3, 80] = r[0, 111] = r[7, 8] = 1.5  # one row, a group's first and last voxels
    r[2, 304] = r[9, 1001] = 0.5  # lone groups far apart (with those above: 6 lit groups before 500)
    r[k - 1, n - 1] = 2.0  # the tail after the last whole group
    r[:, 500:700] = rng.random((k, 200)) * (rng.random(200) < 0.3)
    m = rng.random((96, k))
    u = rng.random((96, n)).astype(np.float32)
    want = u + 0.9 * (m @ r.astype(np.float64))
    dark = ~r.any(0)
    before = u[:, dark].copy()
    passes._scatter_into(u, m, r, 0.9)
    np.testing.assert_allclose(u, want, rtol=2e-6)
    np.testing.assert_array_equal(u[:, dark], before)


def test_scatter_into_skips_groups_that_hold_no_medium():
    """Groups of 8 voxels that ``held`` marks empty are neither read nor written: NaN there (which no
    empty voxel ever catches) stays out of the sums, and the other voxels get the direct product.  A
    group holding medium in one voxel, and the last voxels (fewer than a group), still count."""
    rng = np.random.default_rng(6)
    k, n = 40, 8 * 300 + 5
    sigma = np.where(rng.random(n) < 0.2, rng.random(n), 0.0)
    sigma[8 * 17 + 7] = 0.3  # one voxel of its group
    sigma[-1] = 1.0  # the tail
    held = _native.held_groups(sigma)
    r = (rng.random((k, n)) * (sigma > 0)).astype(np.float32)
    empty = np.repeat(held == 0, 8)[:n]
    r[:, empty] = np.nan
    m = rng.random((96, k))
    u = rng.random((96, n)).astype(np.float32)
    want = u.astype(np.float64) + 0.9 * (m @ np.where(np.isnan(r), 0.0, r).astype(np.float64))
    passes._scatter_into(u, m, r, 0.9, held)
    assert empty.sum() > 8 * 50 and not np.isnan(u).any()
    np.testing.assert_allclose(u, want, rtol=2e-6)


@pytest.mark.parametrize("second", [False, True])
def test_moments_where_little_is_caught(second):
    """The moments' sums skip blocks of voxels that hold no medium: lone lit voxels at block edges,
    one lit slot of one bin, and the last voxels still count (against float64 sums), and the sums of
    voxels that caught nothing are left exactly as they were, in ``also`` too, whether they hold
    medium (some do here) or not."""
    rng = np.random.default_rng(8)
    sets, g, n, comp = 3, 5, 1024 * 2 + 32 * 5 + 7, 1
    slot = {"m1": 0, "kept": 1} | ({"m2": 2, "dep": 3} if second else {})
    bm = np.zeros((g, len(slot), n), np.float32)
    bm[:, :, 40:56] = rng.random((g, len(slot), 16))  # half a block
    bm[2, 1, 64] = bm[0, 0, 127] = 1.5  # one slot of one bin, alone in its block (first, last voxel)
    bm[g - 1, 0, n - 1] = 2.0  # the last voxels, after the last whole block
    bm[:, :, 1000:1100] = rng.random((g, len(slot), 100)) * (rng.random(100) < 0.3)  # across a run's end
    mw = rng.random((sets, g)).astype(np.float32)
    d = rng.uniform(-0.4, 0.4, (3, n)).astype(np.float32)
    m2 = rng.uniform(0.0, 0.25, (3, n)).astype(np.float32)
    order = 2 if second else 1
    out, also = (rng.random((sets, order, 3, n)) for _ in range(2))
    acc = np.einsum("sb,bkn->skn", mw.astype(np.float64), bm.astype(np.float64)) * 0.7
    add = np.zeros_like(out)
    add[:, 0, comp] += acc[:, 0]
    add[:, 0] += d * acc[:, None, 1]
    if second:
        side = [x for x in range(3) if x != comp]
        add[:, 1, comp] += acc[:, 2]
        add[:, 1, side] += acc[:, None, 3] / 12 + m2[side] * acc[:, None, 1]
    want = out + add, also + add
    dark = ~bm.any((0, 1))
    before = out[..., dark].copy(), also[..., dark].copy()
    held = _native.held_groups(bm.any((0, 1)) | (rng.random(n) < 0.05))  # (medium where something was caught)
    assert _native.moments(mw, bm, 2 - comp, slot, d, m2 if second else None, 0.7, out, held, also=also)
    for o, w, b in zip((out, also), want, before):  # (float32 sums: measured within 2e-7)
        np.testing.assert_allclose(o, w, rtol=0, atol=1e-6 * np.abs(acc).max())
        np.testing.assert_array_equal(o[..., dark], b)


def test_float32_exponentials_of_the_kernels(monkeypatch):
    # the sweep of one beam through one voxel returns exp(-tau) (no emission) and, with an even
    # source, (1 - exp(-tau)) / tau: scatter_math.h's expf and expm1 against float64 (measured:
    # within 7.0e-8 and 1.0e-7 relative; NumPy's float32 exp and expm1 1.4e-7 and 1.6e-7)
    tau = np.geomspace(1e-6, 80.0, 400).astype(np.float32)
    d = np.array([[[0.0, 0.0, -1.0]]])
    out = []
    for t in tau:
        sig = np.full((1, 1, 1), t, np.float32)
        _, _, ex = sweeps._sweep(sig, np.ones(3), d, np.ones((1, 1)), None, np.ones((1, 1)), (True, True, False), 0)
        _, _, ee = sweeps._sweep(sig, np.ones(3), d, np.ones((1, 1)), np.ones((1, 1, 1, 1)), np.zeros((1, 1)),
                                 (True, True, False), 0)
        out.append((ex[0], ee[0]))
    ex, ee = np.array(out).T
    np.testing.assert_allclose(ex, np.exp(-tau.astype(np.float64)), rtol=3e-7, atol=1e-37)
    np.testing.assert_allclose(ee, -np.expm1(-tau.astype(np.float64)) / tau, rtol=5e-7)


def test_escape_of_a_profiled_source_against_float64(monkeypatch):
    # a beam straight along the columns of one layer, each voxel its own depth and rate: what the
    # voxel keeps of its source exp(-beta v) is 1 - escape; both paths against the float64 closed
    # form, over the depths, rates and signs a solve meets (the compiled one through scatter_math.h's
    # nph_exp_expm1f: measured 1.8e-7 of the source, as before it, its NumPy twin 1.9e-7)
    from nephele.core.light import _escape as escape

    tau = np.concatenate([[1e-4], np.geomspace(1e-3, 60.0, 29)])
    k = np.concatenate([-np.geomspace(400.0, 1e-4, 20), [0.0], np.geomspace(1e-4, 400.0, 20)])
    T, K = np.meshgrid(tau, k, indexing="ij")
    kap = np.zeros((3, 1) + T.shape, np.float32)
    kap[2, 0] = K
    dlt = np.zeros_like(kap)
    dlt[2, 0] = escape._offset(K.astype(np.float32))
    m2 = np.full_like(kap, 1 / 12)
    d = np.array([[[0.0, 0.0, 1.0]]])

    def kept():
        r, _, _ = sweeps._sweep(T[None].astype(np.float32), np.ones(3), d, np.ones((1, 1)), np.ones((1, 1) + T.shape),
                                np.zeros((1, 1)), (True, True, False), 0, profile=(kap, dlt, m2, None))
        return r[0, 0]

    want = 1.0 - np.clip(escape._exp_source_escape(T, K), 0.0, 1.0)
    for got in both(monkeypatch, kept):
        assert np.max(np.abs(got - want)) < 1e-6, np.max(np.abs(got - want))


@pytest.mark.parametrize("case", ["cloud", "sky", "isotropic slab", "low sun cubic"])
def test_solve_by_either_path(monkeypatch, case):
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in (10, 12, 12)], indexing="ij")
    cloud = np.where(x * x + 1.5 * y * y + z * z < 0.6, 25.0 * (1.2 - x * x - z), 0.0)
    sig, size, kw = {
        "cloud": (cloud, (1, 1, 0.8), dict(albedo=0.95, g=0.7, sun_dir=(0.3, -0.2, 1.0), tol=1e-3)),
        "sky": (cloud, (1, 1, 0.8), dict(albedo=0.99, g=0.8, sun_dir=(0.6, -0.35, 0.55), sky_radiance=0.3)),
        "isotropic slab": (np.full((8, 1, 1), 2.0), (1, 1, 1),
                           dict(albedo=0.9, g=0.0, sun_dir=(0.5, 0, 0.8), tol=1e-5, periodic=(True, True, False))),
        "low sun cubic": (np.full((4, 3, 3), 2.0), (0.75, 0.75, 1),
                          dict(albedo=1.0, g=0.8, sun_dir=(0.9, 0, 0.26), tol=1e-5, periodic=(True, True, False),
                               max_passes=300)),
    }[case]
    c, n = both(monkeypatch, lambda: scatter.solve(sig, size, total=True, **kw))
    assert c.passes == n.passes and c.injected == pytest.approx(n.injected, rel=1e-6)
    for name in ("received", "total", "received_peaked"):
        close(getattr(c, name), getattr(n, name), 3e-4, name)
    if kw.get("periodic"):
        close(scatter.slab_reflectance(c), scatter.slab_reflectance(n), 1e-5)


def into_case(per_sub, axis=0, shape=(6, 7, 5), with_total=True):
    """A sweep that adds its total to the solve's arrays (``with_total``; else sums none) and (per
    sub-direction) sums each bin's catch into them as it goes, bins scattered over the arrays (not a
    run of rows): (the call, its rows, the arrays before)."""
    rng = np.random.default_rng(9)
    sigma = rng.uniform(0.0, 3.0, shape) * (rng.random(shape) > 0.2)
    _, _, dirs, w = phase.bins(2)
    cen = phase.bins(1)[2][:, 0]
    comp = 2 - axis
    bs = np.flatnonzero((np.abs(cen[:, comp]) >= np.abs(cen).max(1)) & (cen[:, comp] > 0))[[0, 2, 3]]
    emis = rng.uniform(0, 1, (3,) + shape).astype(np.float32) * (sigma > 0)
    base = rng.uniform(0, 1, (96,) + shape).astype(np.float32)
    profile = random_profile(rng, shape, False)

    def run():
        rec, total = np.zeros_like(base), base.copy() if with_total else None
        r, caught, ex = sweeps._sweep(sigma, np.full(3, 0.1), dirs[bs], w[bs] / w[bs].sum(1, keepdims=True), emis,
                                      np.zeros((3, 4)), (False,) * 3, axis, per_sub=per_sub, profile=profile,
                                      into=(rec, total, bs))
        return r.copy(), caught, rec, total, ex.copy()

    return run, bs, base


@pytest.mark.parametrize("with_total", [True, False])
@pytest.mark.parametrize("per_sub", [True, False])
def test_sweep_into_the_solve_arrays_matches_numpy(monkeypatch, per_sub, with_total):
    run, bs, base = into_case(per_sub, with_total=with_total)
    c, n = both(monkeypatch, run)
    assert (c[3] is None) == (n[3] is None) == (not with_total)
    for name, a, b in zip(("received", "caught", "rec", "total", "exit"), c, n):
        if b is None:
            assert a is None, name
            continue
        close(a, b, 2e-5, name)
    if with_total:
        assert np.array_equal(c[3][np.setdiff1d(np.arange(96), bs)], base[np.setdiff1d(np.arange(96), bs)])
    if per_sub:
        close(c[2][bs], c[0].sum(1), 1e-6, "rec is the catch summed over sub-directions")
        close(c[1], c[0].reshape(3, 4, -1).sum(2), 1e-6, "caught per sub-direction")


def staged_and_in_place(monkeypatch, fn):
    """``fn()`` with every layer of the arrays whose layers lie next to one another (the sweeps along
    x) staged in blocks, then with none."""
    with monkeypatch.context() as m:
        m.setattr(_native, "STAGE_MIN", 1)
        staged = fn()
    with monkeypatch.context() as m:
        m.setattr(_native, "STAGE_MIN", 1 << 62)
        return staged, fn()


def equal(a, b, what):
    assert (a is None) == (b is None), what
    if a is not None:
        assert np.array_equal(a, b), (what, np.abs(np.asarray(a, float) - np.asarray(b, float)).max())


# Staging copies the layers through blocks of 16; the arithmetic is the same, so the results are bit
# for bit those of the arrays used in place: 37 layers (two whole blocks and a part), swept down x
# here and up x into the solve's arrays below.
@pytest.mark.parametrize("kind", ["sky", "plain", "profile", "p2", "per_sub"])
def test_staged_layers_give_the_same_bits(monkeypatch, kind):
    s, p = staged_and_in_place(monkeypatch, sweep_case(2, kind, shape=(7, 9, 37)))
    for name, a, b in zip(("received", "total", "exit", "moments"), s, p):
        equal(a, b, name)


@pytest.mark.parametrize("per_sub", [True, False])
def test_staged_layers_into_the_solve_arrays_give_the_same_bits(monkeypatch, per_sub):
    s, p = staged_and_in_place(monkeypatch, into_case(per_sub, axis=2, shape=(6, 7, 37))[0])
    for name, a, b in zip(("received", "caught", "rec", "total", "exit"), s, p):
        equal(a, b, name)


def test_staged_solve_gives_the_same_bits(monkeypatch):
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in (10, 12, 34)], indexing="ij")
    cloud = np.where(x * x + 1.5 * y * y + z * z < 0.6, 25.0 * (1.2 - x * x - z), 0.0)
    kw = dict(albedo=0.95, g=0.7, sun_dir=(0.8, -0.2, 0.5), tol=1e-3)
    s, p = staged_and_in_place(monkeypatch, lambda: scatter.solve(cloud, (2, 1, 0.8), total=True, **kw))
    assert s.passes == p.passes
    for name in ("received", "total", "received_peaked", "exit_flux", "unshot"):
        equal(getattr(s, name), getattr(p, name), name)


def test_outputs_left_dark_give_the_same_bits(monkeypatch):
    """The solve's sweeps leave their outputs as they are outside the cloud (``dark_zero``: the
    memory holds zero there, and no sweep writes anything else there) instead of zeroing each bin's
    first: bit for bit the zeroed sweeps' solve, cold and warm-started from a frame whose cloud had
    another shape (its light in voxels empty now is not part of the guess: as emission there no
    sweep would carry it, and the catches written over the guess's would keep it), and no light
    is received in an empty voxel."""
    from nephele.core.climate.synthetic import demo_dataset
    from nephele.core.light import evolving

    data = demo_dataset()
    first, later = (evolving.climate_cloud(data, step, shape=(12, 16, 16)) for step in (0, 40))
    assert ((first > 0) != (later > 0)).sum() > 100
    kw = dict(albedo=0.99, g=0.8, sun_dir=(0.3, 0.2, 0.9), tol=1e-3, size=(1.0, 1.0, 0.75), total=True)

    def run():
        cold = scatter.solve(first, **kw)
        return cold, scatter.solve(later, warm=cold, **kw)

    dark = run()
    with monkeypatch.context() as m:
        sweep = _native.sweep
        m.setattr(_native, "sweep", lambda *a, dark_zero=False: sweep(*a, dark_zero=False))
        zeroed = run()
    for d, z, sigma in zip(dark, zeroed, (first, later)):
        assert d.passes == z.passes
        for name in ("received", "total", "received_peaked", "exit_flux", "unshot", "moments_binned"):
            equal(getattr(d, name), getattr(z, name), name)
        empty = sigma[d.box] == 0
        assert empty.any() and not d.received[:, empty].any()
    assert dark[1].warm
