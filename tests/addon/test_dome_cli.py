"""``nephele dome``: cube faces / equirect files to dome frames, and its errors."""

import numpy as np
import pytest

pytest.importorskip("bpy")

from nephele.core.camera import dome  # noqa: E402
from nephele.farm.cli import main  # noqa: E402
from nephele.fileio import read_image, write_image  # noqa: E402


def _field(d):
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.stack([0.5 + 0.5 * d[..., 0], 0.5 + 0.5 * d[..., 1], 0.5 + 0.5 * d[..., 2]], axis=-1)


def _faces(folder, n=32, pattern="face_{face}.png"):
    c = np.arange(n)
    cc, rr = np.meshgrid(c, c)
    for i, name in enumerate(dome.CUBE_FACES):
        write_image(folder / pattern.format(face=name), _field(dome.cube_to_direction(np.full(cc.shape, i), cc, rr, n)))


def test_cli_cube_folder_to_omnimax(tmp_path):
    _faces(tmp_path / "faces")
    out = tmp_path / "omni.png"
    assert main(["dome", str(tmp_path / "faces"), "--out", str(out), "--size", "64x47"]) == 0
    got = read_image(out)
    cam = dome.dome_camera("omnimax", width=64, height=47)
    faces = np.stack([read_image(tmp_path / "faces" / f"face_{n}.png") for n in dome.CUBE_FACES])
    want = dome.remap(faces, cam, "cube")
    assert got.shape == (47, 64, 3)
    assert np.abs(got - want).max() <= 1 / 255 + 1e-6  # only the 8-bit rounding of the output


def test_cli_sequence_with_face_pattern_and_equirect(tmp_path):
    for f in (1, 2):
        _faces(tmp_path, pattern=f"{f:04d}" + "_{face}.png")
    assert main(["dome", str(tmp_path / "{frame:04d}_{face}.png"), "--out", str(tmp_path / "dm_{frame:04d}.png"),
                 "--preset", "domemaster", "--size", "48x48", "--frames", "1-2"]) == 0
    assert read_image(tmp_path / "dm_0002.png").shape == (48, 48, 3)
    lon = ((np.arange(128) + 0.5) / 128 - 0.5) * 2 * np.pi
    lat = (0.5 - (np.arange(64) + 0.5) / 64) * np.pi
    lo, la = np.meshgrid(lon, lat)
    write_image(tmp_path / "eq.png",
                _field(np.stack([np.cos(la) * np.sin(lo), np.cos(la) * np.cos(lo), np.sin(la)], -1)))
    assert main(["dome", str(tmp_path / "eq.png"), "--out", str(tmp_path / "eqdm.png"), "--preset", "domemaster",
                 "--size", "48x48"]) == 0
    a, b = read_image(tmp_path / "eqdm.png"), read_image(tmp_path / "dm_0001.png")
    inside = dome.dome_camera("domemaster", width=48).pixel_to_direction(*np.meshgrid(np.arange(48), np.arange(48)))[1]
    assert np.abs(a - b)[inside].mean() < 0.02  # the cube and equirect routes agree


@pytest.mark.parametrize(
    "args, word",
    [
        (["--fov", "0"], "fov"),
        (["--fov", "400"], "fov"),
        (["--size", "0x10"], "width"),
        (["--size", "big"], "--size"),
        (["--supersample", "0"], "supersample"),
    ],
)
def test_cli_bad_values_exit_2(tmp_path, capsys, args, word):
    _faces(tmp_path, n=8)
    assert main(["dome", str(tmp_path), "--out", str(tmp_path / "x.png")] + args) == 2
    assert word in capsys.readouterr().err


def test_cli_missing_face_exit_2(tmp_path, capsys):
    _faces(tmp_path, n=8)
    (tmp_path / "face_up.png").unlink()
    assert main(["dome", str(tmp_path), "--out", str(tmp_path / "x.png")]) == 2
    assert "face_up.png" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
