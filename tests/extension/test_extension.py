"""The extension as a user gets it: ``nephele build-extension`` zips, installed
through Blender's extension API into a Python holding only what Blender ships
(``bpy`` and its dependencies), the whole sidebar workflow driven there.

The Blender-only interpreters come from ``NEPHELE_BLENDER_PYTHONS`` (paths
separated by ``os.pathsep``), else ``build/venv-bpy52`` (bpy 5.2.3, Python
3.13) and ``build/venv-bpy50`` (bpy 5.0.1, Python 3.11 + numpy 1.26) made by
``make test``.  With ``NEPHELE_REQUIRE_BLENDER_PYTHONS=1`` (``make test``) a
missing one fails instead of skipping.
"""

import json
import os
import re
import subprocess
import zipfile
from pathlib import Path

import pytest

from nephele.farm import cmd_build_extension as be
from nephele.farm.cli import UsageError, main

pytestmark = [pytest.mark.bpy, pytest.mark.timeout(1200)]  # building and installing two zips takes minutes
pytest.importorskip("bpy")  # the builder is the one inside the bpy wheel

ROOT = Path(__file__).resolve().parents[2]
WORKFLOW = Path(__file__).with_name("workflow.py")
NETCDF = ROOT / "tests" / "data" / "climate" / "rectilinear_grid_3D.nc"
DEFAULT_PYTHONS = {"3.13": ROOT / "build" / "venv-bpy52" / "bin" / "python",
                   "3.11": ROOT / "build" / "venv-bpy50" / "bin" / "python"}
EXCLUDED_TOP = {"tests", "farm", "examples", "benchmarks", "docs", "build", "dist", "out", ".venv", ".venv311"}
REGISTRATION_WARNINGS = ("already registered", "register_class", "unregister_class", "was not registered",
                         "Traceback")


def _python_version(exe):
    res = subprocess.run([str(exe), "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                         capture_output=True, text=True, check=True)
    return res.stdout.strip()


def _blender_pythons():
    env = os.environ.get("NEPHELE_BLENDER_PYTHONS")
    exes = [Path(p) for p in env.split(os.pathsep) if p] if env else list(DEFAULT_PYTHONS.values())
    found = {}
    for exe in exes:
        if exe.exists():
            found[_python_version(exe)] = exe
        elif os.environ.get("NEPHELE_REQUIRE_BLENDER_PYTHONS") == "1":
            raise FileNotFoundError(f"Blender-only Python missing: {exe} (make test creates it)")
    return found


PYTHONS = _blender_pythons()


@pytest.fixture(scope="module")
def dist(tmp_path_factory):
    return tmp_path_factory.mktemp("dist")


def _zip_for(dist, py):
    zips = sorted(dist.glob(f"*{be.TARGETS[py].label}-linux_x64.zip"))
    if not zips:
        assert main(["build-extension", "--out", str(dist), "--platform", "linux-x64", "--python", py]) == 0
        zips = sorted(dist.glob(f"*{be.TARGETS[py].label}-linux_x64.zip"))
    assert len(zips) == 1, zips
    return zips[0]


@pytest.fixture(scope="module", params=sorted(PYTHONS) or [pytest.param(None, marks=pytest.mark.skip(
    reason="no Blender-only Python (build/venv-bpy52); run make test"))])
def installed(request, dist, tmp_path_factory):
    """The workflow run once per Blender-only Python: (result dict, full output)."""
    py = request.param
    zip_path = _zip_for(dist, py)
    tmp = tmp_path_factory.mktemp(f"blender{py}")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env.update(BLENDER_USER_RESOURCES=str(tmp / "resources"), NEPHELE_CACHE=str(tmp / "cache"))
    args = [str(PYTHONS[py]), str(WORKFLOW), str(zip_path), str(tmp / "out"), str(NETCDF)]
    res = subprocess.run(args, capture_output=True, text=True, timeout=900, env=env, cwd=tmp)
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-4000:]
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
    assert len(line) == 1, out[-4000:]
    result = json.loads(line[0][len("RESULT "):])
    result["zip_mb"] = zip_path.stat().st_size / 1e6
    print(f"\nBlender {result['bpy']} / Python {result['python']}: zip {result['zip_mb']:.1f} MB, "
          + ", ".join(f"{k} {v:.1f} s" for k, v in result["times"].items()))
    return result, out


def test_whole_workflow_finishes(installed):
    result, _ = installed
    assert set(result["results"]) >= {"import_demo", "add_contour", "add_advected_texture", "update_frame",
                                      "add_globe", "add_sky", "add_camera", "add_volume_clouds",
                                      "add_scattering_cloud", "add_dome_camera", "render_dome_cube", "render",
                                      "add_globe_again"}
    assert all(v == ["FINISHED"] for v in result["results"].values()), result["results"]
    assert result["results"]["import_netcdf"] == ["FINISHED"]


def test_disable_leaves_nothing_registered(installed):
    left = installed[0]["left_after_disable"]
    assert left == {"panel": False, "operators": [], "classes": [], "scene_properties": [], "handlers": []}


def test_no_registration_warnings(installed):
    out = installed[1]
    hits = [ln for ln in out.splitlines() if any(w in ln for w in REGISTRATION_WARNINGS)]
    assert not hits, hits


# --- the zip itself ---------------------------------------------------------------------------------------------


def _manifest_wheels(z):
    text = z.read("blender_manifest.toml").decode()
    block = re.search(r"(?ms)^wheels = \[(.*?)\]", text).group(1)
    return [w.removeprefix("./") for w in re.findall(r'"([^"]+)"', block)], text


@pytest.mark.parametrize("py", sorted(be.TARGETS))
def test_zip_contents(dist, py):
    z = zipfile.ZipFile(_zip_for(dist, py))
    names = z.namelist()
    top = {n.split("/", 1)[0] for n in names}
    assert {"__init__.py", "blender_manifest.toml", "addon", "core", "wheels"} <= top
    assert not top & EXCLUDED_TOP
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or "egg-info" in n]
    assert "addon/contour_ops.py" in names and "core/resources/relief_1deg.npz" in names
    wheels, manifest = _manifest_wheels(z)
    assert sorted(wheels) == sorted(n for n in names if n.startswith("wheels/"))
    assert {be.wheel_name(w) for w in wheels} >= {"scipy", "xarray", "netcdf4", "pandas", "cftime", "nephele-native"}
    assert not {be.wheel_name(w) for w in wheels} & be.BLENDER_SHIPS  # numpy comes with Blender
    abi = be.TARGETS[py].abi
    for w in wheels:
        python_tag, abi_tag, platform_tag = Path(w).stem.split("-")[-3:]
        assert abi_tag in (abi, "abi3", "none"), w
        assert abi_tag != "abi3" or int(python_tag[2:]) <= int(abi[2:]), w
        assert python_tag in (abi, "py3", "py2.py3") or abi_tag == "abi3", w
        assert platform_tag == "any" or all("x86_64" in t and ("linux" in t) for t in platform_tag.split(".")), w
    assert 'platforms = ["linux-x64"]' in manifest
    assert f'blender_version_min = "{be.TARGETS[py].blender_min}"' in manifest


def test_offline_build_uses_the_cache(dist, tmp_path, capsys):
    _zip_for(dist, "3.13")  # fills the cache
    assert main(["build-extension", "--out", str(tmp_path), "--platform", "linux-x64", "--python", "3.13",
                 "--offline"]) == 0
    assert "fetching" not in capsys.readouterr().out
    assert len(list(tmp_path.glob("*.zip"))) == 1


def test_offline_without_wheels_is_one_line(tmp_path, capsys):
    code = main(["build-extension", "--out", str(tmp_path / "o"), "--platform", "windows-x64", "--python", "3.11",
                 "--offline", "--wheel-cache", str(tmp_path / "empty")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--offline" in err
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").glob("*.zip"))


def test_bad_manifest_is_refused(tmp_path):
    src = be.stage(tmp_path / "src")
    manifest = src / "blender_manifest.toml"
    text = manifest.read_text()
    # The extension platform refuses a tagline ending in punctuation.
    manifest.write_text(text.replace("\ntagline = ", '\ntagline = "Trailing punctuation."\n#', 1))
    cmd = be.builder_command()
    (tmp_path / "o").mkdir()
    res = subprocess.run(cmd + ["build", "--source-dir", str(src), "--output-dir", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert res.returncode != 0
    assert not list((tmp_path / "o").glob("*.zip"))


def test_missing_blender_is_usage_error():
    with pytest.raises(UsageError):
        be.builder_command("/no/such/blender")


def test_source_manifest_is_real():
    text = (ROOT / "blender_manifest.toml").read_text()
    assert "example.invalid" not in text and "website" not in text  # no placeholder page
    assert "network" not in text  # the add-on never goes online
    for reason in re.findall(r'(?m)^\w+ = "([^"]*)"$', text.split("[permissions]")[1].split("[")[0]):
        assert len(reason) <= 64 and reason[-1] not in ".!?,;:"
