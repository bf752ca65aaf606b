"""``nephele info``: through the real command (no bpy needed), exit code 2 and one line on bad input."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

NEPHELE = Path(sys.executable).parent / "nephele"
# Where ecCodes is not installed (GRIB is optional in the core-only Python 3.11), GRIB files are refused for
# that reason.
GRIB_REFUSAL = ("x.grib: cannot open as GRIB" if importlib.util.find_spec("eccodes")
                else "x.grib: reading GRIB needs ecCodes")


def nephele(*args, cwd):
    cmd = [str(NEPHELE)] if NEPHELE.exists() else [sys.executable, "-m", "nephele.farm"]
    return subprocess.run(cmd + ["info", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=120)


def test_info_demo_small(tmp_path):
    r = nephele("demo:small", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "curvilinear, terrain following" in out
    assert "64 lon x 32 lat x 8 levels" in out
    assert "periodic" in out and "not periodic" not in out
    for name in ("cloud", "temperature", "u", "v", "w"):
        assert f"\n    {name} " in out
    assert "48: 1987-01-01T00:00:00 .. 1987-01-02T23:00:00, step 1 h" in out


def test_info_json_real_grads(tmp_path, shared_data):
    r = nephele(shared_data / "climate" / "model.ctl", "--json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["shape"] == {"lon": 72, "lat": 46, "levels": 7}
    assert info["grid"].startswith("rectilinear (pressure levels")
    assert info["periodic_lon"] is True and info["lat"] == [-90.0, 90.0]
    names = {v["name"]: v for v in info["variables"]}
    assert names["cloud"]["derived"].startswith("rh, Sundqvist") and names["temperature"]["file_name"] == "T"
    assert info["times"]["count"] == 5 and info["times"]["step_hours"] == 24.0
    assert set(info["skipped"]) == {"PS", "TS", "P"}


@pytest.mark.parametrize(
    "make, expect",
    [
        (lambda d: d / "missing.nc", "missing.nc: file not found"),
        (lambda d: (d / "x.grib").write_bytes(b"GRIB") and d / "x.grib", GRIB_REFUSAL),
        (lambda d: (d / "bad.nc").write_bytes(b"\x01\x02junk") and d / "bad.nc", "bad.nc: cannot open as NetCDF"),
        (lambda d: (d / "bad.ctl").write_text("DSET ^nothing.dat\n") and d / "bad.ctl",
         "bad.ctl: field 'xdef': descriptor has no XDEF"),
    ],
)
def test_info_bad_input_exits_2_with_one_line(tmp_path, make, expect):
    r = nephele(make(tmp_path), cwd=tmp_path)
    assert r.returncode == 2
    assert r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert lines[0].startswith("nephele info: error: ") and expect in lines[0]
