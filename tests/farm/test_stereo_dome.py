"""Stereo and dome scenes through the farm: both eyes valid and resumable, the EEVEE dome route, post stereo.

Real bpy renders on the shared 2-worker cluster: a Workbench cube in Blender's
stereo 3D (one file per eye) and a dome rig with markers rendered by EEVEE,
which the worker sends through the cube-map route (EEVEE alone would render
the fisheye camera as a perspective view).
"""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from nephele.core.camera import dome  # noqa: E402
from nephele.farm import cli  # noqa: E402
from nephele.farm.frames import check_image, frame_name, sha256_file  # noqa: E402
from nephele.farm.render import render_sequence  # noqa: E402

HERE = Path(__file__).resolve().parent
CUBE = HERE / "cube_scene.py"
DOME = HERE / "dome_scene.py"
EYES = ("_L", "_R")


def pixels(path):
    try:
        import OpenImageIO as oiio
    except ImportError:
        bpy.utils.expose_bundled_modules()
        import OpenImageIO as oiio
    buf = oiio.ImageBuf(str(path))
    px = np.asarray(buf.get_pixels(oiio.FLOAT))
    assert not buf.has_error, buf.geterror()
    return px


def stereo_files(out, frames):
    return sorted(frame_name(f, "PNG", v) for f in frames for v in EYES)


def test_stereo_frames_both_eyes_resume_and_post(farm_cluster, tmp_path):
    out = tmp_path / "out"
    res = render_sequence(CUBE, "1-3", out, scheduler=farm_cluster.scheduler_address, progress=False,
                          scene_options={"stereo": True})
    assert res.ok and res.rendered == [1, 2, 3] and res.views == EYES
    assert sorted(p.name for p in out.iterdir()) == stereo_files(out, range(1, 4)) + ["logs", "manifest.json"]
    assert [p.name for p in res.paths] == stereo_files(out, range(1, 4))
    left, right = pixels(out / "frame_0001_L.png"), pixels(out / "frame_0001_R.png")
    assert left.shape == right.shape == (24, 32, 4)
    assert np.abs(left - right).max() > 0.1  # the eyes see the cube from different places
    assert res.manifest["run"]["views"] == list(EYES)
    for f in (1, 2, 3):
        e = res.manifest["frames"][str(f)]
        assert e["status"] == "ok" and "file" not in e and set(e["views"]) == set(EYES)
        for v in EYES:
            rec = e["views"][v]
            p = out / rec["file"]
            assert rec["file"] == frame_name(f, "PNG", v)
            assert rec["size"] == p.stat().st_size and rec["sha256"] == sha256_file(p)

    # Resume from the recorded views: nothing to do, no cluster needed (the address is dead).
    again = render_sequence(CUBE, "1-3", out, scheduler="tcp://127.0.0.1:9", progress=False,
                            scene_options={"stereo": True})
    assert again.skipped == [1, 2, 3] and again.rendered == []

    # One corrupt right eye, one missing left eye: only those frames are redone, both eyes each.
    kept = {v: (out / frame_name(1, "PNG", v)).stat().st_mtime_ns for v in EYES}
    data = (out / "frame_0002_R.png").read_bytes()
    (out / "frame_0002_R.png").write_bytes(data[: len(data) // 2])
    (out / "frame_0003_L.png").unlink()
    fixed = render_sequence(CUBE, "1-3", out, scheduler=farm_cluster.scheduler_address, progress=False,
                            scene_options={"stereo": True})
    assert fixed.ok and fixed.rendered == [2, 3] and fixed.skipped == [1]
    assert {v: (out / frame_name(1, "PNG", v)).stat().st_mtime_ns for v in EYES} == kept
    assert sorted(p.name for p in out.iterdir()) == stereo_files(out, range(1, 4)) + ["logs", "manifest.json"]
    for name in stereo_files(out, range(1, 4)):
        check_image(out / name)

    # nephele post stereo takes the render's directory and pairs the eyes.
    st = tmp_path / "st"
    assert cli.main(["post", "stereo", str(out), "--out", str(st)]) == 0
    assert sorted(p.name for p in st.iterdir()) == sorted(
        [f"sbs_frame_000{f}.png" for f in (1, 2, 3)] + [f"anaglyph_frame_000{f}.png" for f in (1, 2, 3)])
    sbs = pixels(st / "sbs_frame_0001.png")
    assert sbs.shape[0] == 24 and sbs.shape[1] >= 64
    # A contact sheet of a stereo directory takes one eye; without --eye it says so.
    assert cli.main(["post", "contact-sheet", str(out), "--out", str(tmp_path / "sheet.png")]) == 2
    assert cli.main(["post", "contact-sheet", str(out), "--eye", "L", "--out", str(tmp_path / "sheet.png")]) == 0
    assert (tmp_path / "sheet.png").is_file()
    # A lone eye is a clear error (exit 2), not a silent mismatch.
    (out / "frame_0003_R.png").unlink()
    assert cli.main(["post", "stereo", str(out), "--out", str(tmp_path / "st2")]) == 2


def _centroid(img, colour):
    """Intensity-weighted centroid (col, row) of the pixels of one pure marker colour; None if absent."""
    rgb = img[..., :3]
    mask = np.all((rgb > 0.5) == np.array(colour, bool), axis=-1)
    if not mask.any():
        return None
    w = rgb.sum(-1) * mask
    rr, cc = np.mgrid[: img.shape[0], : img.shape[1]]
    return (w * cc).sum() / w.sum(), (w * rr).sum() / w.sum()


def _dome_scene():
    spec = importlib.util.spec_from_file_location("nephele_test_dome_scene", DOME)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _check_fisheye(img, cam, markers):
    """Empty outside the fisheye circle, sky inside, each marker where the core mapping puts it."""
    rows, cols = np.mgrid[: cam.height, : cam.width]
    r = np.hypot(cols - cam.centre[0], rows - cam.centre[1])
    rgb = img[..., :3]
    # Outside the circle (1.5 px margin for antialiasing) the frame is empty; inside, the grey sky
    # fills it.  A perspective view would be sky everywhere, corners included.
    outside, inside = r > cam.radius + 1.5, r < cam.radius - 1.5
    assert outside.sum() > 0.1 * r.size and rgb[outside].max() < 0.02
    sky = np.median(rgb[inside], axis=0)
    assert np.all(sky > 0.05) and np.abs(sky - sky.mean()).max() < 0.02
    for name, (colour, direction) in markers.items():
        col, row, vis = cam.direction_to_pixel(np.array(direction))
        assert vis
        found = _centroid(img, colour)
        assert found is not None, f"{name} marker missing"
        err = math.hypot(found[0] - col, found[1] - row)
        assert err < 1.5, f"{name}: rendered at {found}, the core mapping says ({col:.2f}, {row:.2f})"


@pytest.mark.parametrize("engine, route", [("BLENDER_WORKBENCH", "cube"), ("CYCLES", "fisheye")])
def test_dome_resolution_override_resizes_the_rig(farm_cluster, tmp_path, engine, route):
    """``--resolution`` on a dome scene: the rig follows, so both routes give the fisheye of the new size."""
    ds = _dome_scene()
    out = tmp_path / "dome"
    res = render_sequence(DOME, "1", out, scheduler=farm_cluster.scheduler_address, progress=False,
                          resolution=(40, 40), samples=4,
                          scene_options={"engine": engine, "size": [48, 48], "face": 24})
    assert res.ok, res.failure_report()
    assert res.views == ("",) and res.manifest["run"]["worker_scene"]["dome_route"] == route
    img = pixels(out / "frame_0001.png")
    assert img.shape == (40, 40, 4)
    cam = dome.dome_camera("domemaster", width=40, height=40)
    _check_fisheye(img, cam, {n: (ds.COLOURS[n], ds.direction(*m)) for n, m in ds.MARKERS.items()})


@pytest.mark.slow
def test_eevee_dome_through_the_farm_is_a_fisheye(farm_cluster, tmp_path):
    dome_scene = _dome_scene()
    out = tmp_path / "dome"
    size = (48, 48)
    res = render_sequence(DOME, "1", out, scheduler=farm_cluster.scheduler_address, progress=False,
                          scene_options={"engine": "BLENDER_EEVEE", "size": list(size), "stereo": True, "face": 32})
    assert res.ok, res.failure_report()
    assert res.views == EYES
    assert res.manifest["run"]["worker_scene"]["dome_route"] == "cube"
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001_L.png", "frame_0001_R.png", "logs", "manifest.json"]
    cam = dome.dome_camera("domemaster", width=size[0], height=size[1])
    markers = {n: (dome_scene.COLOURS[n], dome_scene.direction(*m)) for n, m in dome_scene.MARKERS.items()}
    for v in EYES:
        img = pixels(out / frame_name(1, "PNG", v))
        assert img.shape == (size[1], size[0], 4)
        _check_fisheye(img, cam, markers)


def test_dome_example_renders_through_the_farm(farm_cluster, tmp_path, capsys):
    """``nephele render examples/dome_omnimax.py``: Cycles fisheye, stereo, both eyes of each frame."""
    out = tmp_path / "ex"
    example = HERE.parents[1] / "examples" / "dome_omnimax.py"
    rc = cli.main(["render", str(example), "--frames", "1-2", "--out", str(out), "--set", "size=[64,47]",
                   "--set", "samples=2", "--scheduler", farm_cluster.scheduler_address, "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == stereo_files(out, (1, 2)) + ["logs", "manifest.json"]
    run = json.loads((out / "manifest.json").read_text())["run"]
    assert run["views"] == list(EYES) and run["worker_scene"]["dome_route"] == "fisheye"
    img = pixels(out / "frame_0001_L.png")
    assert img.shape == (47, 64, 4)
    cam = dome.dome_camera("omnimax", width=64, height=47)
    # The globe sits ahead of the audience, 25 deg up: lit pixels there, none at the frame's top corners
    # (outside the Omnimax circle).
    col, row, _ = cam.direction_to_pixel(np.array([0.0, math.cos(math.radians(25)), math.sin(math.radians(25))]))
    assert img[int(round(row)), int(round(col)), :3].max() > 0.2
    assert img[0, 0, :3].max() < 0.05 and img[0, -1, :3].max() < 0.05
