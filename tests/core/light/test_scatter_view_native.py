"""The views' plane march by the compiled kernel (native/src/scatter_view.c) against its NumPy twin
(:func:`nephele.core.light._views._march_rays`): views along every axis both ways, the eye inside
the cloud, media too thick and too thin for the exponentials' ranges, a background.  Both take the
same samples in the same order; they differ only by the float32 exponentials (scatter_math.h's
against NumPy's), a few units in the last place of a segment."""

import numpy as np
import pytest

from nephele.core import native
from nephele.core.light import scatter
from nephele.core.splats.camera import Camera

pytestmark = pytest.mark.skipif(native.identity() == "numpy", reason="no compiled kernels")

SIZE = (1.0, 0.8, 0.6)


def both(monkeypatch, fn):
    """``fn()`` by the compiled kernel, then by the NumPy twin."""
    c = fn()
    with monkeypatch.context() as m:
        m.setattr(native, "_module", lambda: None)
        n = fn()
    return c, n


def cloud(shape=(12, 16, 20), seed=0, scale=30.0):
    """Extinction with holes and an empty rim (rays that start, end and skip inside the box), and a
    source that is not zero where the extinction is (emission from voxels no ray attenuates)."""
    rng = np.random.default_rng(seed)
    sigma = scale * rng.uniform(0.0, 1.0, shape) * (rng.random(shape) > 0.3)
    sigma[:, :2] = 0.0
    source = rng.uniform(0.0, 2.0, shape) * (rng.random(shape) > 0.2)
    return sigma, source.astype(np.float32)


def agree(c, n, rel=3e-6, zeros=True):
    scale = max(float(np.abs(n).max()), 1e-30)
    assert np.abs(c - n).max() <= rel * scale, np.abs(c - n).max() / scale
    if zeros:  # the same pixels see nothing
        assert np.array_equal(c == 0, n == 0)


# (orbit angle, elevation): the view's dominant axis x, y and z, each way
VIEWS = [(0.0, 0.2), (np.pi, 0.3), (0.5 * np.pi, -0.2), (1.5 * np.pi, 0.1), (0.3, 1.3), (2.0, -1.35)]


@pytest.mark.parametrize("samples", [1, 2])
@pytest.mark.parametrize("angle, elevation", VIEWS)
def test_march_matches_numpy(monkeypatch, angle, elevation, samples):
    sigma, source = cloud()
    cam = scatter.orbit_camera(angle, SIZE, elevation=elevation, width=80, height=60)
    c, n = both(monkeypatch, lambda: scatter.march_planes(sigma, source, SIZE, cam, samples=samples))
    assert n.std() > 0.0 and (n > 0).mean() > 0.2  # the cloud is in the picture
    agree(c, n)


def test_eye_inside_the_cloud(monkeypatch):
    sigma, source = cloud(scale=3.0)
    cam = Camera.look_at(np.array([0.45, 0.4, 0.3]), np.array([1.0, 0.9, 0.35]), fov=70.0, width=64, height=48)
    c, n = both(monkeypatch, lambda: scatter.march_planes(sigma, source, SIZE, cam, samples=2))
    assert (n > 0).mean() > 0.9
    agree(c, n)


@pytest.mark.parametrize("scale", [0.0, 1e-30, 1e-3, 1e5])
def test_thin_and_thick_media(monkeypatch, scale):
    # 0: tau exactly 0 (the segment's (1 - e^-tau) / tau is 1); 1e5: tau per sample beyond
    # float32's exp range (the light of the first texels only, the rest extinguished)
    sigma, source = cloud(seed=1, scale=scale)
    cam = scatter.orbit_camera(0.7, SIZE, elevation=0.4, width=64, height=48)
    c, n = both(monkeypatch, lambda: scatter.march_planes(sigma, source, SIZE, cam, samples=2, background=0.25))
    # (the kernel flushes values under 1.2e-38 to zero, where NumPy keeps the transmittance's
    # denormals: through a thick voxel some pixels are exactly 0 by one path only)
    agree(c, n, zeros=scale < 1e3)
    if scale == 0.0:  # nothing absorbs: every ray sees the background whole, plus the source's path integral,
        # as the ray march (step 0.1 voxel) integrates it (measured: sums 1e-4 apart, pixels 0.6 % on the mean)
        ref = scatter.render(sigma, source, SIZE, cam, step=0.1, background=0.25) - 0.25
        assert n.min() >= 0.25 and n.max() > 0.3
        assert abs((n - 0.25).sum() / ref.sum() - 1.0) < 1e-3
        lit = ref > 0.05 * ref.max()
        assert np.abs(n - 0.25 - ref)[lit].mean() < 0.02 * ref[lit].mean()
    if scale == 1e5:  # opaque: the front texels' light, nothing of the background behind the cloud
        assert n.min() == 0.0 and n.max() > 0.25


def test_background_through_an_empty_box(monkeypatch):
    sigma, source = np.zeros((6, 7, 8)), np.zeros((6, 7, 8), np.float32)
    sigma[3, 3, 4] = 5.0
    cam = scatter.orbit_camera(1.0, SIZE, width=40, height=30)
    c, n = both(monkeypatch, lambda: scatter.march_planes(sigma, source, SIZE, cam, background=1.0))
    agree(c, n)
    assert n.max() == 1.0 and n.min() < 1.0  # the one voxel's shadow on the background
