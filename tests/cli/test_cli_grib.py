"""``nephele info`` and ``nephele contour`` on real GRIB products, through the real command.

The contour of the GFS cloud water at 1e-5 kg/kg must lie where the file's own values (decoded by
ecCodes here, not by the reader) cross 1e-5: every vertex on a grid edge whose two ends bracket it.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

NEPHELE = Path(sys.executable).parent / "nephele"
GFS = "gfs.t12z.pgrbf120.2p5deg.grib2"


def nephele(*args, cwd):
    cmd = [str(NEPHELE)] if NEPHELE.exists() else [sys.executable, "-m", "nephele.farm"]
    return subprocess.run(cmd + list(map(str, args)), capture_output=True, text=True, cwd=cwd, timeout=300)


def test_info_lists_level_types_members_and_the_shared_level_axis(grib_samples, tmp_path):
    r = nephele("info", grib_samples / GFS, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "level type isobaricInhPa (10 3-D variables" in r.stdout and "choose another with --level-type" in r.stdout
    assert "potentialVorticity 6" in r.stdout and "surface (37)" in r.stdout
    assert "cloud_water  [kg/kg]  'clwmr' in the file" in r.stdout and "omega" in r.stdout
    assert "one axis of 26 isobaricInhPa levels shared by all variables" in r.stdout
    r = nephele("info", grib_samples / "era5-levels-members.grib", "--member", "4", "--json", cwd=tmp_path)
    info = json.loads(r.stdout)
    assert info["members"] == list(range(10)) and info["member"] == 4 and info["times"]["count"] == 4
    r = nephele("info", grib_samples / GFS, "--level-type", "heightAboveSea", cwd=tmp_path)
    assert r.returncode == 0 and "1829, 2743, 3658 m" in r.stdout and "height levels (flat)" in r.stdout


@pytest.mark.parametrize("args, words", [
    (["--level-type", "hybrid"], ["field 'level_type'", "no fields on level type 'hybrid'"]),
    (["--member", "2"], ["field 'member'", "no ensemble members"]),
    (["--p0", "100000"], ["field 'p0'", "GRIB files state their levels"]),
])
def test_bad_choices_exit_2_with_one_line(grib_samples, tmp_path, args, words):
    r = nephele("info", grib_samples / GFS, *args, cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert all(w in lines[0] for w in words), lines[0]


def _clwmr_cube(path):
    """ecCodes' clwmr on the isobaric levels, (levels bottom up, lat south-north, lon), NaN where absent."""
    eccodes = pytest.importorskip("eccodes")
    cube = {}
    with open(path, "rb") as f:
        while (h := eccodes.codes_grib_new_from_file(f)) is not None:
            if eccodes.codes_get(h, "shortName") == "clwmr" and eccodes.codes_get(h, "typeOfLevel") == "isobaricInhPa":
                cube[eccodes.codes_get(h, "level")] = eccodes.codes_get_values(h).reshape(73, 144)[::-1]
            eccodes.codes_release(h)
    return cube


def test_contour_of_cloud_water_lies_where_the_file_crosses_the_level(grib_samples, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    from nephele.core.climate.grid import height_from_radius, xyz_to_lonlat
    from nephele.core.climate.readers import open_dataset

    out = tmp_path / "clouds.ply"
    r = nephele("contour", grib_samples / GFS, "--var", "clwmr", "--level", "1e-5", "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    mesh = trimesh.load(out, force="mesh", process=False)
    assert len(mesh.faces) > 10000
    # The grid nodes where the reader puts the file's points, and ecCodes' own clwmr values on them.
    grid = open_dataset(grib_samples / GFS).grid
    nodes = grid.points().astype(np.float64)  # (26, 73, 144, 3), default radius 1 and exaggeration 30 as the command
    cube = _clwmr_cube(grib_samples / GFS)
    values = np.full(grid.shape, np.nan)
    for k, p in enumerate(sorted(cube, reverse=True)):  # 1000 hPa first: bottom up like the reader's levels
        values[k] = cube[p]
    # Each vertex lies on one grid edge: find it among the three edges through its rounded indices.
    v = np.asarray(mesh.vertices, dtype=np.float64)
    lon, lat, rad = xyz_to_lonlat(v)
    frac = np.stack([np.interp(height_from_radius(rad), grid.height[:, 0, 0], np.arange(26)),
                     (lat + 90.0) / 2.5, np.mod(lon, 360.0) / 2.5], axis=1)
    best = None
    for axis in range(3):
        lo = np.round(frac).astype(int)
        lo[:, axis] = np.floor(frac[:, axis]).astype(int)
        hi = lo.copy()
        hi[:, axis] += 1
        for idx in (lo, hi):
            idx[:, 0] = np.clip(idx[:, 0], 0, 25)
            idx[:, 1] = np.clip(idx[:, 1], 0, 72)
            idx[:, 2] %= 144
        p0, p1 = nodes[lo[:, 0], lo[:, 1], lo[:, 2]], nodes[hi[:, 0], hi[:, 1], hi[:, 2]]
        d = p1 - p0
        t = np.clip(np.einsum("ij,ij->i", v - p0, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-30), 0.0, 1.0)
        dist = np.linalg.norm(v - (p0 + t[:, None] * d), axis=1)
        a, b = values[lo[:, 0], lo[:, 1], lo[:, 2]], values[hi[:, 0], hi[:, 1], hi[:, 2]]
        if best is None:
            best = [dist, t, a, b]
        else:
            take = dist < best[0]
            for n, new in enumerate((dist, t, a, b)):
                best[n] = np.where(take, new, best[n])
    dist, t, a, b = best
    on_edge = dist < 1e-5  # scene units (the sphere has radius 1; float32 vertices)
    assert on_edge.mean() > 0.99, on_edge.mean()
    # Marching cubes interpolates linearly along the edge: the file's values there give 1e-5 at the vertex.
    # (float32 vertices: a few on very short edges near the poles carry t to ~1 %)
    rel = np.abs(a[on_edge] + t[on_edge] * (b[on_edge] - a[on_edge]) - 1e-5) / 1e-5
    assert np.quantile(rel, 0.999) < 2e-3 and rel.max() < 0.01, (np.quantile(rel, 0.999), rel.max())
