"""Post-processing of rendered frames: contact sheet, EXR → PNG, stereo pairs, H.264 movie.

Images are read and written with the OpenImageIO that ships inside the bpy
wheel (importable after ``bpy.utils.expose_bundled_modules()``); movies are
encoded by the ffmpeg binary that imageio-ffmpeg ships (works offline).
Every output is written to a temporary name and moved into place.

Colour: PNG frames are display-referred already and are used as they are.
EXR frames are scene-linear (Rec.709 primaries); they are shown through the
OCIO view ``view`` of Blender's own colour configuration, ``"Standard"``
(plain sRGB transfer) by default, or e.g. ``"AgX"`` (Blender's default view,
what a PNG render of the same scene would show).
"""

import math
import subprocess
from pathlib import Path

import numpy as np

from ..core.camera.anaglyph import red_cyan
from ..core.errors import DataError
from ..core.files import atomic_write
from ..fileio import oiio, write_image

LINEAR = "Linear Rec.709"

# 3x5 bitmap digits for frame labels (OpenImageIO in the bpy wheel has no FreeType).
_DIGITS = {
    "0": "111101101101111", "1": "010110010010111", "2": "111001111100111", "3": "111001111001111",
    "4": "101101111001001", "5": "111100111001111", "6": "111100111101111", "7": "111001001001001",
    "8": "111101111101111", "9": "111101111001111",
}


def read_rgba(path, view="Standard"):
    """``(h, w, 4)`` float32 display values in 0..1, alpha premultiplied, of an image file (EXR through ``view``)."""
    io = oiio()
    path = Path(path)
    if not path.is_file():
        raise DataError("no such image", path=path)
    buf = io.ImageBuf(str(path))
    if buf.has_error or buf.spec().width == 0:
        raise DataError(f"cannot read image: {buf.geterror() or io.geterror()}", path=path)
    spec = buf.spec()
    if spec.format.basetype in (io.HALF, io.FLOAT, io.DOUBLE):
        rgb = io.ImageBufAlgo.channels(buf, (0, 1, 2) if spec.nchannels >= 3 else (0, 0, 0))
        if view == "Standard":
            rgb = io.ImageBufAlgo.colorconvert(rgb, LINEAR, "sRGB")
        else:
            rgb = io.ImageBufAlgo.ociodisplay(rgb, "sRGB", view, LINEAR)
        if rgb.has_error:
            raise DataError(f"colour conversion to view {view!r} failed: {rgb.geterror()}", path=path)
        px = np.asarray(rgb.get_pixels(io.FLOAT))
        alpha = np.asarray(buf.get_pixels(io.FLOAT))[..., 3:4] if spec.nchannels >= 4 else np.ones(px.shape[:2] + (1,))
    else:
        px = np.asarray(buf.get_pixels(io.FLOAT))
        if px.ndim == 2:
            px = px[..., None]
        alpha = px[..., 3:4] if px.shape[2] >= 4 else np.ones(px.shape[:2] + (1,), np.float32)
        px = px[..., :3] if px.shape[2] >= 3 else np.repeat(px[..., :1], 3, axis=2)
    return np.clip(np.concatenate([px, alpha], axis=2), 0.0, 1.0).astype(np.float32)


def _over(rgba, background):
    # OpenImageIO hands out associated (premultiplied) alpha, for PNG as for EXR.
    return rgba[..., :3] + np.asarray(background, np.float32) * (1.0 - rgba[..., 3:4])


def _resize(rgb, width, height):
    io = oiio()
    h, w, _ = rgb.shape
    src = io.ImageBuf(io.ImageSpec(w, h, 3, io.FLOAT))
    src.set_pixels(io.ROI(0, w, 0, h, 0, 1, 0, 3), np.ascontiguousarray(rgb, np.float32))
    dst = io.ImageBufAlgo.resize(src, roi=io.ROI(0, width, 0, height, 0, 1, 0, 3))
    return np.asarray(dst.get_pixels(io.FLOAT))


def _label(canvas, x, y, text, scale=2, color=(1.0, 1.0, 1.0)):
    """Draw digits with a 3x5 bitmap font, bottom-left at (x, y), on a dark backing box."""
    glyphs = [np.array([int(c) for c in _DIGITS[d]], bool).reshape(5, 3) for d in text if d in _DIGITS]
    if not glyphs:
        return
    cols = sum(g.shape[1] + 1 for g in glyphs) - 1
    mask = np.zeros((5, cols), bool)
    cx = 0
    for g in glyphs:
        mask[:, cx : cx + 3] = g
        cx += 4
    mask = np.kron(mask, np.ones((scale, scale), bool))
    mh, mw = mask.shape
    y0, x0 = y - mh, x
    if y0 - 1 < 0 or x0 + mw + 1 > canvas.shape[1]:
        return
    canvas[y0 - 1 : y + 1, x0 - 1 : x0 + mw + 1] *= 0.35
    canvas[y0:y, x0 : x0 + mw][mask] = color


def contact_sheet(paths, out_png, columns=None, thumb_width=None, labels=None, gap=4,
                  background=(0.08, 0.08, 0.08), view="Standard"):
    """Tile frames into one PNG, in the given order, left to right and top to bottom.

    Parameters
    ----------
    paths : list of path
        PNG or EXR frames (EXR shown through ``view``); all thumbnails take the first frame's aspect.
    out_png : path
    columns : int, optional
        Default: ``ceil(sqrt(n))``.
    thumb_width : int, optional
        Thumbnail width in pixels (default: the frame width, at most 256).
    labels : list of str, optional
        Digits drawn in each thumbnail's corner; default: the frame number in each file name.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise DataError("no frames given for the contact sheet")
    first = read_rgba(paths[0], view)
    h0, w0 = first.shape[:2]
    tw = int(thumb_width or min(w0, 256))
    if tw < 1:
        raise DataError(f"thumb width must be >= 1, got {thumb_width}", field="thumb_width")
    th = max(1, round(tw * h0 / w0))
    n = len(paths)
    cols = int(columns or math.ceil(math.sqrt(n)))
    if cols < 1:
        raise DataError(f"columns must be >= 1, got {columns}", field="columns")
    rows = math.ceil(n / cols)
    sheet = np.empty((rows * th + (rows + 1) * gap, cols * tw + (cols + 1) * gap, 3), np.float32)
    sheet[:] = background
    if labels is None:
        labels = ["".join(ch for ch in p.stem if ch.isdigit()).lstrip("0") or "0" for p in paths]
    for i, p in enumerate(paths):
        rgba = first if i == 0 else read_rgba(p, view)
        thumb = _resize(_over(rgba, background), tw, th)
        r, c = divmod(i, cols)
        y, x = gap + r * (th + gap), gap + c * (tw + gap)
        sheet[y : y + th, x : x + tw] = thumb
        if labels and th >= 16:
            _label(sheet, x + 3, y + th - 3, str(labels[i]), scale=2 if th >= 40 else 1)
    return write_image(out_png, sheet)


def exr_to_png(src, dst, view="Standard"):
    """Convert one scene-linear EXR to an 8-bit sRGB PNG through the OCIO view ``view`` (alpha kept)."""
    return write_image(dst, read_rgba(src, view))


def _pair(left, right):
    a, b = read_rgba(left), read_rgba(right)
    if a.shape != b.shape:
        raise DataError(f"left and right views differ in size: {a.shape[1]}x{a.shape[0]} vs {b.shape[1]}x{b.shape[0]}",
                        path=right)
    return a, b


def side_by_side(left, right, out):
    """Left view on the left half, right view on the right half (full resolution each)."""
    a, b = _pair(left, right)
    return write_image(out, np.concatenate([a, b], axis=1))


def anaglyph(left, right, out, mode="colour"):
    """Red-cyan anaglyph (:func:`~nephele.core.camera.anaglyph.red_cyan`): red from the left view,
    green and blue from the right; ``mode`` "colour", "half" or "grey"."""
    a, b = _pair(left, right)
    return write_image(out, red_cyan(a[..., :3], b[..., :3], mode))


def ffmpeg_exe():
    """The ffmpeg binary bundled with imageio-ffmpeg."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def movie(paths, out_mp4, fps=24, crf=18, view="Standard", background=(0.0, 0.0, 0.0)):
    """Encode frames (in the given order) as an H.264 MP4 (yuv420p, plays everywhere), atomically.

    Odd frame sizes are padded by one pixel (H.264 4:2:0 needs even sizes).
    Frames must all have the first frame's size.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise DataError("no frames given for the movie")

    def pictures():
        for p in paths:
            rgba = read_rgba(p, view)
            yield p, np.round(_over(rgba, background) * 255.0).astype(np.uint8)

    return encode(pictures(), out_mp4, fps=fps, crf=crf)


def encode(pictures, out_mp4, fps=24, crf=18, preset="medium"):
    """Encode ``(label, rgb)`` pairs, ``rgb`` an ``(h, w, 3)`` uint8 array, as an H.264 MP4, atomically.

    Every picture must have the first one's size (``label``, a path or a
    name, is what an error message names).  Odd sizes are padded by one pixel
    (H.264 4:2:0 needs even sizes).  Returns the path of the movie.
    """
    if not fps > 0:
        raise DataError(f"fps must be > 0, got {fps}", field="fps")
    out_mp4 = Path(out_mp4)
    out_mp4.parent.mkdir(parents=True, exist_ok=True)
    pictures = iter(pictures)
    try:
        label, rgb = next(pictures)
    except StopIteration:
        raise DataError("no frames given for the movie") from None
    h, w = rgb.shape[:2]
    with atomic_write(out_mp4) as tmp:
        cmd = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
               "-r", str(fps), "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264",
               "-preset", preset, "-crf", str(crf), "-pix_fmt", "yuv420p", "-movflags", "+faststart", str(tmp)]
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            while True:
                if rgb.shape[:2] != (h, w):
                    raise DataError(f"frame size {rgb.shape[1]}x{rgb.shape[0]} differs from the first {w}x{h}",
                                    path=label)
                proc.stdin.write(np.ascontiguousarray(rgb, np.uint8).tobytes())
                try:
                    label, rgb = next(pictures)
                except StopIteration:
                    break
            proc.stdin.close()
            err = proc.stderr.read().decode(errors="replace")
            if proc.wait() != 0:
                raise DataError(f"ffmpeg failed: {err.strip()}", path=out_mp4)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
    return out_mp4
