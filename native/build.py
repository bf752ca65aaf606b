"""Build the compiled kernels: ``native/src/*.c`` into one shared library, packed as the
``nephele_native`` package (``--package DIR``) or a wheel (``--wheel DIR``), for this Linux
machine or, cross-compiled from it, for Windows and macOS (``--target``).

The library uses no Python C API (it is loaded with ctypes), so the wheel is ``py3-none``
for its platform: on Linux the manylinux level of the newest glibc symbol it links
(built with this machine's ``cc``); ``win_amd64`` (a PE32+ DLL importing only the universal C
runtime, ucrtbase.dll); ``macosx_X_Y_arm64`` / ``_x86_64`` with X.Y the minimum macOS
written into the dylib (``--macos``).  Other platforms are built by ``zig cc`` from the
``ziglang`` package, which this script installs from PyPI into ``build/toolchain`` on first
use.  Each cross-built library is read back (:func:`describe`) and refused unless its format,
architecture, minimum macOS and imports are the platform's.  ``BUILD_ID`` is a hash of the
sources, the flags, the target and the compiler's version.
"""

import argparse
import base64
import hashlib
import os
import re
import shutil
import struct
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
VERSION = "0.1.0"
CC = "cc"
FLAGS = ["-O3", "-std=c11", "-fPIC", "-shared", "-fno-math-errno", "-Wall", "-Werror", "-Wno-psabi"]
# Cross builds: clang's default -ffp-contract=on would fuse a*b+c on arm64 (GCC's -std=c11 does not),
# and the kernels promise their NumPy twins' arithmetic operation by operation.
ZIG_FLAGS = ["-O3", "-std=c11", "-shared", "-fno-math-errno", "-ffp-contract=off", "-Wall", "-Werror", "-Wno-psabi"]
ZIG = "ziglang==0.17.0"
# Windows: the kernels call malloc, free, memcpy, memset and expf, all in the C runtime every Windows 10+
# has (ucrtbase.dll).  Linking that alone, without MinGW-w64's start-up code, spares zig building
# MinGW-w64's C runtime from source first (3.5 minutes from a cold cache, on every fresh clone); the DLL
# needs no entry point (the kernels keep no state), and compiler-rt still gives ___chkstk_ms, the
# stack probe of frames over 4 KiB.
WINDOWS_LINK = ["-nostdlib", "-rtlib=compiler-rt", "-lucrtbase"]
WINDOWS_DLL = ["-shared", "-Wl,--no-entry", *WINDOWS_LINK]
TOOLCHAIN = HERE.parent / "build" / "toolchain"
HOST = "linux-x64"
MACOS_MIN = "11.0"  # Blender 4.2's; the extension builder passes the version its zip's wheels need

# Blender platform -> (library file name, zig target without the macOS version, Mach-O/PE arch).
# The file names are nephele_native/__init__.py's, per sys.platform.
TARGETS = {
    "linux-x64": ("libnephele_kernels.so", None, "x86_64"),
    "windows-x64": ("nephele_kernels.dll", "x86_64-windows-gnu", "x86_64"),
    "macos-arm64": ("libnephele_kernels.dylib", "aarch64-macos", "arm64"),
    "macos-x64": ("libnephele_kernels.dylib", "x86_64-macos", "x86_64"),
}
LIB = TARGETS[HOST][0]
LIBSYSTEM = "/usr/lib/libSystem.B.dylib"


class BuildError(RuntimeError):
    """A library that is not what its platform loads (one line)."""


def sources():
    return sorted((HERE / "src").glob("*.c"))


def zig(toolchain=TOOLCHAIN):
    """The ``zig`` executable of the pinned ``ziglang`` wheel, pip-installed into ``toolchain`` once."""
    folder = Path(toolchain) / ZIG.replace("==", "-")
    exe = folder / "ziglang" / ("zig.exe" if sys.platform == "win32" else "zig")
    if not exe.is_file():
        print(f"installing the C cross-compiler ({ZIG}) from PyPI into {folder}", file=sys.stderr, flush=True)
        part = folder.with_name(folder.name + ".part")
        shutil.rmtree(part, ignore_errors=True)
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                        "--only-binary=:all:", "--target", str(part), ZIG], check=True)
        shutil.rmtree(folder, ignore_errors=True)
        part.replace(folder)
    return exe


def _zig_env(exe):
    cache = str(Path(exe).parents[2] / "zig-cache")  # beside the toolchain: no ~/.cache
    return {**os.environ, "ZIG_GLOBAL_CACHE_DIR": cache, "ZIG_LOCAL_CACHE_DIR": cache}


def compiler(target=HOST, cc=CC, macos=None, toolchain=TOOLCHAIN):
    """``(command, flags, version, env)`` that compile ``native/src`` for ``target``."""
    lib, triple, _ = TARGETS[target]
    if triple is None and not sys.platform.startswith("linux"):
        triple, flags = "x86_64-linux-gnu.2.27", ZIG_FLAGS + ["-fPIC"]  # from elsewhere: zig, glibc 2.27
    elif triple is None:
        ver = subprocess.run([cc, "--version"], capture_output=True, text=True, check=True).stdout.splitlines()[0]
        return [cc], FLAGS, ver, None
    exe = zig(toolchain)
    env = _zig_env(exe)
    ver = "zig " + subprocess.run([str(exe), "version"], capture_output=True, text=True, check=True,
                                  env=env).stdout.strip()
    flags = list(ZIG_FLAGS) if target != HOST else flags
    if target.startswith("macos"):
        triple += "." + (macos or MACOS_MIN)
        flags.append(f"-Wl,-install_name,@rpath/{lib}")  # not this machine's build path
    if target == "windows-x64":
        flags += [f for f in WINDOWS_DLL if f not in flags]
    return [str(exe), "cc", "-target", triple], flags, ver, env


def build_id(cc=CC, target=HOST, macos=None, toolchain=TOOLCHAIN):
    cmd, flags, ver, _ = compiler(target, cc, macos, toolchain)
    # The id of a build with this machine's cc is the hash it always was (cached frames keep their
    # keys); a zig build adds its target (with the minimum macOS) to its flags.
    head = " ".join(flags) if len(cmd) == 1 else " ".join(cmd[2:] + flags)
    h = hashlib.sha256(head.encode() + b"\0" + ver.encode() + b"\0")
    for f in sources() + sorted((HERE / "src").glob("*.h")) + [HERE / "nephele_native" / "__init__.py"]:
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def package(dest, cc=CC, target=HOST, macos=None, toolchain=TOOLCHAIN):
    """Compile into ``dest/nephele_native`` (replaced whole); returns that folder."""
    lib = TARGETS[target][0]
    cmd, flags, _, env = compiler(target, cc, macos, toolchain)
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".nephele_native.", dir=dest))
    pkg = tmp / "nephele_native"
    pkg.mkdir()
    shutil.copy2(HERE / "nephele_native" / "__init__.py", pkg / "__init__.py")
    obj = tmp / "obj"  # the compiler's by-products (zig writes a .pdb beside a DLL) stay out of the wheel
    obj.mkdir()
    if target == "windows-x64":
        _windows_dll(cmd, flags, obj / lib, env)
    else:
        subprocess.run([*cmd, *flags, "-o", str(obj / lib), *map(str, sources()), "-lm"], check=True, env=env)
    (obj / lib).replace(pkg / lib)
    shutil.rmtree(obj)
    if target != HOST:  # (the Linux build's check is its glibc tag, below)
        check(pkg / lib, target, macos or MACOS_MIN)
    (pkg / "BUILD_ID").write_text(build_id(cc, target, macos, toolchain) + "\n")
    final = dest / "nephele_native"
    shutil.rmtree(final, ignore_errors=True)
    pkg.replace(final)
    tmp.rmdir()
    return final


def _windows_dll(cmd, flags, out, env):
    """Compile each source against MinGW-w64's headers, then link the objects into ``out`` with the
    UCRT alone (``-nostdlib`` also drops the headers, so the two steps are apart)."""
    objs = []
    for src in sources():
        objs.append(str(out.parent / (src.stem + ".o")))
        subprocess.run([*cmd, *[f for f in flags if f not in WINDOWS_DLL], "-c", "-o", objs[-1], str(src)],
                       check=True, env=env)
    subprocess.run([*cmd, *WINDOWS_DLL, "-o", str(out), *objs], check=True, env=env)


def platform_tag(lib, target=HOST, macos=None):
    """The wheel's platform tag: ``manylinux_2_N_<arch>`` for the newest ``GLIBC_2.N`` symbol version
    ``lib`` needs, ``win_amd64``, or ``macosx_X_Y_<arch>`` for the minimum macOS X.Y."""
    if target == "windows-x64":
        return "win_amd64"
    if target.startswith("macos"):
        major, minor = (macos or MACOS_MIN).split(".")[:2]
        return f"macosx_{major}_{minor}_{TARGETS[target][2]}"
    arch = sysconfig.get_platform().split("-", 1)[1].replace("-", "_")
    need = [int(m) for m in re.findall(rb"GLIBC_2\.(\d+)", Path(lib).read_bytes())]
    return f"manylinux_2_{max(need + [17])}_{arch}"


def _record_line(name, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def wheel(dest, cc=CC, target=HOST, macos=None, toolchain=TOOLCHAIN):
    """Build the wheel for ``target`` into ``dest``; returns its path."""
    dest = Path(dest)
    with tempfile.TemporaryDirectory() as tmp:
        pkg = package(tmp, cc, target, macos, toolchain)
        tag = platform_tag(pkg / TARGETS[target][0], target, macos)
        dist = f"nephele_native-{VERSION}.dist-info"
        files = {f"nephele_native/{p.name}": p.read_bytes() for p in sorted(pkg.iterdir())}
        files[f"{dist}/METADATA"] = (f"Metadata-Version: 2.1\nName: nephele-native\nVersion: {VERSION}\n"
                                     "Summary: Nephele's compiled kernels (ctypes)\n").encode()
        files[f"{dist}/WHEEL"] = (f"Wheel-Version: 1.0\nGenerator: nephele native/build.py\n"
                                  f"Root-Is-Purelib: false\nTag: py3-none-{tag}\n").encode()
        record = [_record_line(n, d) for n, d in files.items()] + [f"{dist}/RECORD,,"]
        files[f"{dist}/RECORD"] = ("\n".join(record) + "\n").encode()
        dest.mkdir(parents=True, exist_ok=True)
        out = dest / f"nephele_native-{VERSION}-py3-none-{tag}.whl"
        part = dest / f".{out.name}.part"
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
            for n, d in files.items():
                z.writestr(n, d)
        part.replace(out)
        return out


# --- reading the libraries back ---------------------------------------------------------------------------------

def _pe(data):
    """PE32+ facts: machine, DLL flag, imported DLLs, exported names."""
    pe = struct.unpack_from("<I", data, 0x3C)[0]
    if data[pe : pe + 4] != b"PE\0\0":
        raise BuildError("not a PE file")
    machine, nsec, _, _, _, opt_size, chars = struct.unpack_from("<HHIIIHH", data, pe + 4)
    opt = pe + 24
    if struct.unpack_from("<H", data, opt)[0] != 0x20B:
        raise BuildError("not PE32+")
    dirs = [struct.unpack_from("<II", data, opt + 112 + 8 * i) for i in range(2)]  # export, import
    sections = [struct.unpack_from("<IIII", data, opt + opt_size + 40 * i + 8) for i in range(nsec)]

    def off(rva):  # file offset of an RVA
        for vsize, va, rsize, raw in sections:
            if va <= rva < va + max(vsize, rsize):
                return raw + rva - va
        raise BuildError(f"RVA {rva:#x} in no section")

    def cstr(rva):
        o = off(rva)
        return data[o : data.index(b"\0", o)].decode()

    needs, exports = [], []
    if dirs[1][0]:
        o = off(dirs[1][0])
        while struct.unpack_from("<5I", data, o) != (0,) * 5:
            needs.append(cstr(struct.unpack_from("<I", data, o + 12)[0]))
            o += 20
    if dirs[0][0]:
        n, names = struct.unpack_from("<I4xI", data, off(dirs[0][0]) + 24)
        exports = [cstr(struct.unpack_from("<I", data, off(names) + 4 * i)[0]) for i in range(n)]
    arch = {0x8664: "x86_64", 0xAA64: "arm64"}.get(machine, hex(machine))
    return {"format": "PE32+ DLL" if chars & 0x2000 else "PE32+", "arch": arch, "needs": needs,
            "exports": exports, "undefined": []}


def _macho(data):
    """64-bit Mach-O facts: arch, file type, minimum macOS, dylibs, undefined and exported symbols."""
    _, cpu, _, ftype, ncmds = struct.unpack_from("<IiIII", data, 0)
    arch = {0x0100000C: "arm64", 0x01000007: "x86_64"}.get(cpu, hex(cpu))
    o, minos, needs, symtab = 32, None, [], None
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<II", data, o)
        if cmd == 0x32:  # LC_BUILD_VERSION
            v = struct.unpack_from("<I", data, o + 12)[0]
            minos = f"{v >> 16}.{(v >> 8) & 0xFF}"
        elif cmd == 0x24:  # LC_VERSION_MIN_MACOSX
            v = struct.unpack_from("<I", data, o + 8)[0]
            minos = f"{v >> 16}.{(v >> 8) & 0xFF}"
        elif cmd in (0xC, 0x80000018, 0x8000001F, 0x80000023):  # LC_(LOAD|LOAD_WEAK|REEXPORT|LOAD_UPWARD)_DYLIB
            name = o + struct.unpack_from("<I", data, o + 8)[0]
            needs.append(data[name : data.index(b"\0", name)].decode())
        elif cmd == 0x2:  # LC_SYMTAB
            symtab = struct.unpack_from("<IIII", data, o + 8)
        o += size
    undefined, exports = [], []
    if symtab:
        symoff, nsyms, stroff, _ = symtab
        for i in range(nsyms):
            strx, ntype, _, desc, _ = struct.unpack_from("<IBBHQ", data, symoff + 16 * i)
            if ntype & 0xE0 or not ntype & 1:  # debug entries, local symbols
                continue
            name = data[stroff + strx : data.index(b"\0", stroff + strx)].decode()
            if ntype & 0x0E == 0:  # N_UNDF: (name, dylib it binds to: 1-based, 0 = self / flat)
                ordinal = desc >> 8
                undefined.append((name, needs[ordinal - 1] if 0 < ordinal <= len(needs) else ordinal))
            elif ntype & 0x0E == 0x0E:
                exports.append(name.removeprefix("_"))
    kind = {6: "Mach-O dylib"}.get(ftype, f"Mach-O type {ftype}")
    return {"format": kind, "arch": arch, "minos": minos, "needs": needs, "undefined": undefined, "exports": exports}


def describe(path):
    """What a platform's loader sees in a cross-built library (PE32+ or 64-bit Mach-O): format,
    arch, needs (DLLs / dylibs), exports, undefined symbols with their dylib, and Mach-O's minos."""
    data = Path(path).read_bytes()
    if data[:2] == b"MZ":
        return _pe(data)
    if data[:4] == b"\xcf\xfa\xed\xfe":
        return _macho(data)
    raise BuildError(f"{path}: neither a PE32+ nor a 64-bit Mach-O file")


def system_dll(name):
    """Whether a DLL is one every Windows 10+ has: KERNEL32 or the universal C runtime (ucrtbase.dll
    or its api-ms-win-crt-* sets)."""
    n = name.lower()
    return n in ("kernel32.dll", "ucrtbase.dll") or (n.startswith("api-ms-win-crt-") and n.endswith(".dll"))


def check(path, target, macos=MACOS_MIN):
    """Raise :class:`BuildError` unless ``path`` is the library ``target`` loads: a PE32+ x86-64 DLL
    importing only system DLLs, or a Mach-O dylib of the arch and minimum macOS linking only
    libSystem; returns :func:`describe`'s facts."""
    info = describe(path)
    arch = TARGETS[target][2]
    problems = []
    if target == "windows-x64":
        if info["format"] != "PE32+ DLL" or info["arch"] != arch:
            problems.append(f"{info['format']} {info['arch']}, not a PE32+ {arch} DLL")
        problems += [f"imports {d} (not a system DLL)" for d in info["needs"] if not system_dll(d)]
    else:
        if info["format"] != "Mach-O dylib" or info["arch"] != arch:
            problems.append(f"{info['format']} {info['arch']}, not a Mach-O {arch} dylib")
        if info["minos"] != macos:
            problems.append(f"minimum macOS {info['minos']}, not {macos}")
        problems += [f"links {d} (not libSystem)" for d in info["needs"] if d != LIBSYSTEM]
        problems += [f"symbol {s} binds to {d!r}, not libSystem" for s, d in info["undefined"] if d != LIBSYSTEM]
    if problems:
        raise BuildError(f"{path} ({target}): " + "; ".join(problems))
    return info


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--package", help="build the nephele_native package into this folder")
    ap.add_argument("--wheel", help="build the wheel into this folder")
    ap.add_argument("--target", default=HOST, choices=sorted(TARGETS),
                    help=f"platform to build for (default {HOST}; others are cross-compiled with zig)")
    ap.add_argument("--macos", default=None, help=f"minimum macOS of a macos-* build (default {MACOS_MIN})")
    ap.add_argument("--cc", default=CC, help="C compiler of the linux-x64 build")
    ap.add_argument("--toolchain", default=str(TOOLCHAIN), help="folder the ziglang wheel is installed into")
    a = ap.parse_args()
    try:
        if a.package:
            print(package(a.package, a.cc, a.target, a.macos, a.toolchain))
        if a.wheel:
            print(wheel(a.wheel, a.cc, a.target, a.macos, a.toolchain))
    except BuildError as e:
        raise SystemExit(f"native/build.py: {e}") from None


if __name__ == "__main__":
    main()
