"""``nephele scatter``: solve, orbit views, optional VDBs; bad values exit with code 2."""

import json

import numpy as np
import pytest

from nephele.core.light import scatter
from nephele.farm import cli


def test_scatter_command_writes_views_and_solution(tmp_path):
    out = tmp_path / "s"
    rc = cli.main(["scatter", "--out", str(out), "--grid", "8x8x6", "--views", "2", "--size", "24x20",
                   "--tol", "1e-2", "--vdb", "--quiet"])
    assert rc == 0
    meta = json.loads((out / "scatter.json").read_text())
    assert meta["converged"] and meta["views"] == 2
    sol = scatter.load_solution(out / "solution.npz")
    assert sol.sigma.shape == (6, 8, 8) and sol.received.shape == (96,) + sol.sigma[sol.box].shape
    assert sol.grid("received").shape == (96, 6, 8, 8)
    img = np.load(out / "view_0001.npy")
    assert img.shape == (20, 24) and img.max() > 0 and np.all(np.isfinite(img))
    # the view is the film-speed plane march; the ray march of the same solution is the anchor
    cam = scatter.orbit_camera(0.0, (1, 1, 0.75), width=24, height=20)
    anchor = scatter.render(sol.sigma, scatter.view_source(sol, cam.position), sol.size, cam, step=0.1)
    assert img.mean() == pytest.approx(anchor.mean(), rel=5e-3)
    assert np.abs(img - anchor).max() <= 0.03 * anchor.max()
    assert not list(out.glob(".*.tmp*"))  # every file written whole (atomic_write)
    assert (out / "view_0002.png").stat().st_size > 0
    assert (out / "scatter_0002.vdb").stat().st_size > 0


def test_scatter_command_total_on_request(tmp_path):
    # The saved solution holds the total flux only with --total; the received flux is the same either way.
    args = ["--grid", "8x8x6", "--views", "1", "--size", "12x10", "--tol", "1e-2", "--quiet"]
    sols = []
    for name, extra in (("plain", []), ("total", ["--total"])):
        assert cli.main(["scatter", "--out", str(tmp_path / name), *args, *extra]) == 0
        sols.append(scatter.load_solution(tmp_path / name / "solution.npz"))
    plain, total = sols
    assert plain.total is None and total.total.shape == total.received.shape and total.total.max() > 0
    np.testing.assert_array_equal(plain.received, total.received)


def test_scatter_command_bad_values(tmp_path, capsys):
    assert cli.main(["scatter", "--out", str(tmp_path), "--grid", "8x8"]) == 2
    assert "--grid" in capsys.readouterr().err
    assert cli.main(["scatter", "--out", str(tmp_path), "--g", "1.0"]) == 2


def test_scatter_command_sky_map(tmp_path):
    from nephele import fileio

    sky = tmp_path / "sky.exr"
    fileio.write_image(sky, np.tile(np.float32([0.5, 0.25, 1.0]), (32, 64, 1)))
    out = tmp_path / "s"
    rc = cli.main(["scatter", "--out", str(out), "--grid", "8x8x6", "--views", "1", "--size", "24x20",
                   "--tol", "1e-2", "--irradiance", "0", "--sky-map", str(sky), "--sky-strength", "2", "--quiet"])
    assert rc == 0
    sol = scatter.load_solution(out / "solution.npz")
    lum = 0.2126 * 0.5 + 0.7152 * 0.25 + 0.0722 * 1.0  # Rec. 709, linear
    np.testing.assert_allclose(sol.sky_radiance, 2 * lum, rtol=1e-6)  # a constant sky: every bin alike
    assert json.loads((out / "scatter.json").read_text())["sky_map"] == str(sky.resolve())
    assert np.load(out / "view_0001.npy").max() > 0


def test_scatter_command_bad_sky_map(tmp_path, capsys):
    from nephele import fileio

    missing = tmp_path / "none.exr"
    assert cli.main(["scatter", "--out", str(tmp_path / "a"), "--sky-map", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "none.exr" in err and "--sky-map" in err and "Traceback" not in err
    square = fileio.write_image(tmp_path / "square.exr", np.ones((32, 32, 3), np.float32))
    assert cli.main(["scatter", "--out", str(tmp_path / "b"), "--sky-map", str(square)]) == 2
    assert "twice as wide" in capsys.readouterr().err
    assert cli.main(["scatter", "--out", str(tmp_path / "c"), "--sky", "0.3", "--sky-map", str(square)]) == 2
    assert "not both" in capsys.readouterr().err
    bad = np.ones((32, 64, 3), np.float32)
    bad[3, 7] = (-1.0, 0.0, 0.0)
    bad = fileio.write_image(tmp_path / "negative.exr", bad)
    assert cli.main(["scatter", "--out", str(tmp_path / "d"), "--sky-map", str(bad)]) == 2
    assert "finite and >= 0" in capsys.readouterr().err


def test_scatter_command_finer_bins(tmp_path, capsys):
    out = tmp_path / "s"
    rc = cli.main(["scatter", "--out", str(out), "--grid", "8x8x6", "--views", "1", "--size", "24x20",
                   "--tol", "1e-2", "--bins-per-face", "6", "--quiet"])
    assert rc == 0
    sol = scatter.load_solution(out / "solution.npz")
    assert sol.bins_per_face == 6 and sol.received.shape[0] == 216
    assert json.loads((out / "scatter.json").read_text())["bins_per_face"] == 6
    assert np.load(out / "view_0001.npy").max() > 0
    for bad in ("5", "10", "0"):
        assert cli.main(["scatter", "--out", str(tmp_path / "b"), "--bins-per-face", bad]) == 2
        assert "--bins-per-face" in capsys.readouterr().err


@pytest.mark.parametrize("evolve", ["drift", "climate"])
def test_scatter_command_evolving_sequence(tmp_path, evolve):
    from nephele import fileio

    out = tmp_path / "s"
    rc = cli.main(["scatter", "--out", str(out), "--grid", "8x8x6", "--views", "3", "--size", "24x20",
                   "--tol", "1e-2", "--vdb", "--quiet", "--evolve", evolve])
    assert rc == 0
    meta = json.loads((out / "scatter.json").read_text())
    assert meta["evolve"] == evolve and len(meta["frame_solves"]) == 3
    assert all("from the previous frame" in f["report"] for f in meta["frame_solves"][1:])
    sols = [scatter.load_solution(out / n) for n in ("solution.npz", "solution_0002.npz", "solution_0003.npz")]
    assert not sols[0].warm and sols[1].warm and sols[2].warm
    assert np.abs(sols[2].sigma - sols[0].sigma).max() > 0  # the cloud moved
    vdb = fileio.openvdb()
    dens = np.zeros((8, 8, 6), np.float32)
    vdb.read(str(out / "scatter_0003.vdb"), "density").copyToArray(dens)
    np.testing.assert_allclose(dens.transpose(2, 1, 0), sols[2].sigma, rtol=1e-6)  # each frame's own density
    assert np.load(out / "view_0003.npy").max() > 0


def test_scatter_command_bad_drift(tmp_path, capsys):
    assert cli.main(["scatter", "--out", str(tmp_path), "--evolve", "drift", "--drift", "0.1,x,0"]) == 2
    assert "--drift" in capsys.readouterr().err
