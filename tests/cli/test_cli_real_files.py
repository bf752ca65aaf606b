"""The CLI on the real files in tests/data: overrides, rotated-pole extent, and one line + exit 2 on bad input."""

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("xarray")

from nephele.farm.cli import main  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"
CAM, NCL, UM = DATA / "cam_vinth2p.nc", DATA / "ncl_nc4uvt_T.nc", DATA / "um_hybrid_height.nc"


def run(capsys, *args):
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def one_line_error(rc, err, *words):
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert all(w in lines[0] for w in words), lines[0]


def test_info_rotated_pole_true_extent_radius_and_notes(capsys):
    rc, out, err = run(capsys, "info", UM, "--json")
    assert rc == 0, err
    info = json.loads(out)
    assert info["rotated_pole"] is True and info["earth_radius_m"] == 6371229.0
    # The 100 x 100 UM grid lies over mid-Wales (PROJ ob_tran gives the same corners: test_readers.py).
    west, east = info["true_lon"]
    south, north = info["true_lat"]
    assert -3.3 < west < east < -3.0 and 52.3 < south < north < 52.5
    assert not any(name.endswith("_bnds") or name == "rotated_latitude_longitude" for name in info["skipped"])
    rc, out, _ = run(capsys, "info", NCL)
    assert rc == 0
    assert "note       time: time units 'Month'" in out and "read as K" in out
    assert "radius     6371000 m" in out


def test_info_overrides_reach_the_reader(capsys):
    rc, out, err = run(
        capsys,
        "info",
        NCL,
        "--json",
        "--time-units",
        "days since 2000-01-01",
        "--earth-radius",
        "6371220",
        "--var-map",
        "temperature=T",
    )
    assert rc == 0, err
    info = json.loads(out)
    assert info["times"]["first"] == "2000-01-01T00:00:00"  # value 0 in days since 2000-01-01
    assert info["earth_radius_m"] == 6371220.0
    assert not any(n.startswith("time:") for n in info["notes"])


@pytest.mark.parametrize(
    "args, words",
    [
        (
            ["contour", CAM, "--var", "T", "--level", "1000", "-o", "x.ply"],
            ["cam_vinth2p.nc", "'temperature'", "level 1000", "187.092..309.265"],
        ),
        (
            ["contour", CAM, "--var", "Q", "--level", "250", "-o", "x.ply"],
            ["cam_vinth2p.nc", "'Q'", "no such variable"],
        ),
        (
            ["contour", CAM, "--var", "T", "--level", "250", "--time", "2", "-o", "x.ply"],
            ["cam_vinth2p.nc", "time index 2"],
        ),
        (
            ["contour", NCL, "--var", "T", "--level", "250", "--time-units", "fortnights", "-o", "x.ply"],
            ["ncl_nc4uvt_T.nc", "'time'", "fortnights"],
        ),
        (
            ["contour", NCL, "--var", "T", "--level", "250", "--var-map", "temperature=Q", "-o", "x.ply"],
            ["'Q'", "not a 3-D field"],
        ),
        (
            ["contour", NCL, "--var", "T", "--level", "250", "--var-map", "temperature", "-o", "x.ply"],
            ["--var-map", "STD=NAME"],
        ),
        (
            ["contour", UM, "--var", "air_potential_temperature", "--level", "250", "-o", "x.ply"],
            ["um_hybrid_height.nc", "outside the data range"],
        ),
        (["volume", CAM, "--var", "Q", "--out", "vol"], ["cam_vinth2p.nc", "'Q'", "no such variable"]),
        (["volume", CAM, "--var", "T", "--steps", "3-4", "--out", "vol"], ["--steps 3-4", "0-1"]),
        (["volume", NCL, "--var", "T", "--p0", "-3", "--out", "vol"], ["--p0"]),
        (["advect", CAM, "--var", "T", "--level", "250", "--frames", "1-1", "--cache", "c"], ["cam_vinth2p.nc", "'u'"]),
        (["info", UM, "--earth-radius", "6371.229"], ["--earth-radius", "metres"]),
    ],
)
def test_bad_input_on_real_files_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, args, words):
    monkeypatch.chdir(tmp_path)
    rc, out, err = run(capsys, *args)
    one_line_error(rc, err, *words)
    assert not any(p.is_file() for p in tmp_path.rglob("*"))


def test_contour_on_the_rotated_grid_lands_over_wales(tmp_path, capsys):
    trimesh = pytest.importorskip("trimesh")
    out = tmp_path / "theta.ply"
    rc, _, err = run(capsys, "contour", UM, "--var", "air_potential_temperature", "--level", "288", "-o", out)
    assert rc == 0, err
    v = np.asarray(trimesh.load(out, force="mesh", process=False).vertices, dtype=np.float64)
    lon = np.rad2deg(np.arctan2(v[:, 1], v[:, 0]))
    lat = np.rad2deg(np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1])))
    assert len(v) > 1000
    # Inside the grid's true extent (float32 vertices: 1e-4 degrees), which is over Wales, not at grid (0, 0).
    from nephele.core.climate.readers import open_dataset

    tlon, tlat = open_dataset(UM).grid.true_lonlat()
    assert tlon.min() - 1e-4 < lon.min() and lon.max() < tlon.max() + 1e-4
    assert tlat.min() - 1e-4 < lat.min() and lat.max() < tlat.max() + 1e-4
    assert -3.2 < lon.mean() < -3.04 and 52.37 < lat.mean() < 52.46


@pytest.mark.parametrize("command", [["contour", "--level", "250", "-o", "x.ply"], ["volume", "--out", "vol"]])
def test_all_nan_field_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, command):
    import xarray as xr

    with xr.open_dataset(NCL, decode_times=False) as f:
        f = f.load()
    f["T"][:] = np.nan
    f.to_netcdf(tmp_path / "allnan.nc")
    monkeypatch.chdir(tmp_path)
    rc, _, err = run(capsys, command[0], tmp_path / "allnan.nc", "--var", "T", *command[1:])
    one_line_error(rc, err, "allnan.nc", "'temperature'", "every value at time step 0 is missing")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["allnan.nc"]


def _lcc_file(path):
    """The Lambert conformal test file of tests/core/climate/test_readers_curvilinear.py (2-D lat/lon)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "curvilinear_files", Path(__file__).resolve().parents[1] / "core" / "climate" / "test_readers_curvilinear.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod._lcc_file(path)


def test_voxel_volume_on_a_curvilinear_grid(tmp_path, capsys):
    pytest.importorskip("bpy")  # openvdb comes with bpy: where bpy is, openvdb must be
    from nephele.fileio import openvdb

    _lcc_file(tmp_path / "lcc.nc")
    out = tmp_path / "vol"
    rc, _, err = run(capsys, "volume", tmp_path / "lcc.nc", "--var", "T", "--threshold", "279", "--full", "281",
                     "--mode", "voxels", "--voxel-size", "0.002", "--steps", "0-0", "--out", out, "--quiet")
    assert rc == 0, err
    assert [p.name for p in sorted(out.glob("*.vdb"))] == ["clouds_0001.vdb"]
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["mode"] == "voxels" and meta["grids"][0] == "density"
    # The file holds the core resampler's voxels: the same active count.
    from nephele.core.climate.readers import open_dataset
    from nephele.core.volume.sparse import resample
    from nephele.core.volume.transfer import TransferFunction

    ds = open_dataset(tmp_path / "lcc.nc")
    want = resample(ds.grid, ds.read("T", 0), TransferFunction.ramp(279.0, 281.0), voxel_size=0.002).stats[
        "active_voxels"
    ]
    grids, _ = openvdb().readAll(str(out / "clouds_0001.vdb"))
    density = next(g for g in grids if g.name == "density")
    assert want > 1000 and density.activeVoxelCount() == want


def test_exact_volume_on_curvilinear_and_rotated_grids(tmp_path, capsys):
    # The exact mode places both: a 2-D lat/lon grid through its column index map, a rotated pole by the
    # rotation the volume object takes (refused before).
    pytest.importorskip("xarray")
    from nephele.core.climate.readers import open_dataset
    from nephele.core.volume.volume_atlas import atlas_layout
    from nephele.volume_files import read_exr

    pytest.importorskip("bpy")  # openvdb comes with bpy: where bpy is, openvdb must be
    _lcc_file(tmp_path / "lcc.nc")
    out = tmp_path / "lcc"
    rc, _, err = run(capsys, "volume", tmp_path / "lcc.nc", "--var", "T", "--threshold", "279", "--full", "281",
                     "--steps", "0-0", "--out", out, "--quiet")
    assert rc == 0, err
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["mode"] == "exact" and meta["layout"]["index"] is not None and "rotation" not in meta
    index, _ = read_exr(out / "clouds_index.exr")
    np.testing.assert_array_equal(index, atlas_layout(open_dataset(tmp_path / "lcc.nc").grid).index.image)
    out = tmp_path / "um"
    rc, _, err = run(
        capsys, "volume", UM, "--var", "air_potential_temperature", "--steps", "0-0", "--out", out, "--quiet"
    )
    assert rc == 0, err
    meta = json.loads((out / "sequence.json").read_text())
    np.testing.assert_array_equal(meta["rotation"], open_dataset(UM).grid.rotation)
    assert meta["layout"]["index"] is None and not (out / "clouds_index.exr").exists()
