"""nephele/fileio.py: the one image and volume I/O of the add-on and the farm."""

import os
import stat
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("bpy")

from nephele import fileio  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402


def test_png_and_exr_round_trip(tmp_path):
    px = np.linspace(0.0, 1.0, 4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    png = fileio.write_image(tmp_path / "a.png", px)
    np.testing.assert_allclose(fileio.read_image(png), np.round(px * 255) / 255, atol=1e-6)
    exr = fileio.write_image(tmp_path / "a.exr", px * 7.0 - 2.0, pixel_type="float", metadata={"nephele_key": "k1"},
                             compression="zip")
    np.testing.assert_array_equal(fileio.read_image(exr), px * 7.0 - 2.0)
    inp = fileio.oiio().ImageInput.open(str(exr))
    assert inp.spec().get_string_attribute("nephele_key") == "k1"
    inp.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "a.png"]


def test_written_files_have_the_umasks_mode(tmp_path):
    old = os.umask(0o022)
    try:
        p = fileio.write_image(tmp_path / "m.png", np.zeros((2, 2, 3), np.float32))
        v = fileio.write_vdb(tmp_path / "m.vdb",
                             [fileio.block_grid("density", [(0, 0, 0)], np.ones((1, 8, 8, 8)), 8, 0.5)])
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(p).st_mode) == stat.S_IMODE(os.stat(v).st_mode) == 0o644


def test_unwritable_image_is_a_data_error(tmp_path):
    with pytest.raises(DataError):
        fileio.write_image(tmp_path / "a.unknownformat", np.zeros((2, 2, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_vdb_block_and_dense_grids_round_trip(tmp_path):
    data = np.zeros((2, 8, 8, 8), np.float32)
    data[0, 1, 2, 3] = 0.5
    data[1, 7, 7, 7] = 1.0
    path = fileio.write_vdb(tmp_path / "b.vdb", [fileio.block_grid("density", [(0, 0, 0), (1, 0, 2)], data, 8, 0.25)],
                            {"nephele_key": "abc"})
    a, lo, vs = fileio.read_grid(path)
    assert vs == pytest.approx(0.25)
    assert tuple(lo) == (1, 2, 3) and a.shape == (15, 6, 21)
    assert a[0, 0, 0] == 0.5 and a[-1, -1, -1] == 1.0 and a.sum() == 1.5
    assert fileio.vdb_metadata(path)["nephele_key"] == "abc"
    sigma = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4) + 1.0  # (nz, ny, nx)
    fileio.write_vdb(tmp_path / "d.vdb", fileio.dense_grids({"density": sigma}, (1.0, 1.0, 0.5)))
    a, lo, vs = fileio.read_grid(tmp_path / "d.vdb")
    np.testing.assert_array_equal(a, sigma.transpose(2, 1, 0))
    assert vs == pytest.approx(0.25)


def test_the_farm_reads_images_without_the_addon(tmp_path):
    fileio.write_image(tmp_path / "eq.png", np.full((4, 8, 3), 0.5, np.float32))
    code = (
        "import sys\n"
        "from nephele.farm import cmd_dome\n"
        f"img = cmd_dome.load_source({str(tmp_path / 'eq.png')!r}, 'equirect')\n"
        "assert img.shape == (4, 8, 3), img.shape\n"
        "assert not [m for m in sys.modules if m.startswith('nephele.addon')]\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[-1] == "ok"  # bpy may log its colour config first
