"""The package layout promises: core never needs Blender, the manifest is valid for the extension platform."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_core_imports_without_bpy():
    # A fresh interpreter where bpy cannot be imported at all.
    code = (
        "import sys, importlib, pkgutil\n"
        "sys.modules['bpy'] = None\n"
        "import nephele, nephele.core\n"
        "for m in pkgutil.iter_modules(nephele.core.__path__):\n"
        "    importlib.import_module('nephele.core.' + m.name)\n"
        "assert sys.modules['bpy'] is None\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_no_blender_imports_in_core():
    offenders = []
    for path in (ROOT / "core").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            offenders += [f"{path.name}: {n}" for n in names if n.split(".")[0] in ("bpy", "mathutils", "bmesh")]
    assert offenders == []


def test_extension_code_imports_itself_relatively():
    # Installed as an extension the package is bl_ext.user_default.nephele: an absolute
    # "nephele" import inside the add-on or core fails there (no such top-level module).
    offenders = []
    for part in ("addon", "core"):
        for path in (ROOT / part).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                offenders += [f"{path.relative_to(ROOT)}:{node.lineno}" for n in names if n.split(".")[0] == "nephele"]
    assert offenders == []


def test_manifest_fields():
    tomllib = pytest.importorskip("tomllib")
    m = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert m["id"] == "nephele" and m["type"] == "add-on"
    assert m["blender_version_min"] == "4.2.0"
    for text in [m["tagline"], *m.get("permissions", {}).values()]:
        assert len(text) <= 64 and text[-1] not in ".!?,;:"
    excludes = m["build"]["paths_exclude_pattern"]
    for required in ("__pycache__/", ".*", "/*.zip", "*.blend[1-9]", "/tests/", "/farm/", "/examples/"):
        assert required in excludes


def test_former_flat_names_warn_until_they_end():
    import nephele.core as core
    from nephele.core.climate import grid

    with pytest.warns(DeprecationWarning, match="ends in Nephele 0.2: use nephele.core.climate.grid"):
        assert core.grid is grid
    with pytest.raises(AttributeError):
        _ = core.no_such_name
