"""``nephele contour``: exports through the real command, clear errors with exit code 2."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

NEPHELE = Path(sys.executable).parent / "nephele"


def nephele(*args, cwd):
    cmd = [str(NEPHELE)] if NEPHELE.exists() else [sys.executable, "-m", "nephele.farm"]
    return subprocess.run(cmd + ["contour", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=120)


@pytest.mark.parametrize("ext", [".ply", ".obj"])
def test_exports_the_demo_cloud_surface(tmp_path, ext):
    trimesh = pytest.importorskip("trimesh")
    out = tmp_path / f"cloud{ext}"
    r = nephele("demo:small", "--var", "cloud", "--level", "0.15", "--time", "3", "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "triangles" in r.stdout
    mesh = trimesh.load(out, force="mesh", process=False)
    if ext == ".ply":  # normals and the altitude attribute travel with the vertices
        header = out.read_bytes()[:600]
        assert b"property float nx" in header and b"property float altitude" in header
    assert len(mesh.faces) > 100
    # On the globe: between the terrain (chords dip a little under it) and the exaggerated atmosphere top.
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert radius.min() > 0.99 and radius.max() < 1.2
    # The same surface as the core function gives.
    from nephele.core.climate.readers import open_dataset
    from nephele.core.surface.contour import isosurface

    ds = open_dataset("demo:small")
    periodic = ds.grid.periodic_lon
    ref = isosurface(ds.grid.points(), ds.read("cloud", 3), 0.15, periodic_lon=periodic, close_poles=periodic)
    assert len(mesh.faces) == len(ref.faces)
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


@pytest.mark.parametrize(
    "args, words",
    [
        (["demo:small", "--var", "nope", "--level", "0.1", "-o", "x.ply"], ["nope", "no such variable"]),
        (["demo:small", "--var", "cloud", "--level", "0.1", "-o", "x.stl"], ["x.stl", ".ply"]),
        (["missing.nc", "--var", "cloud", "--level", "0.1", "-o", "x.ply"], ["missing.nc", "not found"]),
        (["demo:small", "--var", "cloud", "--level", "0.1", "--time", "999", "-o", "x.ply"], ["999"]),
        (["demo:small", "--var", "cloud", "--level", "nan", "-o", "x.ply"], ["--level"]),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, args, words):
    r = nephele(*args, cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert all(w in lines[0] for w in words), lines[0]
    assert not list(tmp_path.iterdir())
