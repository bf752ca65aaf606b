"""Red-cyan anaglyphs: which eye feeds which channel, and the grey they use."""

import numpy as np
import pytest

from nephele.core.camera.anaglyph import LUMA, MODES, grey, red_cyan
from nephele.core.errors import DataError


def _pair(shape=(5, 7, 4), seed=0):
    rng = np.random.default_rng(seed)
    return rng.random(shape), rng.random(shape)


def test_colour_takes_red_from_left_green_blue_from_right():
    left, right = _pair()
    out = red_cyan(left, right, "colour")
    assert np.array_equal(out[..., 0], left[..., 0])
    assert np.array_equal(out[..., 1:3], right[..., 1:3])
    assert np.array_equal(out[..., 3], left[..., 3])  # alpha from the left view


def test_half_and_grey_use_rec709_luma():
    left, right = _pair(shape=(3, 4, 3), seed=1)
    luma_l = 0.2126 * left[..., 0] + 0.7152 * left[..., 1] + 0.0722 * left[..., 2]
    luma_r = 0.2126 * right[..., 0] + 0.7152 * right[..., 1] + 0.0722 * right[..., 2]
    half = red_cyan(left, right, "half")
    np.testing.assert_allclose(half[..., 0], luma_l, rtol=0, atol=1e-12)
    assert np.array_equal(half[..., 1:3], right[..., 1:3])
    g = red_cyan(left, right, "grey")
    np.testing.assert_allclose(g[..., 0], luma_l, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g[..., 1], luma_r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g[..., 2], luma_r, rtol=0, atol=1e-12)


def test_grey_of_primaries_and_white():
    assert sum(LUMA) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(grey(np.eye(3)), LUMA, atol=1e-12)
    assert grey(np.ones((2, 2, 4)))[0, 0] == pytest.approx(1.0)


def test_identical_eyes_give_a_grey_picture_and_a_point_offset_splits_into_red_and_cyan():
    img = np.zeros((4, 8, 3))
    img[1, 2] = 1.0
    same = red_cyan(img, img, "grey")
    assert np.array_equal(same[..., 0], same[..., 1]) and np.array_equal(same[..., 1], same[..., 2])
    shifted = np.roll(img, 3, axis=1)  # the right eye sees the white point 3 pixels further right
    out = red_cyan(img, shifted, "grey")
    assert tuple(out[1, 2]) == (1.0, 0.0, 0.0)  # left eye only: red
    assert tuple(out[1, 5]) == (0.0, 1.0, 1.0)  # right eye only: cyan
    assert out.sum() == 3.0


def test_inputs_untouched_nan_passed_and_float32_kept():
    left, right = (a.astype(np.float32) for a in _pair(shape=(2, 3, 3), seed=2))
    left[0, 0, 0] = np.nan
    keep = left.copy(), right.copy()
    out = red_cyan(left, right, "colour")
    assert out.dtype == np.float32 and np.isnan(out[0, 0, 0])
    assert np.array_equal(left, keep[0], equal_nan=True) and np.array_equal(right, keep[1])
    assert np.isnan(red_cyan(left, right, "half")[0, 0, 0])


def test_empty_image():
    out = red_cyan(np.zeros((0, 0, 3)), np.zeros((0, 0, 3)))
    assert out.shape == (0, 0, 3)


@pytest.mark.parametrize("left, right, mode, msg", [
    (np.zeros((2, 2, 3)), np.zeros((2, 3, 3)), "half", "differ in shape"),
    (np.zeros((2, 2)), np.zeros((2, 2)), "half", r"\(h, w, 3 or 4\)"),
    (np.zeros((2, 2, 2)), np.zeros((2, 2, 2)), "half", r"\(h, w, 3 or 4\)"),
    (np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), "dubois", "mode must be one of"),
])
def test_bad_input_one_clear_line(left, right, mode, msg):
    with pytest.raises(DataError, match=msg):
        red_cyan(left, right, mode)


@pytest.mark.parametrize("mode", MODES)
def test_uint8_values_kept_as_they_are(mode):
    left = np.full((1, 1, 3), 200, np.uint8)
    out = red_cyan(left, left, mode)
    assert out.dtype == np.float64 and np.allclose(out, 200.0)
