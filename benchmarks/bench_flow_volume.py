"""Flow volumes: rebuild time against front size and error, beside the anchors measured in the same run.

Part 1 — accuracy on the ABC flow (divergence-free): for each tolerance, the
front size, build time, the volume error against flux × duration (flux by a
fine centroid rule on the generator) and the front error of the oldest layer
against scipy ``solve_ivp`` DOP853 (rtol = atol = 1e-12), whose own time on
the same seeds is shown.

Part 2 — rebuild time on the demo climate (synthetic winds, 24 h release) for
8-, 16- and 32-sided generators, the interactive case of the issue (goal
≤ 50 ms on 2 cores), beside the same build reading the winds one hourly step
at a time (the path used when the steps are too big to stack; before the
stacked gather every rebuild took it: 459 ms for 32 sides, 24 h on
2026-11-25 05:14; before this session's one sweep per round and split margin, 57-59 ms at 32 sides, 24 h,
load 0.9).  "kept" counts the points the tetrahedra use after
merging where the front converges.

Part 3 — the fire in a room (``fire_ug.vtu``, hexahedral grid, one steady
snapshot): the rebuild as a stream tube (the default for a steady flow: each
generator point's streamline integrated once, every layer read from it)
beside the per-layer front (``steady=False``, each layer integrated on its
own, 8 steps) and the same stream tube with the velocity from VTK's
``vtkProbeFilter`` (its own cell locator), all in the same run.  Accuracy:
the volume against a stream tube with 600 steps per streamline at the same
tolerance (converged in the steps: 1200 steps change it by < 0.05%).  Air
that leaves the room stops at its exit point and the smoke ends there ("left
the room" counts those front points); before 2026-11-25 09:40 such releases
were refused (10 s: NaN velocities) and 1 s took 429 ms (cKDTree of cell
centres + Newton); before 2026-11-27 every rebuild was per-layer.

Part 4 — VTK's ``vtkStreamSurface`` on the ABC flow sampled on a 64³ image,
seeded on the same polygon: its time and whether its surface is closed (it
is an open ribbon of the ring only: no volume).

Usage: ``python benchmarks/bench_flow_volume.py [--quick]``.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402

from nephele.core.climate.synthetic import SyntheticClimate  # noqa: E402
from nephele.core.flowvol import ClimateVelocity, flow_volume  # noqa: E402


def abc(p, t, A=np.sqrt(3), B=np.sqrt(2), C=1.0):
    x, y, z = np.asarray(p).reshape(-1, 3).T
    return np.stack([A * np.sin(z) + C * np.cos(y), B * np.sin(x) + A * np.cos(z), C * np.sin(y) + B * np.cos(x)],
                    axis=1)


def polygon_flux(fv, n=80):
    c, outer = fv.generator[0], fv.generator[1:][1::2]
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    up, down = i + j < n, i + j < n - 1
    a = np.concatenate([(i[up] + 1 / 3) / n, (i[down] + 2 / 3) / n])
    b = np.concatenate([(j[up] + 1 / 3) / n, (j[down] + 2 / 3) / n])
    flux = 0.0
    for k in range(len(outer)):
        p, q = outer[k] - c, outer[(k + 1) % len(outer)] - c
        flux += 0.5 * np.linalg.norm(np.cross(p, q)) * np.mean(abc(c + a[:, None] * p + b[:, None] * q, 0) @ fv.normal)
    return flux


def timed(f, repeat, cpu=None):
    """Result and best wall time of ``repeat`` runs; with a list ``cpu``, the best CPU time (this process) is
    appended to it."""
    best, best_cpu = np.inf, np.inf
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = f()
        best, best_cpu = min(best, time.perf_counter() - t), min(best_cpu, time.process_time() - c)
    if cpu is not None:
        cpu.append(best_cpu)
    return out, best


def part_abc(quick):
    rows = []
    centre, radius, T = [0.5, 0.3, 0.2], 0.3, 1.0
    for tol in ([0.1, 0.04] if quick else [0.2, 0.1, 0.04, 0.02]):
        fv, sec = timed(lambda tol=tol: flow_volume(abc, centre, radius, T, sides=16, tol=tol, steps=16),
                        1 if quick else 3)
        first = np.isclose(fv.release, 0.0)
        ref, ref_sec = timed(lambda fv=fv: solve_ivp(lambda t, y: abc(y.reshape(-1, 3), t).ravel(), (0, T),
                                                     fv.generator.ravel(),
                                               method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1].reshape(-1, 3), 1)
        err = np.max(np.linalg.norm(fv.vertices[first] - ref, axis=1))
        flux = polygon_flux(fv)
        rows.append([f"{tol:g}", len(fv.vertices), len(fv.tets), f"{sec * 1e3:.1f}",
                     f"{100 * (fv.volume / (flux * T) - 1):+.3f}",
                     f"{err:.1e}", f"{ref_sec * 1e3:.1f}", "yes" if fv.complete else "no"])
    return md_table(["tol", "front points", "tets", "build ms", "volume vs flux×T %", "front error vs DOP853",
                     "DOP853 ms (same seeds)", "converged"], rows)


def part_climate(quick):
    ds = SyntheticClimate(ni=160, nj=80, nk=6, days=2, seed=0)
    vel, per_step = ClimateVelocity(ds), ClimateVelocity(ds, stack_mb=0)
    # read the first steps
    vel(vel.point(np.array([0.0]), np.array([0.0]), np.array([2000.0])).reshape(1, 3), np.array([0.0]))
    rows = []
    c = vel.point(-40.0, 35.0, 2000.0)
    for sides in ([8, 32] if quick else [8, 16, 32]):
        for hours in ([24.0] if quick else [6.0, 24.0]):
            kw = dict(sides=sides, rings=1, steps=8, tol=0.02)
            flow_volume(vel, c, 0.03, hours, **kw)  # warm the wind cache
            cpu = []
            fv, sec = timed(lambda hours=hours, kw=kw: flow_volume(vel, c, 0.03, hours, **kw), 1 if quick else 5, cpu)
            flow_volume(per_step, c, 0.03, hours, **kw)
            _, slow = timed(lambda hours=hours, kw=kw: flow_volume(per_step, c, 0.03, hours, **kw), 1)
            rows.append([sides, f"{hours:g}", len(fv.vertices), len(np.unique(fv.tets)), len(fv.tets),
                         f"{sec * 1e3:.0f}", f"{cpu[0] * 1e3:.0f}",
                         f"{slow * 1e3:.0f}", "yes" if cpu[0] <= 0.05 else "no"])
    return md_table(["sides", "release hours", "front points", "kept (merged)", "tets", "rebuild ms (wall)", "CPU ms",
                     "ms, winds read step by step", "≤ 50 ms (CPU)"], rows)


class VtkProbeVelocity:
    """The anchor: the fire's velocity by ``vtkProbeFilter`` (its own cell locator), NaN outside the grid."""

    bounded = True

    def __init__(self, path):
        import vtk

        r = vtk.vtkXMLUnstructuredGridReader()
        r.SetFileName(str(path))
        r.Update()
        self.grid = r.GetOutput()
        self.vtk = vtk

    def __call__(self, points, t=None):
        from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

        vtk = self.vtk
        pts = vtk.vtkPoints()
        pts.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=1))
        pd = vtk.vtkPolyData()
        pd.SetPoints(pts)
        probe = vtk.vtkProbeFilter()
        probe.SetInputData(pd)
        probe.SetSourceData(self.grid)
        probe.Update()
        out = probe.GetOutput().GetPointData()
        v = vtk_to_numpy(out.GetArray("uvw")).astype(np.float64)
        v[vtk_to_numpy(out.GetArray("vtkValidPointMask")) == 0] = np.nan
        return v


def part_fire(quick):
    from nephele.core.flowvol import UnstructuredVelocity

    path = Path(__file__).resolve().parents[1] / "tests" / "data" / "flow" / "fire_ug.vtu"
    if not path.is_file():
        return f"{path} not found: no fire timing."
    fire = UnstructuredVelocity(path)
    try:
        probe = VtkProbeVelocity(path)
        probe.cell_size = fire.cell_size  # the same grid: the same steps per streamline
    except ImportError:
        probe = None
    c = fire.updraft(0.1)
    rows = []
    for sides, secs, tol in ([(32, 1.0, 0.05), (32, 10.0, 0.1)] if quick
                             else [(16, 1.0, 0.05), (32, 1.0, 0.05), (32, 10.0, 0.05), (32, 10.0, 0.1)]):
        kw = dict(sides=sides, rings=1, steps=8, tol=tol)
        cpu = []
        fv, sec = timed(lambda secs=secs, kw=kw: flow_volume(fire, c, 0.1, secs, **kw), 1 if quick else 3, cpu)
        layer, layer_sec = timed(lambda secs=secs, kw=kw: flow_volume(fire, c, 0.1, secs, steady=False, **kw),
                                 1 if quick else 3)
        ref, ref_sec = ((None, None) if probe is None
                        else timed(lambda secs=secs, kw=kw: flow_volume(probe, c, 0.1, secs, steady=True, **kw), 1))
        agree = "-" if ref is None else f"{100 * (fv.volume / ref.volume - 1):+.3f}"
        conv = flow_volume(fire, c, 0.1, secs, **dict(kw, steps=600)).volume
        rows.append([sides, f"{secs:g}", f"{tol:g}", len(fv.vertices), int(fv.exited.sum()), len(fv.tets),
                     f"{sec * 1e3:.0f}", f"{cpu[0] * 1e3:.0f}",
                     f"{100 * (fv.volume / conv - 1):+.2f}", f"{layer_sec * 1e3:.0f}",
                     f"{100 * (layer.volume / conv - 1):+.2f}",
                     "-" if ref is None else f"{ref_sec * 1e3:.0f}", f"{fv.volume:.4f}", agree,
                     "yes" if cpu[0] <= 0.05 else "no"])
        print(rows[-1], flush=True)
    return md_table(["sides", "release s", "tol m", "front points", "left the room", "tets", "rebuild ms (wall)",
                     "CPU ms", "volume vs 600 steps %", "per-layer ms (wall)", "per-layer volume vs 600 steps %",
                     "ms (wall), velocity by vtkProbeFilter", "volume m³", "volume vs probe %", "≤ 50 ms (CPU)"], rows)


def part_vtk(quick):
    try:
        import vtk
        from vtk.util.numpy_support import numpy_to_vtk
    except ImportError:
        return "VTK not installed: no comparison."
    n = 32 if quick else 64
    ax = np.linspace(-0.5, 1.5, n)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    v = abc(np.stack([X, Y, Z], -1).reshape(-1, 3), 0)
    img = vtk.vtkImageData()
    img.SetDimensions(n, n, n)
    img.SetOrigin(-0.5, -0.5, -0.5)
    d = ax[1] - ax[0]
    img.SetSpacing(d, d, d)
    arr = numpy_to_vtk(v.reshape(n, n, n, 3).transpose(2, 1, 0, 3).reshape(-1, 3).copy(), deep=1)
    arr.SetName("v")
    img.GetPointData().SetVectors(arr)
    fv = flow_volume(abc, [0.5, 0.3, 0.2], 0.3, 1.0, sides=16, tol=0.04, steps=16)
    ring = fv.generator[1:][1::2]
    pts = vtk.vtkPoints()
    for p in ring:
        pts.InsertNextPoint(*p)
    line = vtk.vtkPolyLine()
    line.GetPointIds().SetNumberOfIds(len(ring) + 1)
    for i in range(len(ring) + 1):
        line.GetPointIds().SetId(i, i % len(ring))
    cells = vtk.vtkCellArray()
    cells.InsertNextCell(line)
    seeds = vtk.vtkPolyData()
    seeds.SetPoints(pts)
    seeds.SetLines(cells)
    ss = vtk.vtkStreamSurface()
    ss.SetInputData(img)
    ss.SetSourceData(seeds)
    ss.SetIntegratorTypeToRungeKutta4()
    ss.SetIntegrationDirectionToForward()
    ss.SetMaximumPropagation(float(np.linalg.norm(abc(ring, 0), axis=1).max()) * 1.0)
    ss.SetInitialIntegrationStep(0.2)
    ss.SetUseIterativeSeeding(True)
    t = time.perf_counter()
    ss.Update()
    sec = time.perf_counter() - t
    out = ss.GetOutput()
    fe = vtk.vtkFeatureEdges()
    fe.SetInputData(out)
    fe.BoundaryEdgesOn()
    fe.NonManifoldEdgesOn()
    fe.FeatureEdgesOff()
    fe.ManifoldEdgesOff()
    fe.Update()
    open_edges = fe.GetOutput().GetNumberOfCells()
    _, ours = timed(lambda: flow_volume(abc, [0.5, 0.3, 0.2], 0.3, 1.0, sides=16, tol=0.04, steps=16), 1)
    return md_table(["method", "ms", "points", "cells", "boundary/non-manifold edges", "encloses a volume"],
                    [["vtkStreamSurface (ring seeds, 1 arc length of the fastest seed)", f"{sec * 1e3:.1f}",
                      out.GetNumberOfPoints(), out.GetNumberOfCells(), open_edges, "no (open surface)"],
                     ["nephele flow_volume (tol 0.04)", f"{ours * 1e3:.1f}", len(fv.vertices), len(fv.tets), 0,
                      f"yes ({fv.volume:.4f})"]])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer tolerances and generators")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    parts = [("ABC flow (divergence-free), 16-sided generator r = 0.3, 1 time unit, 16 RK4 steps per trajectory",
              part_abc(args.quick)),
             ("Demo climate (SyntheticClimate 160×80×6), generator r = 0.03 at 40°W 35°N 2 km, tol 0.02, 8 RK4 steps",
              part_climate(args.quick)),
             ("Fire in a room (fire_ug.vtu, 12,323 points, 10,462 hexahedra), generator r = 0.1 m placed 0.1 m above "
              "the fastest updraft, 8 RK4 steps", part_fire(args.quick)),
             ("Beside VTK on the same seeds", part_vtk(args.quick))]
    load1 = os.getloadavg()[0]
    body = (f"Shared 2-core machine, other jobs running (1-minute load average {load0:.1f} at the start, {load1:.1f} "
            "at the end; under such load wall times are several times the CPU time this process got, so the "
            f"interactive goal is judged on CPU ms, best of 5){'; --quick' if args.quick else ''}.\n\n"
            + "\n\n".join(f"**{t}**\n\n{b}" for t, b in parts))
    write_section("flow_volume", body, "Flow volumes (Fig. 5)")


if __name__ == "__main__":
    main()
