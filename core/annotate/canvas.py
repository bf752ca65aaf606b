"""Drawing on float RGBA canvases: text masks, boxes, compositing, sRGB.

Canvases are ``(h, w, 4)`` float32 arrays, rows top-down, colour
display-referred (sRGB-encoded) 0..1 with *straight* alpha, which is what a
PNG holds and what Blender's compositor reads from an sRGB image.

Text comes from a rasteriser passed in: ``text(string, size) -> (h, w)``
float alpha mask, ``h`` the same for every string of one ``size`` (pixels
per em) so that lines line up.  :func:`nephele.fileio.text_mask` draws with
Blender's own font engine (``blf``); :func:`box_text` is a stand-in of
plain boxes for tests and for environments without Blender.
"""

import numpy as np

PANEL = (0.05, 0.06, 0.08, 1.0)
"""Colour of the boxes behind text and legends.  Opaque: a translucent box over a bright, high dynamic range
picture (a compositor works in scene-linear light, before the view transform) hardly darkens it."""


def srgb_encode(linear):
    """Linear RGB 0..1 → sRGB-encoded (IEC 61966-2-1)."""
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def srgb_decode(encoded):
    """sRGB-encoded 0..1 → linear RGB."""
    c = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, np.power((c + 0.055) / 1.055, 2.4))


def new_canvas(width, height):
    """A transparent ``(height, width, 4)`` canvas."""
    return np.zeros((int(height), int(width), 4), np.float32)


def line_height(size):
    """Height of one text line of ``size`` pixels per em (what a rasteriser returns)."""
    return int(round(1.3 * size))


def box_text(string, size):
    """A rasteriser of boxes: one ``0.6 size`` wide block per visible character (tests, no Blender)."""
    h = line_height(size)
    cw = max(1, int(round(0.6 * size)))
    mask = np.zeros((h, max(1, cw * len(string))), np.float32)
    top, bottom = int(round(0.25 * size)), h - int(round(0.3 * size))
    for i, ch in enumerate(string):
        if not ch.isspace():
            mask[top:bottom, i * cw + 1 : (i + 1) * cw - 1] = 1.0
    return mask


def fill(canvas, x0, y0, x1, y1, rgba):
    """Composite a solid ``rgba`` rectangle over ``canvas`` (straight alpha), clipped to it."""
    h, w = canvas.shape[:2]
    x0, x1 = max(0, int(x0)), min(w, int(x1))
    y0, y1 = max(0, int(y0)), min(h, int(y1))
    if x1 <= x0 or y1 <= y0:
        return canvas
    src = np.broadcast_to(np.asarray(rgba, np.float32), (y1 - y0, x1 - x0, 4))
    canvas[y0:y1, x0:x1] = over_rgba(src, canvas[y0:y1, x0:x1])
    return canvas


def over_rgba(top, bottom):
    """``top`` over ``bottom``, both straight-alpha RGBA (Porter-Duff over)."""
    ta, ba = top[..., 3:4], bottom[..., 3:4]
    a = ta + ba * (1.0 - ta)
    rgb = top[..., :3] * ta + bottom[..., :3] * ba * (1.0 - ta)
    rgb = np.divide(rgb, a, out=np.zeros_like(rgb), where=a > 0)
    return np.concatenate([rgb, a], axis=-1).astype(np.float32)


def paint(canvas, mask, x, y, rgb, opacity=1.0):
    """Paint colour ``rgb`` through alpha ``mask`` with its top-left corner at ``(x, y)``; clipped to the canvas."""
    h, w = canvas.shape[:2]
    mh, mw = mask.shape
    x, y = int(x), int(y)
    cx0, cy0 = max(0, -x), max(0, -y)
    cx1, cy1 = min(mw, w - x), min(mh, h - y)
    if cx1 <= cx0 or cy1 <= cy0:
        return canvas
    m = mask[cy0:cy1, cx0:cx1, None] * float(opacity)
    src = np.concatenate([np.broadcast_to(np.asarray(rgb, np.float32), m.shape[:2] + (3,)), m], axis=-1)
    region = canvas[y + cy0 : y + cy1, x + cx0 : x + cx1]
    canvas[y + cy0 : y + cy1, x + cx0 : x + cx1] = over_rgba(src, region)
    return canvas


def halo(mask, radius=1):
    """``mask`` grown by ``radius`` pixels (a maximum filter): a dark outline keeps text readable on any picture."""
    r = int(radius)
    out = np.pad(mask, r)
    grown = out.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx or dy:
                grown = np.maximum(grown, np.roll(np.roll(out, dy, 0), dx, 1))
    return grown


def draw_text(canvas, text, string, size, x, y, rgb=(1.0, 1.0, 1.0), outline=True, anchor="left"):
    """Draw ``string`` with its line box's top at ``y``; ``x`` is its left edge, centre or right edge by ``anchor``.

    ``outline`` adds a translucent dark halo.  Returns the text's width in pixels.
    """
    if not string:
        return 0
    mask = text(string, size)
    mw = mask.shape[1]
    left = x if anchor == "left" else x - mw // 2 if anchor == "center" else x - mw
    if outline:
        r = max(1, int(round(size / 12)))
        paint(canvas, halo(mask, r), left - r, y - r, (0.0, 0.0, 0.0), 0.75)
    paint(canvas, mask, left, y, rgb)
    return mw


def paste(canvas, image, x, y):
    """Composite the RGBA ``image`` over ``canvas`` with its top-left corner at ``(x, y)``; clipped to the canvas."""
    h, w = canvas.shape[:2]
    ih, iw = image.shape[:2]
    x, y = int(x), int(y)
    cx0, cy0 = max(0, -x), max(0, -y)
    cx1, cy1 = min(iw, w - x), min(ih, h - y)
    if cx1 > cx0 and cy1 > cy0:
        region = canvas[y + cy0 : y + cy1, x + cx0 : x + cx1]
        canvas[y + cy0 : y + cy1, x + cx0 : x + cx1] = over_rgba(image[cy0:cy1, cx0:cx1], region)
    return canvas


def over_rgb(rgb, overlay):
    """A straight-alpha RGBA ``overlay`` composited over an opaque ``(h, w, 3)`` picture (same colour encoding)."""
    a = overlay[..., 3:4]
    return (overlay[..., :3] * a + np.asarray(rgb, np.float32)[..., :3] * (1.0 - a)).astype(np.float32)


__all__ = ["PANEL", "box_text", "draw_text", "fill", "halo", "line_height", "new_canvas", "over_rgb", "over_rgba",
           "paint", "paste",
           "srgb_decode", "srgb_encode"]
