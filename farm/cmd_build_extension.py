"""``nephele build-extension``: the add-on as Blender extension zips, one per
platform and Blender Python, each with the third-party wheels the add-on
imports, built and validated by Blender's own extension tool.

Blender 4.2-5.0 ship Python 3.11 + numpy 1.26, Blender 5.1 and later Python
3.13 + numpy 2.x, so each platform gets two zips whose manifests carry
``blender_version_min``/``blender_version_max``.  The bundled packages are
scipy (advection, dome remapping, scattering views, the relief reader) and
xarray + netCDF4 (NetCDF import) with what they pull in (pandas, cftime,
dateutil, tzdata, packaging), pinned to the versions the test suite runs
(``requirements.txt`` for Python 3.13, ``requirements-core311.txt`` for
3.11).  Blender's own packages (numpy, certifi, requests, ...) are never
bundled.

Wheels come from ``pip download --only-binary=:all: --platform ...
--python-version ...`` into a cache folder (``build/wheels`` by default), one
sub-folder per (Python, platform) stamped with what it holds; a complete
sub-folder is reused without the network, and ``--offline`` refuses to fetch.
Only the extension's parts (``__init__.py``, ``blender_manifest.toml``,
``addon/``, ``core/``, ``README.md``, licence files) are staged, so nothing
local leaks in; the manifest's ``[build]`` excludes still apply.  The zip for
every platform carries the compiled kernels (``native/``, built here from
source as that platform's ``nephele_native`` wheel: this machine's ``cc`` for
Linux, ``zig cc`` from the ``ziglang`` package for Windows and macOS, the dylibs
with the minimum macOS of the zip's other wheels), each read back and refused
unless its format, architecture and imports are the platform's.  The builder
is ``blender_ext.py`` from the ``bpy`` wheel, or ``blender --command
extension`` when ``--blender`` is given.
"""

import importlib.util
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import UsageError

HELP = "build the Blender extension zips (one per platform and Blender Python), wheels bundled"

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("__init__.py", "fileio.py", "volume_files.py", "blender_manifest.toml", "addon", "core", "README.md",
         "LICENSE", "LICENSE.txt", "COPYING")

# Packages the add-on imports that Blender does not ship, and what they pull in, all pinned
# in the requirement files the tests run on, so a zip built another day bundles the same
# wheels that were tested.
BUNDLED = ("scipy", "xarray", "netCDF4", "pandas", "cftime", "python-dateutil", "tzdata", "packaging")
# Blender's bundled Python already has these: never put them in the zip.
BLENDER_SHIPS = frozenset({"numpy", "certifi", "requests", "urllib3", "idna", "charset-normalizer",
                           "zstandard", "cython"})

# Blender platform -> pip platform tags, tried in order until every pinned package resolves
# (Blender 4.2+ needs glibc 2.28 and macOS 11.2; some pins have only newer macOS wheels, so the
# oldest macOS that works is used; pip accepts older tags of the same kind too).
PLATFORM_TAGS = {
    "linux-x64": (("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),),
    "windows-x64": (("win_amd64",),),
    "macos-arm64": tuple((f"macosx_{v}_0_arm64",) for v in (11, 12, 14, 15)),
    "macos-x64": tuple((f"macosx_{v}_0_x86_64",) for v in (11, 12, 14, 15)),
}


@dataclass(frozen=True)
class Target:
    """One Blender Python: which Blenders run it and which pins its wheels use."""

    python: str  # "3.11"
    blender_min: str
    blender_max: str | None  # exclusive
    numpy: str  # numpy requirement used only to resolve compatible wheels
    requirements_file: str
    platforms: tuple

    @property
    def abi(self):
        return "cp" + self.python.replace(".", "")

    @property
    def label(self):
        if self.blender_max is None:
            return f"blender{_short(self.blender_min)}-and-later"
        return f"blender{_short(self.blender_min)}-{_previous(self.blender_max)}"


def _short(version):
    return ".".join(version.split(".")[:2])


def _previous(version_max):
    major, minor = (int(x) for x in version_max.split(".")[:2])
    return f"{major}.{minor - 1}" if minor else f"{major - 1}.x"


TARGETS = {
    # No Intel-Mac Blender after 4.5 and no bpy 5.1+ for it: macos-x64 only here.
    "3.11": Target("3.11", "4.2.0", "5.1.0", "numpy==1.26.4", "requirements-core311.txt",
                   ("linux-x64", "windows-x64", "macos-arm64", "macos-x64")),
    "3.13": Target("3.13", "5.1.0", None, "numpy==2.2.*", "requirements.txt",
                   ("linux-x64", "windows-x64", "macos-arm64")),
}


def add_arguments(p):
    p.add_argument("--out", default="dist", help="output directory (default: dist)")
    p.add_argument("--blender", default=None, help="use this Blender executable instead of the bpy wheel's builder")
    p.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS), dest="platforms",
                   help="build only for this platform (repeatable; default: every platform with wheels)")
    p.add_argument("--python", action="append", choices=sorted(TARGETS), dest="pythons",
                   help="build only for this Blender Python: 3.11 = Blender 4.2-5.0, 3.13 = 5.1+ (default: both)")
    p.add_argument("--wheel-cache", default=str(ROOT / "build" / "wheels"),
                   help="folder of downloaded wheels, reused offline (default: build/wheels)")
    p.add_argument("--offline", action="store_true", help="never contact PyPI; use only --wheel-cache")


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


def pinned_requirements(target, root=ROOT):
    """The ``BUNDLED`` pins of ``target``'s requirement file, e.g. ``["scipy==1.18.1", ...]``."""
    path = root / target.requirements_file
    if not path.is_file():
        raise UsageError(f"{path}: missing (the wheel pins for Python {target.python} are read from it)")
    pins = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\s*([A-Za-z0-9_.-]+)\s*==\s*([^\s;#]+)", line)
        if m and m.group(1).lower() in {b.lower() for b in BUNDLED}:
            pins[m.group(1).lower()] = f"{m.group(1)}=={m.group(2)}"
    missing = [b for b in BUNDLED if b.lower() not in pins]
    if missing:
        raise UsageError(f"{path}: no exact pin (name==version) for {', '.join(missing)}")
    return [pins[b.lower()] for b in BUNDLED]


def wheel_name(path):
    """The normalised distribution name of a wheel file (``netcdf4``, ``python-dateutil``)."""
    return re.sub(r"[-_.]+", "-", Path(path).name.split("-")[0]).lower()


def _cache_folder(target, platform, cache):
    return Path(cache) / f"{target.abi}-{platform}"


def macos_minimum(target, platform, cache):
    """The minimum macOS of ``platform``'s fetched wheels (``"14.0"`` for ``macosx_14_0_arm64``), the
    version the zip's kernels are built for; None off macOS."""
    if not platform.startswith("macos"):
        return None
    tags = (_cache_folder(target, platform, cache) / "tags.txt").read_text().split()
    return ".".join(re.match(r"macosx_(\d+)_(\d+)_", tags[0]).groups())


def fetch_wheels(target, platform, cache, offline=False, root=ROOT):
    """The wheels to bundle for ``target`` on ``platform``, downloaded into ``cache`` once.

    A cache sub-folder is complete when its ``request.txt`` equals this
    request; it is then reused without the network (``tags.txt`` says which
    platform tags resolved).  A fresh download goes to a temporary sibling that
    replaces the sub-folder only when pip succeeded.
    """
    request = pinned_requirements(target, root) + [target.numpy]
    alternatives = PLATFORM_TAGS[platform]
    stamp_text = "\n".join(request + [" ".join(tags) for tags in alternatives]) + "\n"
    cache = Path(cache)
    folder = _cache_folder(target, platform, cache)
    stamp = folder / "request.txt"
    if not (stamp.is_file() and stamp.read_text() == stamp_text):
        if offline:
            raise UsageError(f"wheels for Python {target.python} {platform} are not in {cache} "
                             "(run once without --offline to fetch them)")
        cache.mkdir(parents=True, exist_ok=True)
        part = cache / f".{folder.name}.part"
        for tags in alternatives:
            print(f"fetching wheels for Blender's Python {target.python} on {platform} ({tags[0]}) from PyPI: "
                  f"{' '.join(request[:-1])} and their dependencies", flush=True)
            shutil.rmtree(part, ignore_errors=True)
            cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--only-binary=:all:",
                   "--python-version", target.python, "--implementation", "cp",
                   "--abi", target.abi, "--abi", "abi3", "--abi", "none", "--dest", str(part)]
            for tag in tags:
                cmd += ["--platform", tag]
            res = subprocess.run(cmd + request, capture_output=True, text=True)
            if res.returncode == 0:
                break
        else:
            shutil.rmtree(part, ignore_errors=True)
            last = (res.stderr.strip() or res.stdout.strip()).splitlines()[-1:] or ["no output"]
            raise UsageError(f"pip could not fetch wheels for Python {target.python} {platform}: {last[0]}")
        (part / "tags.txt").write_text(" ".join(tags) + "\n")
        (part / "request.txt").write_text(stamp_text)
        shutil.rmtree(folder, ignore_errors=True)
        part.replace(folder)
    wheels = sorted(p for p in folder.glob("*.whl") if wheel_name(p) not in BLENDER_SHIPS)
    if not {b.lower() for b in BUNDLED} <= {wheel_name(w) for w in wheels}:
        raise UsageError(f"{folder}: incomplete wheel set; delete it and build again")
    return wheels


def native_wheel(dest, platform="linux-x64", macos=None, root=ROOT):
    """Build the compiled kernels' wheel for ``platform`` into ``dest`` (from ``root/native``); returns its path."""
    spec = importlib.util.spec_from_file_location("nephele_native_build", root / "native" / "build.py")
    build = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build)
    try:
        return build.wheel(dest, target=platform, macos=macos, toolchain=root / "build" / "toolchain")
    except (OSError, subprocess.CalledProcessError, build.BuildError) as e:
        raise UsageError(f"building the compiled kernels (native/) for {platform} failed: {e}") from None


def write_manifest(path, target, platforms, wheels):
    """Set ``platforms``, ``wheels`` and the Blender version range in a staged manifest."""
    text = path.read_text(encoding="utf-8")  # (TOML is UTF-8; Windows' default is its code page)
    lines = [f'blender_version_min = "{target.blender_min}"']
    if target.blender_max:
        lines.append(f'blender_version_max = "{target.blender_max}"')
    lines.append("platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]")
    lines.append("wheels = [\n" + "".join(f'  "./wheels/{w.name}",\n' for w in wheels) + "]")
    new, n = re.subn(r'(?m)^blender_version_min\s*=.*$', lambda _m: "\n".join(lines), text)
    if n != 1 or re.search(r"(?m)^(platforms|wheels|blender_version_max)\s*=", text):
        raise UsageError(f"{path}: expected one blender_version_min and no platforms/wheels/blender_version_max")
    path.write_text(new, encoding="utf-8")


def _check(cmd, what):
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise UsageError(f"{what} failed ({res.returncode}): {(res.stdout + res.stderr).strip()}")
    return res.stdout


def build_target(target, platforms, out, cmd, cache, offline=False, root=ROOT):
    """Build, validate and copy into ``out`` one zip per platform for one Blender Python."""
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="nephele-ext-") as tmp:
        src = stage(Path(tmp) / "nephele", root)
        (src / "wheels").mkdir()
        names = set()
        for platform in platforms:
            for w in fetch_wheels(target, platform, cache, offline, root):
                if w.name not in names:
                    shutil.copy2(w, src / "wheels" / w.name)
                    names.add(w.name)
            kernels = native_wheel(src / "wheels", platform, macos_minimum(target, platform, cache), root)
            print(f"compiled kernels for {platform}: {kernels.name}", flush=True)
        wheels = sorted((src / "wheels").glob("*.whl"))
        write_manifest(src / "blender_manifest.toml", target, platforms, wheels)
        build_dir = Path(tmp) / "out"
        build_dir.mkdir()
        _check(cmd + ["build", "--split-platforms", "--source-dir", str(src), "--output-dir", str(build_dir)],
               "extension build")
        zips = sorted(build_dir.glob("*.zip"))
        if len(zips) != len(platforms):
            raise UsageError(f"extension build produced {len(zips)} zip files for {len(platforms)} platforms")
        built = []
        for z in zips:
            _check(cmd + ["validate", str(z)], "extension validate")
            # nephele-0.1.0-linux_x64.zip -> nephele-0.1.0-blender5.1-and-later-linux_x64.zip
            stem, plat = z.stem.rsplit("-", 1)
            target_path = out / f"{stem}-{target.label}-{plat}.zip"
            # Copy beside the target, then rename: never a half-written zip in --out.
            part = out / f".{target_path.name}.part"
            shutil.copy2(z, part)
            part.replace(target_path)
            built.append(target_path)
    return built


def build(out="dist", blender=None, platforms=None, pythons=None, wheel_cache=None, offline=False):
    """Build every requested (Python, platform) zip into ``out``; returns their paths."""
    cmd = builder_command(blender)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(wheel_cache) if wheel_cache else ROOT / "build" / "wheels"
    built = []
    for py in pythons or sorted(TARGETS):
        target = TARGETS[py]
        plats = [p for p in target.platforms if not platforms or p in platforms]
        if plats:
            built += build_target(target, plats, out, cmd, cache, offline)
    if not built:
        raise UsageError("no zip to build: none of the requested platforms has a build for the requested Python")
    return built


def run(args):
    for path in build(args.out, args.blender, args.platforms, args.pythons, args.wheel_cache, args.offline):
        print(f"built and validated {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0
