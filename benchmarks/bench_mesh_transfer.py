"""Moving a 1M-triangle contour mesh into Blender: foreach_set paths against from_pydata.

Each path builds a new ``bpy.types.Mesh`` from the same NumPy arrays; the
result is compared with the ``from_pydata`` mesh (vertex positions and face
corners must be identical).  Median of ``--repeat`` runs.  Writes the table to
docs/benchmarks.md, section ``mesh_transfer``.

    .venv/bin/python benchmarks/bench_mesh_transfer.py [--triangles 1000000] [--repeat 3]
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402


def gyroid_mesh(target):
    """A contour mesh of a gyroid with about ``target`` triangles (a realistic, branching surface)."""
    from nephele.core.surface.contour import isosurface, regular_points

    n = max(int(round((target / 3.6) ** (1 / 3) * 1.45)), 8)
    for _ in range(6):
        x = np.linspace(0.0, 4 * np.pi, n, dtype=np.float32)
        X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
        v = (np.sin(X) * np.cos(Y) + np.sin(Y) * np.cos(Z) + np.sin(Z) * np.cos(X)).astype(np.float32)
        m = isosurface(regular_points(v.shape, spacing=(x[1] - x[0],) * 3), v, 0.0, attributes={"value": Z})
        if abs(len(m.faces) - target) < 0.03 * target:
            break
        n = int(round(n * (target / len(m.faces)) ** 0.5))
    return m


def path_fill_mesh(bpy, m):
    from nephele.addon.mesh import new_mesh

    return new_mesh("fill_mesh", m)


def path_attributes_only(bpy, m):
    me = bpy.data.meshes.new("attrs")
    me.vertices.add(len(m.vertices))
    me.loops.add(m.faces.size)
    me.polygons.add(len(m.faces))
    me.attributes["position"].data.foreach_set("vector", m.vertices.ravel())
    me.attributes[".corner_vert"].data.foreach_set("value", m.faces.ravel())
    me.polygons.foreach_set("loop_start", np.arange(0, m.faces.size, 3, dtype=np.int32))
    me.update(calc_edges=True)
    return me


def path_legacy_foreach(bpy, m):
    me = bpy.data.meshes.new("legacy")
    me.vertices.add(len(m.vertices))
    me.loops.add(m.faces.size)
    me.polygons.add(len(m.faces))
    me.vertices.foreach_set("co", m.vertices.ravel())
    me.loops.foreach_set("vertex_index", m.faces.ravel())
    me.polygons.foreach_set("loop_start", np.arange(0, m.faces.size, 3, dtype=np.int32))
    me.update(calc_edges=True)
    return me


def path_from_pydata(bpy, m):
    me = bpy.data.meshes.new("pydata")
    me.from_pydata(m.vertices, [], m.faces)
    me.update()
    return me


PATHS = [
    ("nephele `fill_mesh` (position + corner_vert + loop_start, edges, 1 attribute, smooth)", path_fill_mesh),
    ("attribute foreach_set only (position, .corner_vert)", path_attributes_only),
    ("legacy foreach_set (vertices.co, loops.vertex_index)", path_legacy_foreach),
    ("`from_pydata` (anchor)", path_from_pydata),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-write", action="store_true", help="print only, do not touch docs/benchmarks.md")
    ap.add_argument("--quick", action="store_true", help="10k triangles, one repeat (smoke run; prints only)")
    args = ap.parse_args(argv)
    if args.quick:
        args.triangles, args.repeat = 10_000, 1

    import bpy

    from nephele.addon.mesh import mesh_arrays

    bpy.ops.wm.read_factory_settings(use_empty=True)
    t = time.perf_counter()
    m = gyroid_mesh(args.triangles)
    t_contour = time.perf_counter() - t
    print(f"mesh: {len(m.vertices)} vertices, {len(m.faces)} triangles (contoured in {t_contour:.2f} s)")

    results = {}
    cpu = {}
    meshes = {}
    load_before = os.getloadavg()[0]
    for label, fn in PATHS:
        times, cpus = [], []
        for _ in range(args.repeat):
            for me in list(bpy.data.meshes):
                bpy.data.meshes.remove(me)
            t, c = time.perf_counter(), time.process_time()
            me = fn(bpy, m)
            times.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
        results[label] = times
        cpu[label] = cpus
        meshes[label] = mesh_arrays(me) + (len(me.edges),)
        print(f"{label}: median {statistics.median(times):.3f} s  {['%.3f' % x for x in times]}")

    ref_v, ref_f, ref_e = meshes[PATHS[-1][0]]
    anchor = statistics.median(results[PATHS[-1][0]])
    rows = []
    for label, _ in PATHS:
        v, f, e = meshes[label]
        med = statistics.median(results[label])
        rows.append([
            label,
            med,
            min(results[label]),
            statistics.median(cpu[label]),
            f"{anchor / med:.1f}×",
            float(np.abs(v - ref_v).max()),
            int((f != ref_f).any(axis=1).sum()),
            e - ref_e,
        ])
    body = (
        f"A gyroid contour mesh of {len(m.faces):,} triangles and {len(m.vertices):,} vertices into a new "
        f"`bpy.types.Mesh` (bpy {bpy.app.version_string}), median of {args.repeat} runs on a machine shared "
        f"with other jobs (2 cores; 1-minute load average {load_before:.1f} before and {os.getloadavg()[0]:.1f} "
        "after, so wall times are inflated; CPU s is the process time of all Blender threads). Error columns "
        "compare with the `from_pydata` mesh built in the same run: max vertex difference, faces whose corners "
        "differ, difference in edge count. Goal: ≤ 1 s for 1M triangles.\n\n"
        + md_table(["path", "median s", "min s", "median CPU s", "speed-up vs from_pydata", "max Δvertex",
                    "faces differing", "Δ edges"], rows)
    )
    if not args.no_write:
        write_section("mesh_transfer", body, title="Mesh transfer into Blender (1M triangles)")
    else:
        print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
