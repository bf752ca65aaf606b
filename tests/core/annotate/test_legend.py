"""Legends show the transfer functions the renderer uses; overlays and title cards stay inside the frame."""

import numpy as np
import pytest

from nephele.core.annotate import (
    ColorBar,
    OpacityBar,
    Swatch,
    bar_pixels,
    bar_values,
    box_text,
    legend_image,
    overlay,
    srgb_decode,
    srgb_encode,
    title_card,
)
from nephele.core.annotate.canvas import line_height
from nephele.core.annotate.legend import legend_size
from nephele.core.errors import DataError
from nephele.core.volume.transfer import ALTITUDE_COLORS, TEMPERATURE_COLORS, TransferFunction


def test_srgb_round_trip_and_known_values():
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    np.testing.assert_allclose(srgb_encode([0.0, 0.0031308, 0.214041, 1.0]), [0.0, 0.04045, 0.5, 1.0], atol=1e-5)


@pytest.mark.parametrize("cmap", [ALTITUDE_COLORS, TEMPERATURE_COLORS])
def test_colour_bar_is_the_colour_map(cmap):
    """Each pixel of the bar is the ColorMap's own colour at that pixel's value, sRGB-encoded."""
    bar = ColorBar("c", cmap.points)
    for width in (7, 160, 401):
        values = bar_values(bar, width)
        lo, hi = cmap.range
        np.testing.assert_allclose(values, lo + (np.arange(width) + 0.5) * (hi - lo) / width)
        np.testing.assert_allclose(srgb_decode(bar_pixels(bar, width)), cmap(values), atol=2e-6)


def test_opacity_bar_is_the_transfer_function():
    tf = TransferFunction.ramp(0.3, 0.7)
    bar = OpacityBar("cloud", tf.points)
    assert bar.range == (0.0, 1.0)
    px = bar_pixels(bar, 200)
    values = bar_values(bar, 200)
    np.testing.assert_allclose(px[:, 0], tf(values), atol=1e-6)
    assert np.all(px[values <= 0.3] == 0.0) and np.all(px[values >= 0.7] == 1.0)
    # opacities above 1 are shown relative to the largest
    strong = OpacityBar("q", ((0.0, 0.0), (10.0, 4.0)), span=(0.0, 10.0))
    np.testing.assert_allclose(bar_pixels(strong, 10)[:, 1], (np.arange(10) + 0.5) / 10, atol=1e-6)
    with pytest.raises(DataError, match="ascending"):
        OpacityBar("bad", ((0.5, 0.0), (0.2, 1.0)))


def test_legend_image_holds_the_bars_where_laid_out():
    entries = [ColorBar("altitude", ALTITUDE_COLORS.points, "m"),
               OpacityBar("cloud", TransferFunction.ramp(0.3, 0.7).points),
               Swatch("smoke", (0.8, 0.8, 0.9))]
    size = 12
    img = legend_image(entries, box_text, size)
    w, h, bw, bh = legend_size(entries, size, box_text)
    assert img.shape == (h, w, 4)
    long = legend_image([Swatch("a label much longer than the bar is wide", (1.0, 1.0, 1.0))], box_text, size)
    assert long.shape[1] > legend_size([entries[2]], size)[0]  # the panel widens for its label
    pad, lh = size // 2, line_height(size)
    y = pad + lh  # the first bar under its label
    np.testing.assert_allclose(img[y + bh // 2, pad : pad + bw, :3], bar_pixels(entries[0], bw), atol=1e-6)
    y += bh + lh + pad + lh  # ticks, gap, next label
    np.testing.assert_allclose(img[y + bh // 2, pad : pad + bw, :3], bar_pixels(entries[1], bw), atol=1e-6)
    y += bh + lh + pad + lh
    np.testing.assert_allclose(img[y + 1, pad : pad + bw, :3], bar_pixels(entries[2], bw), atol=1e-6)
    assert np.all(img[..., 3] == 1.0)  # an opaque panel behind it all: readable over any picture


def _ink(layer):
    ys, xs = np.nonzero(layer[..., 3] > 0.5)
    return xs, ys


@pytest.mark.parametrize("size", [(480, 270), (1920, 1080), (640, 480)])
def test_overlay_corners(size):
    w, h = size
    entries = [ColorBar("altitude", ALTITUDE_COLORS.points, "m")]
    layer = overlay(w, h, box_text, heading="Fig. 1  Contour surfaces of 15% cloudiness",
                    time_text="1987-01-02 06:00", note="360-day calendar", legend=entries)
    assert layer.shape == (h, w, 4) and layer.dtype == np.float32
    right = layer[: h // 3, w // 2 :]
    assert right[..., 3].max() == 1.0  # the time, top right
    left = layer[h // 2 :, : w // 2]
    assert left[..., 3].max() > 0.5  # the legend, bottom left
    middle = layer[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3]
    assert middle[..., 3].max() == 0.0  # the picture's centre is left alone


def test_tiny_frames_get_a_small_legend_or_none():
    entries = [ColorBar("altitude", ALTITUDE_COLORS.points, "m"), OpacityBar("cloud", ((0.3, 0.0), (0.7, 1.0)))]
    for w, h in ((160, 90), (64, 36)):
        layer = overlay(w, h, box_text, legend=entries)
        ys = np.nonzero(layer[..., 3] > 0)[0]
        assert ys.size == 0 or ys.min() >= 0.5 * h


def test_heading_never_runs_into_the_time():
    w, h = 320, 180
    alone = overlay(w, h, box_text, time_text="1987-01-02 06:00")
    both = overlay(w, h, box_text, heading="Fig. 3  Clouds and wind velocity by hardware texture mapping",
                   time_text="1987-01-02 06:00")
    xs_time, _ = _ink(alone)
    heading_only = (both[..., 3] > 0.5) & ~(alone[..., 3] > 0.5)
    assert heading_only.any()
    assert np.nonzero(heading_only)[1].max() < xs_time.min()


def test_title_card():
    card = title_card(480, 270, box_text, number="Fig. 4", caption="Clouds of fig. 1 with transparency texture",
                      lines=["a line", "another"])
    assert card.shape == (270, 480, 3)
    assert card.max() == pytest.approx(1.0) and card.min() >= 0.0
    # text stays inside: the margins are the bare background gradient, the same in every column
    np.testing.assert_array_equal(card[:, :8], np.broadcast_to(card[:, :1], (270, 8, 3)))
    np.testing.assert_array_equal(card[:, -8:], np.broadcast_to(card[:, :1], (270, 8, 3)))
    assert not np.array_equal(card[:, 200:280], np.broadcast_to(card[:, :1], (270, 80, 3)))
