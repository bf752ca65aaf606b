"""A legend of the transfer functions a picture uses: colour bars, opacity ramps, constant colours.

Each entry shows one scalar's mapping over its value range, sampled at the
pixel centres of the bar, exactly as the renderer maps it: piecewise linear
between control points and constant beyond them (the
:class:`~nephele.core.volume.transfer.ColorMap` and
:class:`~nephele.core.volume.transfer.TransferFunction` rule, and Blender's
linear Color Ramp).  Colours are linear RGB, shown sRGB-encoded; an opacity
is shown as a grey level (black clear, white opaque), the convention of the
add-on's transfer-function ramp (:mod:`nephele.addon.tf_ramp`).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization": "a
   separate transfer function can be used to specify the cloud color as a
   function of another scalar variable like altitude or temperature."
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from .canvas import PANEL, draw_text, fill, line_height, new_canvas, srgb_encode


def _ascending(values, what):
    v = np.asarray(values, np.float64)
    if v.size < 1 or not np.all(np.isfinite(v)) or np.any(np.diff(v) < 0):
        raise DataError("control point values must be finite and ascending", field=what)
    return v


@dataclass(frozen=True)
class ColorBar:
    """A colour transfer function: ``stops`` are ``(value, (r, g, b))`` in linear RGB, ascending values."""

    label: str
    stops: tuple
    unit: str = ""

    def __post_init__(self):
        _ascending([s[0] for s in self.stops], f"legend {self.label}")

    @property
    def range(self):
        return float(self.stops[0][0]), float(self.stops[-1][0])

    def colors(self, values):
        """Linear RGB at ``values``: ``values.shape + (3,)``."""
        v = np.array([s[0] for s in self.stops], np.float64)
        c = np.array([s[1][:3] for s in self.stops], np.float64)
        return np.stack([np.interp(values, v, c[:, k]) for k in range(3)], axis=-1)

    def ticks(self):
        return sorted({float(s[0]) for s in self.stops})


@dataclass(frozen=True)
class OpacityBar:
    """An opacity transfer function: ``points`` are ``(value, opacity)``; shown over ``span`` (default: around them)."""

    label: str
    points: tuple
    unit: str = ""
    span: tuple = None

    def __post_init__(self):
        _ascending([p[0] for p in self.points], f"legend {self.label}")

    @property
    def range(self):
        if self.span is not None:
            return float(self.span[0]), float(self.span[1])
        v = [float(p[0]) for p in self.points]
        if 0.0 <= v[0] and v[-1] <= 1.0:  # fractions (cloudiness): the whole 0..1
            return 0.0, 1.0
        pad = 0.25 * (v[-1] - v[0]) or max(abs(v[0]), 1.0) * 0.25
        return v[0] - pad, v[-1] + pad

    def opacities(self, values):
        v = np.array([p[0] for p in self.points], np.float64)
        o = np.array([p[1] for p in self.points], np.float64)
        return np.interp(values, v, o)

    def grey(self, values):
        """Grey level shown for ``values``: the opacity relative to the largest one (at least 1)."""
        top = max(1.0, max(float(p[1]) for p in self.points))
        return np.clip(self.opacities(values) / top, 0.0, 1.0)

    def ticks(self):
        lo, hi = self.range
        return sorted({float(p[0]) for p in self.points if lo <= p[0] <= hi} | {lo, hi})


@dataclass(frozen=True)
class Swatch:
    """A constant colour (the paper's constant-colour smoke), linear RGB."""

    label: str
    color: tuple


def bar_values(entry, width):
    """The value at each pixel centre of a bar ``width`` pixels wide."""
    lo, hi = entry.range
    return lo + (np.arange(width) + 0.5) / width * (hi - lo)


def bar_pixels(entry, width):
    """``(width, 3)`` sRGB-encoded colours of an entry's bar, left to right."""
    if isinstance(entry, ColorBar):
        return srgb_encode(entry.colors(bar_values(entry, width))).astype(np.float32)
    if isinstance(entry, OpacityBar):
        g = entry.grey(bar_values(entry, width)).astype(np.float32)
        return np.repeat(g[:, None], 3, axis=1)
    return np.tile(srgb_encode(entry.color[:3]).astype(np.float32), (width, 1))


def _tick_text(value):
    return f"{value:.5g}"


def _label(entry):
    return entry.label + (f" ({entry.unit})" if getattr(entry, "unit", "") else "")


def legend_size(entries, size, text=None):
    """``(width, height, bar_width, bar_height)`` in pixels of :func:`legend_image`'s panel for text ``size``.

    With the rasteriser ``text`` the panel is also wide enough for the longest label."""
    pad, lh = max(2, size // 2), line_height(size)
    bw, bh = 10 * size, max(4, int(round(0.8 * size)))
    rows = sum(lh + bh + (lh if not isinstance(e, Swatch) else 0) + pad for e in entries)
    labels = max((text(_label(e), size).shape[1] for e in entries), default=0) if text else 0
    return max(bw, labels) + 2 * pad, rows + pad, bw, bh


def legend_image(entries, text, size=12):
    """A legend panel of ``entries`` as an RGBA image (straight alpha, sRGB-encoded).

    Each entry: its label (and unit), the bar, and the values at its ends and
    control points beneath (a value that would overlap the previous one is
    left out).  ``text`` is the rasteriser (:mod:`.canvas`), ``size`` the
    label size in pixels.
    """
    entries = list(entries)
    if not entries:
        return new_canvas(0, 0)
    w, h, bw, bh = legend_size(entries, size, text)
    canvas = new_canvas(w, h)
    pad, lh, small = max(2, size // 2), line_height(size), max(8, int(round(0.85 * size)))
    fill(canvas, 0, 0, w, h, PANEL)
    cy = pad
    for e in entries:
        draw_text(canvas, text, _label(e), size, pad, cy, outline=False)
        cy += lh
        canvas[cy : cy + bh, pad : pad + bw, :3] = bar_pixels(e, bw)[None, :, :]
        canvas[cy : cy + bh, pad : pad + bw, 3] = 1.0
        cy += bh
        if not isinstance(e, Swatch):
            lo, hi = e.range
            right_edge = -1e9
            for v in e.ticks():
                tx = pad + (v - lo) / (hi - lo) * bw if hi > lo else pad
                mask_w = text(_tick_text(v), small).shape[1]
                left = min(max(tx - mask_w / 2, pad), pad + bw - mask_w)
                if left < right_edge + small // 2:
                    continue
                tick = max(2, bh // 3)
                fill(canvas, min(tx, pad + bw - 1), cy, min(tx, pad + bw - 1) + 1, cy + tick, (1.0, 1.0, 1.0, 0.9))
                draw_text(canvas, text, _tick_text(v), small, int(left), cy + tick - 1, outline=False)
                right_edge = left + mask_w
            cy += lh
        cy += pad
    return canvas


__all__ = ["ColorBar", "OpacityBar", "Swatch", "bar_pixels", "bar_values", "legend_image",
           "legend_size"]
