"""``nephele demo``: the Fig. 1 film end to end (tiny), and clear errors before any work."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nephele.farm.cli import main


@pytest.mark.slow
def test_demo_renders_frames_sheet_and_summary(tmp_path):
    out = tmp_path / "demo"
    # A fresh process, as a user runs it: the memory summed over its process tree
    # must not include this test process (which has bpy and earlier tests loaded).
    cmd = [sys.executable, "-m", "nephele.farm", "demo", "--out", str(out), "--frames", "1-2", "--size", "64x48",
           "--samples", "2", "--source", "demo:small", "--hours-per-frame", "12", "--workers", "1"]
    run = subprocess.run(cmd, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    frames = sorted(out.glob("frame_*.png"))
    assert [p.name for p in frames] == ["frame_0001.png", "frame_0002.png"]
    summary = json.loads((out / "demo.json").read_text())
    assert summary["frames"] == 2 and summary["rendered"] == 2
    assert 0 < summary["peak_memory_pss_mb"] <= summary["peak_memory_total_mb"] < 2048
    from nephele.farm.post import read_rgba

    a, b = (read_rgba(p)[..., :3] for p in frames)
    assert a.shape == (48, 64, 3)
    assert a.std() > 0.02  # a globe on black, not a blank frame
    assert np.abs(a - b).mean() > 0.003  # the clouds moved in 12 model hours
    sheet = read_rgba(out / "contact_sheet.png")
    assert sheet.shape[1] > 2 * 64 and sheet.shape[0] > 48
    # A second run keeps the valid frames.
    assert main(["demo", "--out", str(out), "--frames", "1-2", "--size", "64x48", "--samples", "2",
                 "--source", "demo:small", "--hours-per-frame", "12", "--workers", "1"]) == 0
    assert json.loads((out / "demo.json").read_text())["skipped"] == 2


@pytest.mark.parametrize("args, message", [
    (["--source", "/no/such/file.nc"], "file.nc"),
    (["--size", "big"], "--size"),
    (["--samples", "0"], "--samples"),
    (["--hours-per-frame", "0"], "--hours-per-frame"),
    # a real file without cloud fraction: one line before any worker starts (was a Blender traceback)
    (["--source", str(Path(__file__).resolve().parents[1] / "data" / "cam_vinth2p.nc")],
     "field 'cloud': has no cloud fraction"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, args, message):
    assert main(["demo", "--out", str(tmp_path / "o")] + args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not list((tmp_path / "o").glob("frame_*"))
