"""The extension zip: built and validated by Blender's own tool, add-on and core inside,
nothing else, and it registers when imported under another package name (as
Blender does: ``bl_ext.<repo>.nephele``)."""

import subprocess
import sys
import textwrap
import zipfile

import pytest

from nephele.farm import cmd_build_extension
from nephele.farm.cli import UsageError, main


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    assert main(["build-extension", "--out", str(out)]) == 0
    zips = list(out.glob("*.zip"))
    assert len(zips) == 1
    return zips[0]


def test_zip_contents(built_zip):
    names = zipfile.ZipFile(built_zip).namelist()
    top = {n.split("/", 1)[0] for n in names}
    assert {"__init__.py", "blender_manifest.toml", "addon", "core"} <= top
    for left_out in ("tests", "farm", "examples", "benchmarks", "docs", ".venv", "out"):
        assert left_out not in top
    assert "addon/contour_ops.py" in names and "core/contour.py" in names
    assert "core/resources/relief_1deg.npz" in names
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or "egg-info" in n]


def test_zip_validates(built_zip):
    cmd = cmd_build_extension.builder_command()
    res = subprocess.run(cmd + ["validate", str(built_zip)], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


def test_bad_manifest_is_refused(tmp_path):
    src = cmd_build_extension.stage(tmp_path / "src")
    manifest = src / "blender_manifest.toml"
    text = manifest.read_text()
    # The extension platform refuses a tagline ending in punctuation.
    manifest.write_text(text.replace("\ntagline = ", '\ntagline = "Trailing punctuation."\n#', 1))
    cmd = cmd_build_extension.builder_command()
    (tmp_path / "o").mkdir()
    res = subprocess.run(cmd + ["build", "--source-dir", str(src), "--output-dir", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert res.returncode != 0
    assert not list((tmp_path / "o").glob("*.zip"))


def test_missing_blender_is_usage_error():
    with pytest.raises(UsageError):
        cmd_build_extension.builder_command("/no/such/blender")


@pytest.mark.slow
def test_zip_registers_under_another_name(built_zip, tmp_path):
    # Unpack as package "bl_ext_test_nephele": relative imports must resolve inside it.
    pkg = tmp_path / "bl_ext_test_nephele"
    zipfile.ZipFile(built_zip).extractall(pkg)
    script = textwrap.dedent(f"""
        import sys, bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        sys.path.insert(0, {str(tmp_path)!r})
        import bl_ext_test_nephele as ext
        ext.register()
        assert hasattr(bpy.types, "NEPHELE_PT_main")
        assert bpy.ops.nephele.add_globe() == {{"FINISHED"}}
        assert "Nephele Globe" in bpy.data.objects
        ext.unregister()
        mods = [m for m in sys.modules if m == "nephele" or m.startswith("nephele.")]
        print("OK", mods)
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "OK []" in res.stdout, res.stdout
