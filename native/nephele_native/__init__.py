"""Nephele's compiled kernels, loaded with ctypes (no Python C API: one build serves every Python).

``lib`` is the shared library; callers declare each function's argument types where
they wrap it.  ``BUILD_ID`` names the sources, compiler flags, target and compiler it was
built from (cache keys use it, so a result made by one build is never served to another).
"""

import ctypes
import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
# The file each platform's wheel carries (native/build.py's TARGETS).
LIBRARIES = {"win32": "nephele_kernels.dll", "darwin": "libnephele_kernels.dylib"}


def library_file(platform=sys.platform):
    """The library's file name on ``platform`` (a ``sys.platform`` value)."""
    return LIBRARIES.get(platform, "libnephele_kernels.so")


BUILD_ID = (_HERE / "BUILD_ID").read_text().strip()
lib = ctypes.CDLL(str(_HERE / library_file()))
