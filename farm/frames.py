"""Frame numbers, frame file names, and a light check that a frame file is whole.

No bpy and no Dask here: the client process uses these to plan a run and to
decide, on resume, which frames are already done.

What "valid" means
------------------
* **Right after a render** (in the worker, see :mod:`.worker`) a frame is
  valid when OpenImageIO decodes every pixel, the size is the one the scene
  asks for, *and* :func:`check_image` below accepts the file.  Only then is it
  moved into place with :func:`os.replace`.
* **On resume** (in the client) a frame is valid when the manifest lists it as
  ``ok`` and the file's size and ``st_mtime_ns`` are those recorded: one
  ``stat`` per frame, no decoding (240 frames in a few ms).  A frame not in the
  manifest, or whose size/mtime changed, is checked with :func:`check_image`;
  ``verify=True`` (``--verify``) also re-hashes every file against the
  manifest's sha256, for bit rot that keeps size and mtime.
"""

import hashlib
import re
import struct
import zlib
from pathlib import Path

from ..core.errors import UsageError

FORMATS = {"PNG": ".png", "EXR": ".exr"}
PREFIX = "frame_"
TMP_DIR = ".nephele-tmp"
"""Frames are rendered here (same file system as the output) and moved out when valid."""


class InvalidFrame(ValueError):
    """A frame file that is empty, truncated or does not decode."""


def parse_frames(text):
    """Frame numbers from ``"1-240"``, ``"1-240x2"`` (step), ``"7"`` or ``"1,5,10-12"``.

    Returns a sorted list without duplicates.  Frames are non-negative integers.

    Raises
    ------
    UsageError
        When the text is not a frame list.
    """
    if isinstance(text, int):
        text = str(text)
    if not isinstance(text, str):
        frames = sorted({int(f) for f in text})
        if not frames or frames[0] < 0:
            raise UsageError(f"frames must be a non-empty list of non-negative integers, got {text!r}")
        return frames
    frames = set()
    for part in text.replace(" ", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+)(?:x(\d+))?)?", part)
        if not m:
            raise UsageError(f"cannot read frame range {text!r}: expected e.g. 1-240, 1-240x2 or 1,5,9-12")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        step = int(m.group(3)) if m.group(3) else 1
        if b < a or step < 1:
            raise UsageError(f"cannot read frame range {part!r}: end before start or step < 1")
        frames.update(range(a, b + 1, step))
    return sorted(frames)


def format_frames(frames):
    """Compact text for a frame list: ``[1, 2, 3, 7]`` → ``"1-3,7"``."""
    frames = sorted(frames)
    parts, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        parts.append(str(frames[i]) if i == j else f"{frames[i]}-{frames[j]}")
        i = j + 1
    return ",".join(parts)


def chunks(frames, size):
    """Split ``frames`` into consecutive lists of at most ``size`` frames."""
    if size < 1:
        raise UsageError(f"chunk size must be >= 1, got {size}")
    return [list(frames[i : i + size]) for i in range(0, len(frames), size)]


def frame_name(frame, fmt="PNG", view=""):
    """``frame_0001.png``: zero-padded to 4 digits (more when needed); ``view="_L"`` gives ``frame_0001_L.png``.

    ``view`` is a multi-view file suffix (Blender's ``_L`` / ``_R`` for stereo), ``""`` for one view.
    """
    return f"{PREFIX}{frame:04d}{view}{FORMATS[fmt]}"


def sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def check_png(data):
    """``(width, height)`` of a whole PNG; raises :class:`InvalidFrame` otherwise.

    Walks every chunk (checking its CRC), requires IHDR first and IEND last,
    and inflates the image data to its full expected length, so truncated or
    bit-flipped files are caught without un-filtering the pixels.
    """
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise InvalidFrame("not a PNG file")
    pos, idat, ihdr, end = 8, [], None, False
    while pos + 12 <= len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + n]
        if pos + 12 + n > len(data):
            raise InvalidFrame(f"chunk {kind!r} truncated")
        (crc,) = struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])
        if zlib.crc32(kind + body) != crc:
            raise InvalidFrame(f"CRC error in chunk {kind!r}")
        if ihdr is None and kind != b"IHDR":
            raise InvalidFrame("IHDR is not the first chunk")
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            end = True
            break
        pos += 12 + n
    if not end:
        raise InvalidFrame("no IEND chunk (truncated)")
    width, height, depth, color, _, _, interlace = ihdr
    if width == 0 or height == 0 or color not in _PNG_CHANNELS:
        raise InvalidFrame(f"bad header {width}x{height} colour type {color}")
    try:
        d = zlib.decompressobj()
        raw = d.decompress(b"".join(idat))
        if not d.eof:
            raise InvalidFrame("image data stream is cut short")
    except zlib.error as exc:
        raise InvalidFrame(f"image data does not inflate: {exc}") from None
    if not interlace:
        row = (width * _PNG_CHANNELS[color] * depth + 7) // 8
        if len(raw) != height * (row + 1):
            raise InvalidFrame(f"image data has {len(raw)} bytes, expected {height * (row + 1)}")
    return width, height


# Scanlines per chunk for each EXR compression (OpenEXR file layout).
_EXR_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def check_exr(data):
    """``(width, height)`` of a whole single-part scanline OpenEXR file; raises :class:`InvalidFrame`.

    Reads the header and the line-offset table and checks that every chunk
    lies inside the file (a truncated file fails).  Tiled, deep and multi-part
    files only get the header check; the worker's OpenImageIO decode covers them.
    """
    if data[:4] != b"\x76\x2f\x31\x01":
        raise InvalidFrame("not an OpenEXR file")
    (flags,) = struct.unpack("<I", data[4:8])
    pos, attrs = 8, {}
    try:
        while data[pos] != 0:
            name_end = data.index(b"\0", pos)
            type_end = data.index(b"\0", name_end + 1)
            (size,) = struct.unpack("<i", data[type_end + 1 : type_end + 5])
            name = data[pos:name_end].decode("latin-1")
            attrs[name] = data[type_end + 5 : type_end + 5 + size]
            pos = type_end + 5 + size
    except (IndexError, ValueError, struct.error):
        raise InvalidFrame("OpenEXR header is truncated") from None
    pos += 1
    if "dataWindow" not in attrs or "compression" not in attrs:
        raise InvalidFrame("OpenEXR header lacks dataWindow or compression")
    x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
    width, height = x1 - x0 + 1, y1 - y0 + 1
    if width < 1 or height < 1:
        raise InvalidFrame(f"bad data window {width}x{height}")
    if flags & 0x3200:  # tiled, deep or multi-part
        return width, height
    lines = _EXR_LINES.get(attrs["compression"][0])
    if lines is None:
        raise InvalidFrame(f"unknown OpenEXR compression {attrs['compression'][0]}")
    n = -(-height // lines)
    table = data[pos : pos + 8 * n]
    if len(table) != 8 * n:
        raise InvalidFrame("OpenEXR offset table is truncated")
    for off in struct.unpack(f"<{n}Q", table):
        if off + 8 > len(data):
            raise InvalidFrame("OpenEXR chunk lies past the end of the file (truncated)")
        (size,) = struct.unpack("<i", data[off + 4 : off + 8])
        if size < 0 or off + 8 + size > len(data):
            raise InvalidFrame("OpenEXR chunk lies past the end of the file (truncated)")
    return width, height


def check_image(path):
    """``(width, height)`` when ``path`` is a whole PNG or EXR frame; raises :class:`InvalidFrame`."""
    path = Path(path)
    data = path.read_bytes()
    if not data:
        raise InvalidFrame("empty file (a placeholder)")
    if path.suffix.lower() == ".exr":
        return check_exr(data)
    return check_png(data)
