"""Warm starts (core/light/_warm.py) and evolving clouds (core/light/evolving.py): a solve started
from the previous frame ends where a cold solve of its own frame ends, frame after frame."""

import dataclasses

import numpy as np
import pytest
from kernel_paths import EVERY

from nephele.core.errors import DataError
from nephele.core.light import evolving, scatter
from nephele.core.volume import cloud_density as cd

SIZE = (1.0, 1.0, 0.75)
KW = dict(albedo=0.99, g=0.8, sun_dir=(0.6, -0.35, 0.55), tol=1e-3)
PARAMS = cd.CloudParams(shape=(12, 16, 16), size=SIZE)


def l1(sol, ref):
    return np.abs(sol.received - ref.received).sum(dtype=np.float64) / ref.injected


@pytest.fixture(scope="module")
def frames():
    """Three frames in a row of the drifting cloud filmed in 240 (extinction 20: voxel tau up to 1),
    and each one's reference: tol 1e-5 with 2x2 sub-directions in every pass (a warm start carries
    all the binned light on 2x2 in its Jacobi pass, where a cold solve's late passes take 1x1)."""
    sig = [evolving.drifting_cloud(PARAMS, i, 240, extinction=20.0) for i in (0, 1, 2)]
    return sig, [scatter.solve(s, SIZE, **dict(KW, tol=1e-5, late_sub=None)) for s in sig]


# Measured (16x16x12, frames 0 -> 1 of 240): cold 8.5e-4 from the reference (its 1x1 late passes),
# warm 1.9e-4 in 1 pass against 5; warm from its own reference 0 passes.  (Frames 8 of 240 apart,
# or the coarse 24x24x18 cloud at extinction 40 with second moments: warm 0.6-4e-3, its Jacobi pass
# shooting the guess's light with profiles from its summed moments, not pass by pass.)
@pytest.mark.parametrize("kernels", EVERY, indirect=True)
def test_warm_start_ends_at_its_own_frames_solution(frames, kernels):
    sig, ref = frames
    cold = scatter.solve(sig[1], SIZE, **KW)
    assert not cold.warm
    warm = scatter.solve(sig[1], SIZE, warm=scatter.solve(sig[0], SIZE, **KW), **KW)
    assert warm.warm and warm.converged and "from the previous frame" in warm.report
    assert warm.passes < cold.passes
    assert l1(warm, ref[1]) < 5e-4 < l1(cold, ref[1])
    same = scatter.solve(sig[1], SIZE, warm=ref[1], **KW)
    assert same.passes == 0 and l1(same, ref[1]) < 5e-4
    # the peaked orders and the sun are this frame's own, bit for bit
    np.testing.assert_array_equal(warm.received_peaked, cold.received_peaked)
    np.testing.assert_array_equal(warm.received_sun, cold.received_sun)


def test_warm_starts_do_not_drift(frames):
    # frame after frame (and again and again on one frame) the error stays where one warm start puts it
    sig, ref = frames
    prev, errs = None, []
    for s, r in zip(sig, ref):
        prev = scatter.solve(s, SIZE, warm=prev, **KW)
        errs.append(l1(prev, r))
    for _ in range(4):
        prev = scatter.solve(sig[-1], SIZE, warm=prev, **KW)
        errs.append(l1(prev, ref[-1]))
    assert max(errs[1:]) < 5e-4, errs
    assert errs[-1] < 1.5 * errs[2] + 1e-4, errs


def test_warm_start_needs_the_same_grid_and_survives_a_file(tmp_path, frames):
    sig, ref = frames
    other = scatter.solve(evolving.drifting_cloud(dataclasses.replace(PARAMS, shape=(9, 12, 12)), 0, 240), SIZE, **KW)
    assert not scatter.solve(sig[0], SIZE, warm=other, **KW).warm  # another grid: a cold start, said so
    assert ref[0].moments_binned is not None and ref[0].moments_binned.dtype == np.float32
    scatter.save_solution(ref[0], tmp_path / "s.npz")
    back = scatter.load_solution(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.moments_binned, ref[0].moments_binned)
    a = scatter.solve(sig[1], SIZE, warm=back, **KW)
    b = scatter.solve(sig[1], SIZE, warm=ref[0], **KW)
    np.testing.assert_array_equal(a.received, b.received)


def test_drifting_cloud_moves_its_noise_and_keeps_its_ellipsoids():
    first = evolving.drifting_cloud(PARAMS, 0, 10, extinction=1.0)
    np.testing.assert_array_equal(first, cd.cloud_density(PARAMS))
    later = evolving.drifting_cloud(PARAMS, 5, 10, extinction=1.0)
    smooth = cd.cloud_density(dataclasses.replace(PARAMS, noise_amplitude=0.0))
    assert np.abs(later - first).max() > 0.05
    np.testing.assert_array_equal(later[smooth == 0], 0.0)  # outside the ellipsoids no noise either way
    with pytest.raises(DataError):
        evolving.drifting_cloud(PARAMS, 10, 10)


def test_climate_cloud_is_a_cut_of_the_demo_cloud_field():
    from nephele.core.climate.synthetic import demo_dataset

    data = demo_dataset("small")  # 64x32x8
    sig = evolving.climate_cloud(data, 3, shape=(12, 10, 14), window=(10, 5, 20, 16), extinction=2.0)
    assert sig.shape == (12, 10, 14) and sig.dtype == np.float32
    assert sig.max() <= 2.0 and sig[:, :, 0].max() == sig[0].max() == sig[:, -1].max() == 0.0
    cut = np.asarray(data.read("cloud", 3))[:, 5:21, 10:30]
    # the layers' means follow the field's levels (linear resampling keeps the column's shape)
    assert np.corrcoef(sig[1:-1, 1:-1, 1:-1].mean((1, 2)), np.interp(np.linspace(0, 7, 12), np.arange(8),
                                                                       cut.mean((1, 2)))[1:-1])[0, 1] > 0.9
    with pytest.raises(DataError):
        evolving.climate_cloud(data, 0, window=(60, 0, 20, 10))
