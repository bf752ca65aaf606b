"""Where annotations go on a frame, and the title cards of a film.

:func:`overlay` lays out a frame's annotation layer (the figure's number and
caption top left, the model date and time top right, the legend bottom
left), sized from the frame's height so a 480x270 preview and a 1920x1080
frame read alike.  :func:`title_card` is the card each segment of a film
opens with.  Both draw text with a rasteriser passed in (:mod:`.canvas`).
"""

import numpy as np

from .canvas import PANEL, draw_text, fill, line_height, new_canvas, paste, srgb_encode
from .legend import legend_image, legend_size

FIGURES = {
    "fig1": ("Fig. 1", "Contour surfaces of 15% cloudiness"),
    "fig2": ("Fig. 2", "Volume rendered clouds"),
    "fig3": ("Fig. 3", "Clouds and wind velocity by hardware texture mapping"),
    "fig4": ("Fig. 4", "Clouds of fig. 1 with transparency texture"),
    "fig5": ("Fig. 5", "Simulated smoke in global air circulation"),
    "fig6": ("Fig. 6", "Multiple scattering of light inside a cloud"),
    "fig7": ("Fig. 7", "Muscle cross-bridges in motion during contraction"),
    "dome": ("Dome", "The Fig. 1 globe counter-distorted for a dome"),
}
"""Figure key → (number, caption): the captions of Max & Crawfis (Fig. 1's typo "Countour" mended)."""

REFERENCE = "N. Max and R. Crawfis, Advances in Scientific Visualization"


def heading(key):
    """``"Fig. 1  Contour surfaces of 15% cloudiness"`` for a key of :data:`FIGURES` (the key itself if unknown)."""
    number, caption = FIGURES.get(key, (key, ""))
    return f"{number}  {caption}".strip()


def font_size(height):
    """Text size in pixels for a frame ``height`` pixels tall: 1/24 of it, at least 11."""
    return max(11, int(round(height / 24)))


def overlay(width, height, text, *, heading=None, time_text=None, note=None, legend=()):
    """The annotation layer of one frame: a ``(height, width, 4)`` RGBA canvas (straight alpha, sRGB-encoded).

    Parameters
    ----------
    width, height : int
        The frame's size in pixels.
    text : callable
        The rasteriser, ``text(string, size) -> (h, w)`` alpha mask.
    heading : str, optional
        Top left, e.g. ``"Fig. 1  Contour surfaces of 15% cloudiness"``.
    time_text, note : str, optional
        Top right: the model date and time, and beneath it a smaller note (the calendar).
    legend : sequence of legend entries
        :class:`~.legend.ColorBar`, :class:`~.legend.OpacityBar`, :class:`~.legend.Swatch`; bottom left.
    """
    canvas = new_canvas(width, height)
    size = font_size(height)
    pad = max(4, size // 2)
    big = int(round(1.25 * size))
    used = text(time_text, big).shape[1] + 2 * pad if time_text else 0
    if heading:
        room = width - used - 2 * pad
        s = _fitting(text, heading, size, room)
        line = _elided(text, heading, s, room)
        if line:
            _backed(canvas, text, line, s, pad, pad)
    if time_text:
        _backed(canvas, text, time_text, big, width - pad, pad, anchor="right")
        if note:
            _backed(canvas, text, note, max(9, int(round(0.8 * size))), width - pad, pad + line_height(big),
                    anchor="right")
    legend = list(legend or ())
    small = max(7, int(round(0.8 * size)))
    while legend and small > 7 and legend_size(legend, small)[1] > 0.45 * height:
        small -= 1  # a tiny frame: a smaller legend, at most 45% of the height
    if legend and legend_size(legend, small)[1] <= 0.45 * height:
        img = legend_image(legend, text, small)
        paste(canvas, img, pad, height - pad - img.shape[0])
    return canvas


def _backed(canvas, text, string, size, x, y, anchor="left"):
    """Text on a dark box (:data:`.canvas.PANEL`): readable over bright clouds and molecules alike."""
    w = text(string, size).shape[1]
    left = x if anchor == "left" else x - w
    m = max(2, size // 5)
    fill(canvas, left - m, y - m // 2, left + w + m, y + line_height(size) + m // 2, PANEL)
    draw_text(canvas, text, string, size, x, y, anchor=anchor, outline=False)


def _fitting(text, string, size, width, smallest=9):
    """The largest size not above ``size`` (and not below ``smallest``) at which ``string`` fits in ``width`` pixels."""
    while size > smallest and text(string, size).shape[1] > width:
        size = max(smallest, int(size * 0.9))
    return size


def _elided(text, string, size, width):
    """``string``, cut with an ellipsis where it is wider than ``width`` pixels (``""`` if nothing fits)."""
    if text(string, size).shape[1] <= width:
        return string
    words = string.split()
    while words:
        words.pop()
        line = " ".join(words) + " …"
        if words and text(line, size).shape[1] <= width:
            return line
    return ""


def title_card(width, height, text, *, number, caption, lines=()):
    """A title card: ``number`` large, ``caption`` beneath, then smaller ``lines``; ``(height, width, 3)`` sRGB."""
    top = srgb_encode((0.004, 0.008, 0.02))
    bottom = srgb_encode((0.02, 0.035, 0.07))
    t = np.linspace(0.0, 1.0, int(height))[:, None, None]
    canvas = new_canvas(width, height)
    canvas[..., :3] = (top * (1 - t) + bottom * t).astype(np.float32)
    canvas[..., 3] = 1.0
    usable = int(0.9 * width)
    big = _fitting(text, number, max(12, height // 8), usable)
    mid = _fitting(text, caption, max(10, height // 18), usable)
    small = max(11, height // 30)
    y = int(0.30 * height)
    draw_text(canvas, text, number, big, width // 2, y, anchor="center", outline=False)
    y += line_height(big) + height // 40
    draw_text(canvas, text, caption, mid, width // 2, y, rgb=(0.92, 0.94, 1.0), anchor="center", outline=False)
    y += line_height(mid) + height // 30
    for line in lines:
        s = _fitting(text, line, small, usable)
        draw_text(canvas, text, line, s, width // 2, y, rgb=(0.62, 0.68, 0.78), anchor="center", outline=False)
        y += line_height(s)
    return canvas[..., :3]


__all__ = ["FIGURES", "REFERENCE", "font_size", "heading", "overlay", "title_card"]
