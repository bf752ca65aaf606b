"""Frame ranges, the light PNG/EXR integrity check and resume classification (no bpy, no Dask)."""

import json
import os
import struct
import zlib

import numpy as np
import pytest

from nephele.farm.cli import UsageError
from nephele.farm.frames import (
    InvalidFrame,
    check_exr,
    check_image,
    check_png,
    chunks,
    format_frames,
    frame_name,
    parse_frames,
    sha256_file,
)
from nephele.farm.manifest import Manifest, classify, file_entry


@pytest.mark.parametrize(
    "text, frames",
    [
        ("1-5", [1, 2, 3, 4, 5]),
        ("7", [7]),
        ("0-10x5", [0, 5, 10]),
        ("1,5,9-11", [1, 5, 9, 10, 11]),
        ("3-4,1-3", [1, 2, 3, 4]),
        (" 1 - 3 ", [1, 2, 3]),
        ([4, 2, 2], [2, 4]),
        (12, [12]),
    ],
)
def test_parse_frames(text, frames):
    assert parse_frames(text) == frames


@pytest.mark.parametrize("text", ["", "a-b", "5-1", "1-5x0", "-3", "1-", "1..5", "1-2-3", [], [-1]])
def test_parse_frames_rejects(text):
    with pytest.raises(UsageError):
        parse_frames(text)


def test_format_and_chunks():
    assert format_frames([1, 2, 3, 7, 9, 10]) == "1-3,7,9-10"
    assert format_frames([]) == ""
    assert parse_frames(format_frames([1, 2, 3, 7, 9, 10])) == [1, 2, 3, 7, 9, 10]
    assert chunks([1, 2, 3, 4, 5], 2) == [[1, 2], [3, 4], [5]]
    with pytest.raises(UsageError):
        chunks([1], 0)
    assert frame_name(1) == "frame_0001.png" and frame_name(12345, "EXR") == "frame_12345.exr"


def _chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def make_png(width, height, channels=4, seed=0):
    """An RGBA 8-bit PNG written from first principles (independent of any image library)."""
    color = {1: 0, 3: 2, 4: 6}[channels]
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (height, width, channels), dtype=np.uint8)
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(height))
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, color, 0, 0, 0))
        + _chunk(b"tEXt", b"Software\x00test")
        + _chunk(b"IDAT", zlib.compress(raw)[:40])
        + _chunk(b"IDAT", zlib.compress(raw)[40:])
        + _chunk(b"IEND", b"")
    )


def test_png_whole_and_every_truncation():
    data = make_png(17, 9)
    assert check_png(data) == (17, 9)
    for n in range(len(data)):
        with pytest.raises(InvalidFrame):
            check_png(data[:n])


def test_png_bit_flips_and_wrong_length():
    data = make_png(8, 6, channels=3)
    assert check_png(data) == (8, 6)
    for pos in range(8, len(data), 7):
        bad = bytearray(data)
        bad[pos] ^= 0x10
        with pytest.raises(InvalidFrame):
            check_png(bytes(bad))
    # A consistent file (good CRCs) whose image data is one row short.
    raw = b"".join(b"\x00" + bytes(8 * 3) for _ in range(5))
    short = (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 6, 8, 2, 0, 0, 0))
        + _chunk(b"IDAT", zlib.compress(raw))
        + _chunk(b"IEND", b"")
    )
    with pytest.raises(InvalidFrame, match="expected"):
        check_png(short)


def make_exr(width, height, compression=0):
    """A single-part scanline OpenEXR (one HALF channel 'Y', no compression) from the file-layout spec."""

    def attr(name, kind, value):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    header = (
        b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
        + attr("channels", "chlist", b"Y\0" + struct.pack("<iB3xii", 1, 0, 1, 1) + b"\0")
        + attr("compression", "compression", bytes([compression]))
        + attr("dataWindow", "box2i", struct.pack("<iiii", 0, 0, width - 1, height - 1))
        + attr("displayWindow", "box2i", struct.pack("<iiii", 0, 0, width - 1, height - 1))
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    table_at = len(header)
    first = table_at + 8 * height
    line = np.full(width, 0.5, np.float16).tobytes()
    chunks_ = [struct.pack("<ii", y, len(line)) + line for y in range(height)]
    offsets = [first + i * len(chunks_[0]) for i in range(height)]
    return header + struct.pack(f"<{height}Q", *offsets) + b"".join(chunks_)


def test_exr_whole_and_truncated():
    data = make_exr(5, 4)
    assert check_exr(data) == (5, 4)
    for n in (0, 3, 30, len(data) // 2, len(data) - 1):
        with pytest.raises(InvalidFrame):
            check_exr(data[:n])


def test_check_image_empty_placeholder(tmp_path):
    p = tmp_path / "frame_0001.png"
    p.write_bytes(b"")
    with pytest.raises(InvalidFrame, match="empty"):
        check_image(p)


def test_classify_resume(tmp_path):
    out = tmp_path
    for f in (1, 2, 3, 4, 5):
        (out / frame_name(f)).write_bytes(make_png(6, 4, seed=f))
    m = Manifest(out)
    for f in (1, 2, 3):
        m.set(f, file_entry(out / frame_name(f), seconds=0.1, worker="w"))
    m.save()
    (out / frame_name(4)).write_bytes(b"")  # Blender placeholder
    data = (out / frame_name(5)).read_bytes()
    (out / frame_name(5)).write_bytes(data[:-20])  # truncated
    (out / frame_name(3)).unlink()  # missing
    m = Manifest.load(out)
    done, todo = classify(m, [1, 2, 3, 4, 5, 6], "PNG")
    assert done == [1, 2] and todo == [3, 4, 5, 6]
    assert set(m.frames) == {"1", "2"}

    # A whole frame not in the manifest (an earlier run was interrupted) is adopted.
    (out / frame_name(6)).write_bytes(make_png(6, 4, seed=6))
    done, todo = classify(m, [6], "PNG")
    assert done == [6] and m.entry(6)["sha256"] == sha256_file(out / frame_name(6))

    # Same size and mtime but different bytes: only --verify notices, then the light check decides.
    p = out / frame_name(1)
    st = p.stat()
    bad = bytearray(p.read_bytes())
    bad[40] ^= 0xFF
    p.write_bytes(bytes(bad))
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert classify(m, [1], "PNG") == ([1], [])
    assert classify(m, [1], "PNG", verify=True) == ([], [1])


def test_manifest_atomic_and_tolerant(tmp_path):
    m = Manifest(tmp_path)
    m.run = {"scene": "x"}
    m.set(10, {"status": "ok"})
    m.set(2, {"status": "failed"})
    m.save()
    data = json.loads((tmp_path / "manifest.json").read_text())
    assert list(data["frames"]) == ["2", "10"] and data["run"] == {"scene": "x"}
    assert [p.name for p in tmp_path.iterdir()] == ["manifest.json"]
    (tmp_path / "manifest.json").write_text('{"version": 1, "frames": {"1": ')  # torn by hand
    assert Manifest.load(tmp_path).frames == {}
