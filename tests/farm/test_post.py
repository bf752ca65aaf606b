"""Post-processing against independent truth: Blender's own PNG, pixel bookkeeping, ffmpeg's decoder."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.farm import cli, post  # noqa: E402

SCENE = Path(__file__).with_name("cube_scene.py")


def load_cube():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    spec = importlib.util.spec_from_file_location("cube_scene_post", SCENE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.build(engine="CYCLES", size=(40, 30))
    scene = bpy.context.scene
    scene.cycles.samples = 4
    scene.render.dither_intensity = 0.0
    return scene


def save(scene, path, fmt, view):
    scene.view_settings.view_transform = view
    im = scene.render.image_settings
    im.file_format = fmt
    if fmt == "PNG":
        im.color_depth = "8"
    bpy.data.images["Render Result"].save_render(str(path), scene=scene)
    return path


@pytest.mark.parametrize("view", ["Standard", "AgX"])
def test_exr_to_png_matches_blenders_png(tmp_path, view):
    """The same render saved by Blender as PNG and as EXR (converted by us) agree to 8-bit rounding."""
    scene = load_cube()
    scene.frame_set(30)
    bpy.ops.render.render()
    png = save(scene, tmp_path / "blender.png", "PNG", view)
    exr = save(scene, tmp_path / "linear.exr", "OPEN_EXR", view)
    ours = post.exr_to_png(exr, tmp_path / "ours.png", view=view)
    a, b = post.read_rgba(png), post.read_rgba(ours)
    assert a.shape == b.shape == (30, 40, 4)
    assert a[..., :3].std() > 0.02  # a real picture, not a flat field
    assert np.abs(a - b).max() <= 2.5 / 255


def solid(path, color, size=(12, 8)):
    px = np.zeros((size[1], size[0], 4), np.float32)
    px[..., :3] = color
    px[..., 3] = 1.0
    return post.write_image(path, px)


def test_side_by_side_and_anaglyph(tmp_path):
    rng = np.random.default_rng(1)
    left = np.concatenate([rng.random((8, 12, 3)), np.ones((8, 12, 1))], axis=2)
    right = np.concatenate([rng.random((8, 12, 3)), np.ones((8, 12, 1))], axis=2)
    lp = post.write_image(tmp_path / "L.png", left)
    rp = post.write_image(tmp_path / "R.png", right)
    L, R = post.read_rgba(lp), post.read_rgba(rp)
    sbs = post.read_rgba(post.side_by_side(lp, rp, tmp_path / "sbs.png"))
    assert sbs.shape == (8, 24, 4)
    assert np.array_equal(sbs[:, :12], L) and np.array_equal(sbs[:, 12:], R)
    ana = post.read_rgba(post.anaglyph(lp, rp, tmp_path / "ana.png"))
    assert np.array_equal(ana[..., 0], L[..., 0]) and np.array_equal(ana[..., 1:3], R[..., 1:3])
    # Half colour: red is the left eye's Rec. 709 grey (to 8-bit rounding), cyan the right eye's colour.
    half = post.read_rgba(post.anaglyph(lp, rp, tmp_path / "half.png", "half"))
    grey = L[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    assert np.abs(half[..., 0] - grey).max() <= 0.5 / 255 + 1e-6 and np.array_equal(half[..., 1:3], R[..., 1:3])
    small = solid(tmp_path / "small.png", (1, 0, 0), size=(6, 8))
    with pytest.raises(post.DataError, match="differ in size"):
        post.side_by_side(lp, small, tmp_path / "x.png")


def test_contact_sheet_layout(tmp_path):
    colors = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1)]
    paths = [solid(tmp_path / f"frame_{i + 1:04d}.png", c, size=(20, 10)) for i, c in enumerate(colors)]
    out = post.contact_sheet(paths, tmp_path / "sheet.png", columns=3, thumb_width=20, gap=4, labels=[])
    sheet = post.read_rgba(out)
    assert sheet.shape == (2 * 10 + 3 * 4, 3 * 20 + 4 * 4, 4)
    for i, c in enumerate(colors):
        r, k = divmod(i, 3)
        y, x = 4 + r * 14, 4 + k * 24
        assert np.allclose(sheet[y + 2 : y + 8, x + 2 : x + 18, :3], c, atol=1 / 255), i
    assert np.allclose(sheet[18:26, 52:76, :3], 0.08, atol=1 / 255)  # the empty sixth cell
    # Via the command line, a directory gives its frames in order, labels drawn.
    rc = cli.main(["post", "contact-sheet", str(tmp_path), "--out", str(tmp_path / "cli.png"), "--columns", "5"])
    assert rc == 0 and post.read_rgba(tmp_path / "cli.png").shape[:2] == (10 + 8, 5 * 20 + 6 * 4)


def test_movie_h264_round_trip(tmp_path):
    import imageio_ffmpeg

    colors = [(v, 1 - v, 0.5) for v in np.linspace(0, 1, 10)]
    paths = [solid(tmp_path / f"frame_{i:04d}.png", c, size=(33, 25)) for i, c in enumerate(colors)]
    out = post.movie(paths, tmp_path / "film.mp4", fps=12)
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8).reshape(meta["size"][1], meta["size"][0], 3) for f in reader]
    assert meta["codec"] == "h264" and meta["size"] == (34, 26) and meta["fps"] == 12
    assert len(frames) == 10
    for f, c in zip(frames, colors):
        assert np.abs(f[4:20, 4:28] / 255.0 - c).max() < 0.04  # yuv420p, crf 18


def test_post_bad_input(tmp_path, capsys):
    rc = cli.main(["post", "movie", str(tmp_path / "nothing"), "--out", str(tmp_path / "m.mp4")])
    assert rc == 2 and "no such file" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    rc = cli.main(["post", "contact-sheet", str(tmp_path / "empty"), "--out", str(tmp_path / "s.png")])
    assert rc == 2 and "no frame_" in capsys.readouterr().err


def test_post_cli_exr2png_and_stereo(tmp_path, capsys):
    rng = np.random.default_rng(3)
    lin = np.concatenate([rng.random((6, 10, 3)) * 0.8, np.ones((6, 10, 1))], axis=2)
    (tmp_path / "exr").mkdir()
    post.write_image(tmp_path / "exr" / "frame_0001.exr", lin)
    rc = cli.main(["post", "exr2png", str(tmp_path / "exr"), "--out", str(tmp_path / "png")])
    assert rc == 0
    png = post.read_rgba(tmp_path / "png" / "frame_0001.png")
    # The sRGB transfer function, written out (IEC 61966-2-1), on half-float input, to 8 bits.
    x = lin[..., :3].astype(np.float16).astype(np.float64)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    assert np.abs(png[..., :3] - srgb).max() <= 0.6 / 255

    for eye in ("left", "right"):
        (tmp_path / eye).mkdir()
        for f in (1, 2):
            solid(tmp_path / eye / f"frame_{f:04d}.png", (1.0, 0.0, 0.0) if eye == "left" else (0.0, 1.0, 1.0))
    rc = cli.main(["post", "stereo", str(tmp_path / "left"), str(tmp_path / "right"), "--out", str(tmp_path / "st")])
    assert rc == 0
    names = sorted(p.name for p in (tmp_path / "st").iterdir())
    assert names == ["anaglyph_frame_0001.png", "anaglyph_frame_0002.png", "sbs_frame_0001.png", "sbs_frame_0002.png"]
    ana = post.read_rgba(tmp_path / "st" / "anaglyph_frame_0002.png")
    assert np.allclose(ana[..., :3], 1.0)  # red from the left eye + cyan from the right eye = white
    rc = cli.main(["post", "stereo", str(tmp_path / "left"), str(tmp_path / "right"), "--out", str(tmp_path / "grey"),
                   "--anaglyph-mode", "grey"])
    ana = post.read_rgba(tmp_path / "grey" / "anaglyph_frame_0001.png")
    # Grey: pure red on the left is 0.2126 grey in red; pure cyan on the right 0.7874 in green and blue.
    assert rc == 0 and np.allclose(ana[..., :3], [0.2126, 0.7874, 0.7874], atol=0.5 / 255 + 1e-6)
    capsys.readouterr()
