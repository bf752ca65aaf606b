"""Direction-bin phase tables: built by cube symmetry against every column computed (the anchor).

Each table of :mod:`nephele.core.light.phase` is computed for one incoming bin per orbit of
the cube's 48 symmetries and permuted into the other columns; the anchor computes every
column with the same code (the tables before the symmetry).  Prints seconds (CPU and wall),
the table's size and the largest difference between the two.

Usage: ``python benchmarks/bench_phase.py [--quick]``.
"""

import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, quick, write_section  # noqa: E402

from nephele.core.light import phase  # noqa: E402

CASES = [  # (name, builder, arguments); g 0.8 everywhere
    ("phase_matrix", phase._phase_matrix_cached, (0.8, 6, True, 2, 4)),
    ("phase_matrix", phase._phase_matrix_cached, (0.8, 6, True, 2, 6)),
    ("sub_phase_matrix sub 4, out_sub 8", phase._sub_phase_matrix_cached, (0.8, 4, 8, 4)),
    ("sub_phase_matrix sub 4, out_sub 8", phase._sub_phase_matrix_cached, (0.8, 4, 8, 6)),
    ("sub_sub_phase_matrix sub 4, k 2", phase._sub_sub_cached, (0.8, 4, 2, 4)),
    ("sub_sub_phase_matrix sub 4, k 2", phase._sub_sub_cached, (0.8, 4, 2, 6)),
    ("sub_sub_phase_matrix sub 8, k 2", phase._sub_sub_cached, (0.8, 8, 2, 6)),
]


def _every_column(column, per_face, sub, row_sub):
    """The anchor for :func:`phase._by_symmetry`: every incoming bin's column computed."""
    nb = 6 * per_face ** 2
    m = np.empty((nb * row_sub ** 2, nb, sub * sub))
    for j in range(nb):
        m[:, j, :] = column(j)
    return m


def _timed(build, args):
    for f in (build, phase._bins_cached, phase._symmetries):
        f.cache_clear()
    w, c = time.perf_counter(), time.process_time()
    m = build(*args)
    return m, time.process_time() - c, time.perf_counter() - w


def main():
    rows = []
    for name, build, args in [c for c in CASES if c[2][-1] == 4] if quick() else CASES:  # quick: 96 bins
        m, cpu, wall = _timed(build, args)
        with mock.patch.object(phase, "_by_symmetry", _every_column):
            ref, cpu_ref, wall_ref = _timed(build, args)
        build.cache_clear()
        rows.append((name, args[-1], f"{m.nbytes / 2 ** 20:.1f}", f"{cpu:.2f}", f"{wall:.2f}", f"{cpu_ref:.2f}",
                     f"{wall_ref:.2f}", f"{np.abs(m - ref).max():.1e}"))
        print(rows[-1], flush=True)
        del m, ref
    body = ("g 0.8; each table built once with empty caches (the bins and the symmetries' permutations "
            "included).  "
            "Shared 2-core machine: seconds are upper bounds.\n\n"
            + md_table(["table", "per_face", "MiB", "CPU s", "wall s", "every column: CPU s", "wall s",
                        "max abs difference"], rows))
    write_section("phase", body, "Phase tables by cube symmetry")


if __name__ == "__main__":
    main()
