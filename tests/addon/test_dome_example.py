"""examples/dome_omnimax.py: the Fig. 1 globe lands where the dome mapping says, in both eyes."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[2]


def _example():
    spec = importlib.util.spec_from_file_location("dome_omnimax", ROOT / "examples" / "dome_omnimax.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_example_renders_globe_where_expected(tmp_path):
    from nephele.core.camera import dome
    from nephele.fileio import read_image

    ex = _example()
    paths = ex.render(tmp_path, "omnimax", size=(128, 94), samples=4, stereo=True, elevation=25.0, distance=1.7)
    assert [p.name for p in paths] == ["omnimax_L.png", "omnimax_R.png"]
    cam = dome.dome_camera("omnimax", width=128, height=94)
    e = math.radians(25.0)
    col, row, vis = cam.direction_to_pixel(np.array([0.0, math.cos(e), math.sin(e)]))
    assert vis
    centres = []
    for p in paths:
        img = read_image(p)[..., :3]
        globe = img.sum(-1) > 0.06  # the globe and clouds against near-black space
        rr, cc = np.nonzero(globe)
        assert globe.sum() > 200
        # the bounding box's centre (the sun lights one side, so not the brightness centroid)
        centre = ((cc.min() + cc.max()) / 2, (rr.min() + rr.max()) / 2)
        assert math.hypot(centre[0] - col, centre[1] - row) < 3.0
        centres.append(centre)
    # fixed baseline: the eyes differ along the frame's width, not its height
    assert abs(centres[0][1] - centres[1][1]) <= 0.5
