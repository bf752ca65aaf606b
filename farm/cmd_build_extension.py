"""``nephele build-extension``: the add-on as a Blender extension zip, built and validated
by Blender's own extension tool.

Only the extension's parts (``__init__.py``, ``blender_manifest.toml``,
``addon/``, ``core/``, ``README.md``, licence files) are staged in a temporary
directory, so nothing local (virtual environments, egg-info, outputs) leaks
in; the manifest's ``[build]`` excludes still apply (caches, tests, farm,
examples, benchmarks, docs).  The builder is ``blender_ext.py`` from the
``bpy`` wheel (``.../scripts/addons_core/bl_pkg/cli/``), run with this Python,
or ``blender --command extension`` when ``--blender`` is given.
"""

import importlib.util
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from .cli import UsageError

HELP = "build the Blender extension zip (add-on + core) and validate it"

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("__init__.py", "blender_manifest.toml", "addon", "core", "README.md", "LICENSE", "LICENSE.txt", "COPYING")


def add_arguments(p):
    p.add_argument("--out", default="dist", help="output directory (default: dist)")
    p.add_argument("--blender", default=None, help="use this Blender executable instead of the bpy wheel's builder")


def builder_command(blender=None):
    """The command prefix that runs Blender's extension tool (``... build`` / ``... validate``)."""
    if blender:
        exe = shutil.which(blender) or blender
        if not Path(exe).exists():
            raise UsageError(f"Blender executable not found: {blender}")
        return [exe, "--background", "--factory-startup", "--command", "extension"]
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise UsageError("the bpy module is not installed; pass --blender /path/to/blender")
    for base in spec.submodule_search_locations:
        hits = sorted(Path(base).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
        if hits:
            return [sys.executable, str(hits[-1])]
    raise UsageError("Blender's extension builder (blender_ext.py) is not in the bpy package")


def stage(dest, root=ROOT):
    """Copy the extension's parts from ``root`` into ``dest`` (no caches)."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")
    dest.mkdir(parents=True, exist_ok=True)
    for name in PARTS:
        src = root / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, dest / name)
    return dest


def _check(cmd, what):
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise UsageError(f"{what} failed ({res.returncode}): {(res.stdout + res.stderr).strip()}")
    return res.stdout


def build(out="dist", blender=None):
    """Build and validate the zip into ``out``; returns its path."""
    cmd = builder_command(blender)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="nephele-ext-") as tmp:
        src = stage(Path(tmp) / "nephele")
        build_dir = Path(tmp) / "out"
        build_dir.mkdir()
        _check(cmd + ["build", "--source-dir", str(src), "--output-dir", str(build_dir)], "extension build")
        zips = sorted(build_dir.glob("*.zip"))
        if len(zips) != 1:
            raise UsageError(f"extension build produced {len(zips)} zip files")
        _check(cmd + ["validate", str(zips[0])], "extension validate")
        target = out / zips[0].name
        # Copy beside the target, then rename: never a half-written zip in --out.
        tmp_target = out / f".{zips[0].name}.tmp"
        shutil.copy2(zips[0], tmp_target)
        tmp_target.replace(target)
    return target


def run(args):
    path = build(args.out, args.blender)
    print(f"built and validated {path}")
    return 0
