"""Red-cyan anaglyphs: one picture of a stereo pair for red (left) / cyan (right) glasses.

The red filter passes the left eye's image, the cyan filter the right eye's,
so the anaglyph takes its red channel from the left view and its green and
blue channels from the right view.  Three ways of filling them:

``"colour"``
    Red from the left view's red, green and blue from the right view's:
    full colour, but a saturated blue or red object is seen by one eye only
    (retinal rivalry), which spoils the depth of the muscle film's blue heads.
``"half"``
    Red from the left view's grey, green and blue from the right view's
    colour: every object reaches both eyes, the colours are kept in cyan.
``"grey"``
    Red from the left view's grey, green and blue from the right view's grey:
    no colour, no rivalry, the clearest depth.

Grey is the Rec. 709 luma ``0.2126 R + 0.7152 G + 0.0722 B`` of the values
as given (display-referred PNG values, as rendered; no linearisation), the
weighting of ITU-R BT.709 and of Blender's own RGB-to-BW node.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (the muscle film, Fig. 7, in stereo).
.. [2] ITU-R Recommendation BT.709-6, item 3.2 (luma weights).
"""

import numpy as np

from ..errors import DataError

LUMA = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luma weights of R, G, B."""

MODES = ("colour", "half", "grey")


def grey(rgb):
    """Rec. 709 luma ``(..., )`` of ``(..., 3)`` (or more channels: the first three are used) values."""
    rgb = np.asarray(rgb)
    return rgb[..., 0] * LUMA[0] + rgb[..., 1] * LUMA[1] + rgb[..., 2] * LUMA[2]


def red_cyan(left, right, mode="half"):
    """Red-cyan anaglyph of a stereo pair.

    Parameters
    ----------
    left, right : (h, w, c) array_like, c = 3 or 4
        The left and right eye's images (display values; alpha, if any, is
        taken from the left view, NaN is passed through).
    mode : {"colour", "half", "grey"}
        How the channels are filled (see the module notes): red from the left
        view's red or grey, green and blue from the right view's colour or grey.

    Returns
    -------
    (h, w, c) float array: red from the left eye, green and blue from the right.
    """
    if mode not in MODES:
        raise DataError(f"anaglyph mode must be one of {', '.join(MODES)}, got {mode!r}", field="mode")
    a = np.asarray(left)
    a = a.astype(a.dtype if a.dtype.kind == "f" else np.float64, copy=False)  # floats kept, integers as float64
    b = np.asarray(right, dtype=a.dtype)
    if a.ndim != 3 or a.shape[2] not in (3, 4):
        raise DataError(f"left view must be (h, w, 3 or 4), got shape {a.shape}", field="left")
    if b.shape != a.shape:
        raise DataError(f"left and right views differ in shape: {a.shape} vs {b.shape}", field="right")
    out = a.copy()
    out[..., 0] = a[..., 0] if mode == "colour" else grey(a)
    if mode == "grey":
        out[..., 1] = out[..., 2] = grey(b)
    else:
        out[..., 1:3] = b[..., 1:3]
    return out
