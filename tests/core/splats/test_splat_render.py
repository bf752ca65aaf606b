"""Reference splat renderer: constant media, convergence to the exact ray integral, order, bad input."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.splats import (
    Camera,
    Splats,
    principal_axes,
    project_splats,
    ray_integral,
    render_splats,
    splat_kernel,
)

K = splat_kernel()


def lattice_splats(lo, hi, h, opacity=None, color=None, wind=None):
    """Splats on a cubic lattice of spacing ``h`` filling the box ``lo..hi``."""
    axes = [np.arange(a, b + 1e-9, h) for a, b in zip(lo, hi)]
    c = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    o = np.ones(len(c)) if opacity is None else opacity(c)
    keep = o > 0
    c, o = c[keep], o[keep]
    m = len(c)
    col = np.ones((m, 3)) if color is None else color(c)
    w = np.zeros((m, 3)) if wind is None else np.broadcast_to(wind(c), (m, 3)).copy()
    return Splats(c, principal_axes(np.broadcast_to(np.eye(3) * h, (m, 3, 3)), K.radius), col, o, w, K.radius)


SLAB = dict(lo=(-1.5, -1.5, -0.25), hi=(1.5, 1.5, 0.25), h=0.05)  # 11 layers: thickness 11 h


def test_constant_slab_gives_uniform_exact_opacity_orthographic():
    sp = lattice_splats(**SLAB)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.0)
    img = render_splats(sp, K, cam, 64, 64, extinction=2.0)
    alpha = img[..., 3]
    expected = 1 - np.exp(-2.0 * 11 * 0.05)
    print(f"constant slab, orthographic: alpha mean {alpha.mean():.6f} (exact {expected:.6f}), std {alpha.std():.1e}")
    assert np.abs(alpha - expected).max() < 1e-3 * expected
    assert np.allclose(img[..., :3], alpha[..., None], atol=1e-6)  # white medium: premultiplied colour = alpha


def test_constant_slab_under_perspective_follows_the_slant_path():
    sp = lattice_splats(**SLAB)
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0), fov=30)
    img = render_splats(sp, K, cam, 64, 64, extinction=2.0)
    f = cam.pixels_per_unit(64)
    x, y = np.meshgrid((np.arange(64) + 0.5 - 32) / f, (np.arange(64) + 0.5 - 32) / f)
    tau = 2.0 * 11 * 0.05 * np.sqrt(1 + x * x + y * y)  # path through the slab grows as 1/cos
    rel = np.abs(-np.log1p(-img[..., 3].astype(np.float64)) / tau - 1).max()
    print(f"constant slab, perspective: worst relative optical-depth error {rel:.1e}")
    assert rel < 2e-3


def blob(h):
    """A Gaussian cloud whose colour runs red (back) to blue (front) along z: order matters."""

    def colour(c):
        t = np.clip(0.5 + 1.2 * c[:, 2], 0, 1)
        return np.column_stack([t, np.full_like(t, 0.3), 1 - t])

    def opacity(c):
        o = np.exp(-np.sum(c * c, axis=1) / (2 * 0.35**2))
        return np.where(o > 1e-4, o, 0.0)

    return lattice_splats((-1.2,) * 3, (1.2,) * 3, h, opacity, colour)


@pytest.mark.parametrize(
    "camera",
    [
        Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.4),
        Camera.look_at((0.6, 0.4, 3), (0, 0, 0), up=(0, 1, 0), fov=45),
    ],
    ids=["orthographic", "perspective"],
)
def test_converges_to_the_exact_ray_integral_as_splats_shrink(camera):
    errors = []
    for h in (0.3, 0.15):
        sp = blob(h)
        img = render_splats(sp, K, camera, 32, 32, extinction=5.0, prefilter=0.0)
        ref = ray_integral(sp, K, camera, 32, 32, extinction=5.0, steps=200)
        errors.append(float(np.abs(img - ref).max()))
        if camera.orthographic:
            # Footprints are exact integrals: the opacity matches to rounding.
            assert np.abs(img[..., 3] - ref[..., 3]).max() < 1e-5
    print(f"splat vs exact ray integral, worst pixel error at h 0.3 / 0.15: {errors[0]:.2e} / {errors[1]:.2e}")
    assert errors[1] < errors[0] / 2  # measured ~h^1.5-h^2 (0.026 -> 0.009 -> 0.0025 down to h 0.075)
    assert errors[1] < 0.015


def test_compositing_order_front_splat_wins():
    # Two opaque splats on the axis, red in front, blue behind: red whatever the array order.
    c = np.array([[0, 0, 0.5], [0, 0, -0.5]])
    axes = principal_axes(np.broadcast_to(np.eye(3) * 0.2, (2, 3, 3)), K.radius)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.0)
    images = []
    for order in ([0, 1], [1, 0]):
        sp = Splats(c[order], axes, np.array([[1, 0, 0], [0, 0, 1.0]])[order], np.ones(2), np.zeros((2, 3)), K.radius)
        images.append(render_splats(sp, K, cam, 16, 16, extinction=200.0))
    assert np.array_equal(images[0], images[1])
    centre = images[0][8, 8]
    assert centre[0] > 0.99 and centre[2] < 0.01
    # Transmission is order-free: alpha = 1 - exp(-(tau1 + tau2)).
    single = render_splats(Splats(c[:1], axes[:1], np.ones((1, 3)), np.ones(1), np.zeros((1, 3)), K.radius), K, cam, 16,
                           16, extinction=200.0)
    t1 = 1 - single[..., 3].astype(np.float64)
    assert np.allclose(1 - images[0][..., 3], t1 * t1, atol=1e-6)


def test_prefilter_keeps_tiny_splats_from_aliasing():
    # Splats far smaller than a pixel: with the prefilter every one still deposits its
    # footprint integral (total optical depth conserved); without it, point sampling
    # misses most of them and overweights the few it hits.
    rng = np.random.default_rng(0)
    n = 200
    c = np.column_stack([rng.uniform(-0.8, 0.8, (n, 2)), np.zeros(n)])
    axes = principal_axes(np.broadcast_to(np.eye(3) * 0.001, (n, 3, 3)), K.radius)
    sp = Splats(c, axes, np.ones((n, 3)), np.ones(n), np.zeros((n, 3)), K.radius)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.0)
    f = cam.pixels_per_unit(32)
    exact = 1.0 * n * 0.001**3 * f * f  # Σ ∫ τ d(pixel area): extinction 1 · volume in cell units h³ · px²/unit²
    for pre, tol in ((0.25, 0.01), (0.0, None)):
        img = render_splats(sp, K, cam, 32, 32, extinction=1.0, prefilter=pre)
        total = float(-np.log1p(-img[..., 3].astype(np.float64)).sum())
        if tol is not None:
            assert total == pytest.approx(exact, rel=tol)
        else:
            assert abs(total / exact - 1) > 0.3


def test_splats_behind_or_straddling_the_eye_are_dropped():
    axes = principal_axes(np.broadcast_to(np.eye(3) * 0.1, (3, 3, 3)), K.radius)
    c = np.array([[0, 0, 0], [0, 0, 6.0], [0, 0, 5.1]])  # in front; behind; around the eye
    sp = Splats(c, axes, np.ones((3, 3)), np.ones(3), np.zeros((3, 3)), K.radius)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), fov=40)
    assert list(project_splats(sp, K, cam, 32, 32).keep) == [0]


def test_empty_and_transparent_splats_give_a_clear_image():
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0))
    empty = Splats(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), K.radius)
    assert not render_splats(empty, K, cam, 8, 6).any()
    clear = lattice_splats((0, 0, 0), (0.2, 0.2, 0.2), 0.1, opacity=lambda c: np.zeros(len(c)) + 1e-30)
    assert render_splats(clear, K, cam, 8, 6).max() < 1e-20


def test_bad_input_raises_data_error():
    sp = lattice_splats((0, 0, 0), (0.2, 0.2, 0.2), 0.1)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0))
    calls = [
        lambda: render_splats(sp, splat_kernel(radius=2.0), cam, 8, 8),
        lambda: render_splats(sp, K, "camera", 8, 8),
        lambda: render_splats(sp, K, cam, 0, 8),
        lambda: render_splats(sp, K, cam, 8, 8, streaks=np.zeros((4, 4))),
        lambda: render_splats(sp, K, cam, 8, 8, extinction=-1),
        lambda: render_splats(sp, K, cam, 8, 8, prefilter=np.nan),
        lambda: Camera.look_at((0, 0, 0), (0, 0, 0)),
        lambda: Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 0, 1)),
        lambda: Camera(np.diag([2.0, 1, 1, 1])),
        lambda: Camera(np.eye(4), fov=180),
        lambda: Splats(np.zeros((1, 3)), np.zeros((1, 3, 3)), np.zeros((1, 3)), np.array([np.nan]), np.zeros((1, 3)),
                       2.5),
        lambda: Splats(np.zeros((2, 3)), np.zeros((1, 3, 3)), np.zeros((2, 3)), np.zeros(2), np.zeros((2, 3)), 2.5),
    ]
    for call in calls:
        with pytest.raises(DataError):
            call()


def test_globe_depth_hides_the_far_side():
    from nephele.core.splats import sphere_depth

    for cam in (
        Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=3.0),
        Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), fov=40),
    ):
        d = sphere_depth(cam, 32, 32)
        assert d[16, 16] == pytest.approx(4.0, abs=0.01) and np.isinf(d[0, 0])
        axes = principal_axes(np.broadcast_to(np.eye(3) * 0.05, (2, 3, 3)), K.radius)
        near = Splats(np.array([[0, 0, 1.05]]), axes[:1], np.ones((1, 3)), np.ones(1), np.zeros((1, 3)), K.radius)
        far = Splats(np.array([[0, 0, -1.05]]), axes[:1], np.ones((1, 3)), np.ones(1), np.zeros((1, 3)), K.radius)
        assert render_splats(near, K, cam, 32, 32, depth=d)[..., 3].max() > 0.2
        assert render_splats(far, K, cam, 32, 32, depth=d)[..., 3].max() == 0
        assert render_splats(far, K, cam, 32, 32)[..., 3].max() > 0.2
    with pytest.raises(DataError):
        render_splats(near, K, cam, 32, 32, depth=np.zeros((3, 3)))


def test_anisotropic_splat_matches_line_integrals_of_the_ellipsoidal_kernel():
    # A rotated, strongly anisotropic splat seen obliquely: the optical depth at pixels equals
    # the line integral of the ellipsoidal kernel along the pixel's ray (trapezoid, 20001 points).
    # Orthographic: exact.  Perspective: EWA's affine approximation, whose error falls as the
    # splat shrinks in the view (a splat subtending ~20 degrees: a few per cent).
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    centre = np.array([0.1, -0.05, 0.2])
    ortho = Camera.look_at((3.0, 1.5, 2.0), (0, 0, 0), up=(0, 0, 1), orthographic=True, ortho_scale=1.6)
    persp = Camera.look_at((3.0, 1.5, 2.0), (0, 0, 0), up=(0, 0, 1), fov=20)
    errors = {}
    for name, cam, scale, tol in (("orthographic", ortho, 1.0, 1e-5), ("perspective", persp, 1.0, 0.05),
                                  ("perspective, 1/4 size", persp, 0.25, 0.01)):
        axes = principal_axes((q @ np.diag([0.05, 0.12, 0.3]) * scale)[None], K.radius)
        sp = Splats(centre[None], axes, np.ones((1, 3)), np.ones(1), np.zeros((1, 3)), K.radius)
        inv = K.radius * np.linalg.inv(axes[0])
        reach = np.linalg.norm(axes[0], axis=0).max()
        img = render_splats(sp, K, cam, 40, 40, extinction=1.0, prefilter=0.0)
        tau = -np.log1p(-img[..., 3].astype(np.float64))
        rot, f = cam.world_to_camera[:3, :3], cam.pixels_per_unit(40)
        rows, cols = np.nonzero(tau > 0.3 * tau.max())
        worst = 0.0
        for r, c in list(zip(rows, cols))[:: max(1, len(rows) // 25)]:
            x, y = (c + 0.5 - 20) / f, -(r + 0.5 - 20) / f
            if cam.orthographic:
                o, d = rot.T @ (np.array([x, y, 0.0]) - cam.world_to_camera[:3, 3]), rot.T @ np.array([0, 0, -1.0])
            else:
                o, d = cam.position, rot.T @ (np.array([x, y, -1.0]) / np.linalg.norm([x, y, -1.0]))
            t0 = float((centre - o) @ d)
            t = np.linspace(t0 - reach, t0 + reach, 20001)
            ref = (np.trapezoid(K.weight((o + t[:, None] * d - centre) @ inv.T), t) if hasattr(np, "trapezoid")
                   else np.trapz(K.weight((o + t[:, None] * d - centre) @ inv.T), t))
            worst = max(worst, abs(tau[r, c] - ref) / ref)
        print(f"anisotropic splat, {name}: worst relative optical-depth error {worst:.1e}")
        errors[name] = worst
        assert worst < tol
    assert errors["perspective, 1/4 size"] < errors["perspective"] / 3


@pytest.mark.parametrize("extinction", [1e-4, 1.0, 50.0, 1e9])
def test_thin_and_thick_constant_media(extinction):
    # Optical depth 5.5e-5 .. 5.5e8 through the slab: alpha = 1 - exp(-tau) without loss or NaN.
    sp = lattice_splats(**SLAB)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.0)
    img = render_splats(sp, K, cam, 24, 24, extinction=extinction).astype(np.float64)
    tau = extinction * 11 * 0.05
    assert np.all(np.isfinite(img))
    assert np.allclose(img[..., 3], -np.expm1(-tau), rtol=1e-3, atol=1e-7)
    assert np.allclose(img[..., :3], img[..., 3:], rtol=1e-5, atol=1e-7)


def test_batches_composite_like_one_pass(monkeypatch):
    import nephele.core.splats.render as render

    sp = blob(0.15)
    cam = Camera.look_at((0.6, 0.4, 3), (0, 0, 0), up=(0, 1, 0), fov=45)
    whole = render_splats(sp, K, cam, 32, 32, extinction=5.0)
    monkeypatch.setattr(render, "MAX_FRAGMENTS", 500)  # many front-to-back batches
    batched = render_splats(sp, K, cam, 32, 32, extinction=5.0)
    assert np.allclose(whole, batched, atol=1e-6)
