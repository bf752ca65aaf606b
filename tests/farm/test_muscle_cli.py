"""``nephele muscle``: state table, mesh export and bad input (registered here until farm/cli.py lists it)."""

import numpy as np
import pytest

from nephele.farm import cli


@pytest.fixture(autouse=True)
def registered(monkeypatch):
    if "muscle" not in cli.COMMANDS:
        monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + ("muscle",))


def test_info_prints_states(tmp_path, capsys):
    assert cli.main(["muscle", "--frames", "1-3", "--out", str(tmp_path), "--film-frames", "3", "--info"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].split()[1:6] == ["M.ATP", "M.ADP.Pi", "A.M.ADP.Pi", "A.M.ADP", "A.M"]
    counts = np.array([[int(v) for v in ln.split()[1:6]] for ln in lines[1:]])
    assert counts.shape == (3, 5) and np.all(counts.sum(axis=1) == 270)
    assert counts[0, 1] == 270  # the film starts primed and detached


def test_export_ply(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    out = tmp_path / "meshes"
    assert cli.main(["muscle", "--frames", "2", "--out", str(out), "--film-frames", "2", "--spacing", "1.5",
                     "--export", "ply"]) == 0
    m = trimesh.load(out / "frame_0002.ply", process=False)
    assert len(m.faces) > 1000
    assert np.all(m.bounds[1] <= np.array([128.2, 74.0, 214.5]) + 30)  # the box, plus cylinders poking out


def test_dry_run_names_the_scene(tmp_path, capsys):
    assert cli.main(["muscle", "--frames", "1-2", "--out", str(tmp_path), "--dome", "omnimax", "--stereo",
                     "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "fig7_muscle.py" in out and "'stereo': True" in out


@pytest.mark.parametrize("argv, msg", [
    (["--stereo"], "--stereo needs --dome"),
    (["--frames", "0-3"], "outside the film"),
    (["--frames", "300"], "outside the film"),
    (["--size", "big"], "--size"),
    (["--spacing", "0"], "--spacing"),
    (["--film-frames", "0"], "--film-frames"),
])
def test_bad_input_exits_2(tmp_path, capsys, argv, msg):
    base = ["muscle", "--frames", "1-2", "--out", str(tmp_path), "--info"]
    if "--frames" in argv:
        base = ["muscle", "--out", str(tmp_path), "--info"]
    assert cli.main(base + argv) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err
