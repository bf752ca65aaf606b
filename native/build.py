"""Build the compiled kernels: ``native/src/*.c`` into one shared library, packed as the
``nephele_native`` package (``--package DIR``) or a wheel (``--wheel DIR``).

The library uses no Python C API (it is loaded with ctypes), so the wheel is ``py3-none``
for this platform.  On Linux its tag is the manylinux level of the newest glibc symbol it
links.  ``BUILD_ID`` is a hash of the sources, the flags and the compiler's version.
"""

import argparse
import base64
import hashlib
import re
import shutil
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
LIB = "libnephele_kernels.so"


def sources():
    return sorted((HERE / "src").glob("*.c"))


def build_id(cc=CC):
    ver = subprocess.run([cc, "--version"], capture_output=True, text=True, check=True).stdout.splitlines()[0]
    h = hashlib.sha256(" ".join(FLAGS).encode() + b"\0" + ver.encode() + b"\0")
    for f in sources() + sorted((HERE / "src").glob("*.h")) + [HERE / "nephele_native" / "__init__.py"]:
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def package(dest, cc=CC):
    """Compile into ``dest/nephele_native`` (replaced whole); returns that folder."""
    if not sys.platform.startswith("linux"):
        raise SystemExit("native/build.py: only Linux builds are set up (other platforms use the NumPy kernels)")
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".nephele_native.", dir=dest))
    pkg = tmp / "nephele_native"
    pkg.mkdir()
    shutil.copy2(HERE / "nephele_native" / "__init__.py", pkg / "__init__.py")
    subprocess.run([cc, *FLAGS, "-o", str(pkg / LIB), *map(str, sources()), "-lm"], check=True)
    (pkg / "BUILD_ID").write_text(build_id(cc) + "\n")
    final = dest / "nephele_native"
    shutil.rmtree(final, ignore_errors=True)
    pkg.replace(final)
    tmp.rmdir()
    return final


def platform_tag(lib):
    """``manylinux_2_N_<arch>`` for the newest ``GLIBC_2.N`` symbol version ``lib`` needs."""
    arch = sysconfig.get_platform().split("-", 1)[1].replace("-", "_")
    need = [int(m) for m in re.findall(rb"GLIBC_2\.(\d+)", Path(lib).read_bytes())]
    return f"manylinux_2_{max(need + [17])}_{arch}"


def _record_line(name, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def wheel(dest, cc=CC):
    """Build the wheel into ``dest``; returns its path."""
    dest = Path(dest)
    with tempfile.TemporaryDirectory() as tmp:
        pkg = package(tmp, cc)
        tag = platform_tag(pkg / LIB)
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--package", help="build the nephele_native package into this folder")
    ap.add_argument("--wheel", help="build the wheel into this folder")
    ap.add_argument("--cc", default=CC)
    a = ap.parse_args()
    if a.package:
        print(package(a.package, a.cc))
    if a.wheel:
        print(wheel(a.wheel, a.cc))


if __name__ == "__main__":
    main()
