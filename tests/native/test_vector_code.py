"""The installed Linux library's hot loops are vector code.

GCC decides per build whether a loop vectorizes, and unrelated edits moved that decision: renaming a
zeroing helper left the profile rows scalar (the sweeps 4x as slow, the results bit-identical, every
test green), and its inlining budget once left ``nph_expf`` a call inside the second-moment rows.
So the row kernels are functions of their own and the math helpers are always inlined; this reads
the machine code of the x86-64-v4 clones (the ones this and most current x86 machines run).
"""

import platform
import re
import shutil
import subprocess
import sys

import pytest
from cross_tools import unavailable

from nephele.core import native

PACKED = re.compile(r"\sv(?:mul|add|sub|div)ps\s")


@pytest.fixture(scope="module")
def library():
    if not (sys.platform.startswith("linux") and platform.machine() == "x86_64"):
        pytest.skip("the target clones are built for x86-64 Linux (GCC)")
    mod = native._module()
    if mod is None:
        unavailable("the compiled kernels are not installed (make .venv/.native)")
    for tool in ("nm", "objdump"):
        if shutil.which(tool) is None:
            unavailable(f"{tool} (binutils) is missing: apt-get install binutils")
    return mod.lib._name


def _symbols(lib):
    out = subprocess.run(["nm", lib], capture_output=True, text=True, check=True).stdout
    return [line.split()[-1] for line in out.splitlines() if len(line.split()) == 3]


def _code(lib, symbol):
    return subprocess.run(["objdump", "-d", "--no-show-raw-insn", f"--disassemble={symbol}", lib],
                          capture_output=True, text=True, check=True).stdout


def test_math_helpers_are_never_out_of_line(library):
    assert [s for s in _symbols(library) if s.startswith("nph_")] == []


def test_every_row_kernel_is_vectorized(library):
    rows = sorted(s for s in _symbols(library) if s.startswith("row_") and s.endswith(".arch_x86_64_v4"))
    assert len(rows) == 21  # row_dispatch's specializations
    scalar = [s for s in rows if not PACKED.search(_code(library, s))]
    assert scalar == []


def test_the_views_march_is_vectorized(library):
    # One loop of positions, texels and light stayed scalar (march_planes 640x480 at 64x64x48: 0.150 s
    # against 0.097 s split in two): the positions' packed float64 and the light's packed float32.
    code = _code(library, "scatter_march.arch_x86_64_v4")
    assert re.search(r"\svmulpd\s", code) and re.search(r"\svdivps\s", code) and PACKED.search(code)
