"""``nephele volume``: a VDB sequence from the command line, bad input exits 2."""

import json

import numpy as np
import pytest

pytest.importorskip("bpy")

from nephele.farm.cli import main  # noqa: E402
from nephele.fileio import read_grid  # noqa: E402


def test_writes_sequence_and_metadata(tmp_path, capsys):
    out = tmp_path / "seq"
    rc = main(["volume", "demo:small", "--steps", "2-3", "--mode", "voxels", "--voxel-size", "0.02", "--out", str(out),
               "--quiet"])
    assert rc == 0
    assert sorted(p.name for p in out.glob("*.vdb")) == ["clouds_0001.vdb", "clouds_0002.vdb"]
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["steps"] == [2, 3] and meta["grids"] == ["density", "altitude"]
    a, lo, vs = read_grid(out / "clouds_0001.vdb")
    assert vs == pytest.approx(0.02) and a.max() > 0 and a.max() <= 1.0
    alt, _, _ = read_grid(out / "clouds_0001.vdb", "altitude")
    assert np.nanmax(alt) < 25000.0
    assert "2 VDB files" in capsys.readouterr().out


def test_exact_mode_writes_atlases_the_core_reproduces(tmp_path, capsys):
    from nephele.core.climate.readers import open_dataset
    from nephele.core.volume.transfer import TransferFunction
    from nephele.core.volume.volume_atlas import atlas_layout, exact_volume
    from nephele.volume_files import read_exr

    out = tmp_path / "seq"
    rc = main(["volume", "demo:small", "--steps", "1-1", "--support-size", "0.03", "--out", str(out), "--quiet"])
    assert rc == 0
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == [
        "clouds_0001.exr", "clouds_0001.vdb", "clouds_heights.exr", "sequence.json"]
    meta = json.loads((out / "sequence.json").read_text())
    assert meta["mode"] == "exact" and meta["grids"] == ["support"] and meta["support_size"] == 0.03
    ds = open_dataset("demo:small")
    ev = exact_volume(ds.grid, ds.read("cloud", 1), TransferFunction.ramp(0.3, 1.0), support_size=0.03,
                      color_name="altitude")
    values, info = read_exr(out / "clouds_0001.exr")
    np.testing.assert_array_equal(values, ev.values)  # 32-bit floats: lossless
    heights, _ = read_exr(out / "clouds_heights.exr")
    np.testing.assert_array_equal(heights, atlas_layout(ds.grid).heights)
    assert meta["layout"] == json.loads(json.dumps(ev.layout.to_dict()))
    support, lo, vs = read_grid(out / "clouds_0001.vdb", "support")
    assert vs == pytest.approx(0.03) and np.count_nonzero(support) == ev.support.shape[0]
    assert set(np.unique(support)) <= {0.0, 1.0}


def test_empty_volume_warns(tmp_path, capsys):
    rc = main(["volume", "demo:small", "--steps", "0-0", "--threshold", "5", "--full", "6", "--voxel-size", "0.02",
               "--out", str(tmp_path), "--quiet"])
    assert rc == 0
    assert read_grid(tmp_path / "clouds_0001.vdb", "support")[0] is None
    assert "every volume is empty" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--var", "nosuch"], "nosuch"),
        (["--steps", "0-999"], "--steps"),
        (["--voxel-size", "-1"], "--voxel-size"),
        (["--tf", "[[1, 0], [0, 1]]"], "ascending"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, extra, message):
    rc = main(["volume", "demo:small", "--out", str(tmp_path)] + extra)
    err = capsys.readouterr().err
    assert rc == 2
    assert message in err and "Traceback" not in err
    assert not list(tmp_path.glob("*.vdb"))
