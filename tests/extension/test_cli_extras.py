"""``pip install nephele`` gives numpy only: a command that needs an optional
package says which extra installs it, in one line, exit 2; ``--help`` speaks to
users."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from nephele.farm import cli

ROOT = Path(__file__).resolve().parents[2]
NETCDF = ROOT / "tests" / "data" / "climate" / "rectilinear_grid_3D.nc"
BLENDER_ONLY = ROOT / "build" / "venv-bpy52" / "bin" / "python"  # numpy, no xarray/scipy


def test_missing_extra_is_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "xarray", None)  # import xarray -> ModuleNotFoundError
    path = tmp_path / "x.nc"
    path.write_bytes(b"CDF\x01")
    assert cli.main(["info", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nephele info: error: this needs xarray, which is not installed: pip install 'nephele[data]'"]


def test_other_missing_module_is_not_hidden(monkeypatch):
    # A missing module that no extra provides is a bug: its traceback stays.
    from nephele.farm import cmd_info

    def run(args):
        raise ModuleNotFoundError("No module named 'nosuchmodule'", name="nosuchmodule")

    monkeypatch.setattr(cmd_info, "run", run)
    with pytest.raises(ModuleNotFoundError):
        cli.main(["info", "x.nc"])


def test_extras_named_in_messages_exist():
    text = (ROOT / "pyproject.toml").read_text()
    section = text.split("[project.optional-dependencies]")[1].split("\n[")[0]
    for package, extra in cli.EXTRAS.items():
        line = next(ln for ln in section.splitlines() if ln.startswith(f"{extra} = "))
        wanted = {"netCDF4": "netCDF4", "dask_jobqueue": "dask-jobqueue", "distributed": "dask[distributed]",
                  "dask": "dask[distributed]", "imageio_ffmpeg": "imageio-ffmpeg", "mathutils": "bpy",
                  "cftime": "netCDF4", "pandas": "xarray"}.get(package, package)
        assert f'"{wanted}' in line, (package, extra, line)


def test_help_speaks_to_users(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert "cmd_" not in out and "films" in out
    assert "nephele[data]" in out and "nephele[farm]" in out


@pytest.mark.skipif(not BLENDER_ONLY.exists(), reason="no Blender-only Python (build/venv-bpy52): run make test-full")
def test_in_a_python_without_xarray(tmp_path):
    (tmp_path / "nephele").symlink_to(ROOT, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env["PYTHONPATH"] = str(tmp_path)
    res = subprocess.run([str(BLENDER_ONLY), "-m", "nephele.farm", "info", str(NETCDF)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr.strip() == ("nephele info: error: this needs xarray, which is not installed: "
                                  "pip install 'nephele[data]'")
