"""Blobby surfaces: meshing time and vertex error against the exact Gaussian sum, for
100 ... 5,000 random ellipsoids at spacing sigma_min / 4, beside the anchor measured in
the same run: a dense-grid NumPy evaluation of the same sum (each Gaussian cut at the
same cutoff) contoured by scikit-image's marching_cubes at the same spacing.

Writes docs/benchmarks.md, section ``blobby``.

    .venv/bin/python benchmarks/bench_blobby.py [--quick] [--sizes 100 1000 5000] [--threads 2]
        [--no-metaballs] [--metaball-max 1000]

The full run measures 100, 1,000 and 5,000 ellipsoids; the README's and docs' numbers come from
``--sizes 100 1000 2000 5000 20000 100000 --metaball-max 5000 --actin`` (18 minutes, 8 of them the
metaballs at 5,000, 5 the two 100,000 meshes of 120M vertices; no dense anchor past 5,000; peak
12.1 GiB resident, 2026-11-28): each mesh but its vertices is dropped before its error, and they
before the next mesh.
"""

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402

from nephele.core import native  # noqa: E402
from nephele.core.muscle import blobby_surface, level_distance  # noqa: E402

SIGMA = (0.5, 1.0)  # per-axis sigmas drawn in this range: sigma_min = 0.5
LEVEL = 0.5
CUTOFF = 4.0
VOLUME_PER_BLOB = 30.0  # box volume per ellipsoid (about 15% of it inside the surface)
SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"  # the project's real data
DENSE_LIMIT = 150e6  # dense-grid nodes the anchor may allocate (float32: 600 MB)


def scene(n, seed=0):
    rng = np.random.default_rng(seed)
    side = (n * VOLUME_PER_BLOB) ** (1 / 3)
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1
    return (rng.uniform(0, side, (n, 3)), q, rng.uniform(*SIGMA, (n, 3)), rng.uniform(1.0, 2.0, n)), side


def dense_anchor(c, r, s, w, h):
    """Dense grid over the blobs' cutoff boxes, each Gaussian added on its own sub-box, then skimage."""
    from skimage.measure import marching_cubes

    half = CUTOFF * np.sqrt(np.einsum("nik,nk->ni", r**2, s**2))
    lo = (c - half).min(0) - h
    dims = np.ceil(((c + half).max(0) + h - lo) / h).astype(int) + 1
    vol = np.zeros(dims, np.float32)
    a = np.einsum("nik,nk,njk->nij", r, 1 / s**2, r)
    for ci, ai, wi, hi in zip(c, a, w, half):
        i0 = np.maximum(np.floor((ci - hi - lo) / h).astype(int), 0)
        i1 = np.minimum(np.ceil((ci + hi - lo) / h).astype(int) + 1, dims)
        ax = [lo[k] + h * np.arange(i0[k], i1[k]) - ci[k] for k in range(3)]
        x, y, z = np.meshgrid(*ax, indexing="ij", sparse=True)
        q = (ai[0, 0] * x * x + ai[1, 1] * y * y + ai[2, 2] * z * z
             + 2 * (ai[0, 1] * x * y + ai[0, 2] * x * z + ai[1, 2] * y * z))
        vol[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]] += (wi * np.exp(-0.5 * q)).astype(np.float32)
    verts, faces, _, _ = marching_cubes(vol, LEVEL, spacing=(h, h, h))
    return verts + lo, faces


METABALL_SEMI = 0.572
"""Blender's lone ellipsoid element (threshold 0.6) has semi-axes 0.572 radius size_i (measured)."""


def metaballs(c, r, s, w, h):
    """Blender's metaballs: ellipsoid elements with the same centres, axes and lone-blob semi-axes,
    resolution h; seconds to evaluate and convert to a mesh, and its vertex and face counts."""
    import bpy
    from mathutils import Matrix

    bpy.ops.wm.read_factory_settings(use_empty=True)
    mb = bpy.data.metaballs.new("blobs")
    mb.resolution = mb.render_resolution = h
    for ci, ri, si, wi in zip(c, r, s, w):
        e = mb.elements.new(type="ELLIPSOID")
        e.co = ci
        e.radius = float(np.sqrt(2 * np.log(wi / LEVEL)) / METABALL_SEMI)
        e.size_x, e.size_y, e.size_z = si
        e.rotation = Matrix(ri.tolist()).to_quaternion()
    obj = bpy.data.objects.new("blobs", mb)
    bpy.context.scene.collection.objects.link(obj)
    t = time.perf_counter()
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    me = obj.evaluated_get(dg).to_mesh()
    sec = time.perf_counter() - t
    return sec, len(me.vertices), len(me.polygons)


def error(points, args, box, sample, rng):
    """Max and RMS first-order distance to the exact (uncut, all images) level set, in sigma_min."""
    if len(points) > sample:
        points = points[rng.choice(len(points), sample, replace=False)]
    d = level_distance(np.asarray(points, np.float64), *args, LEVEL, box=box) / SIGMA[0]
    return float(d.max()), float(np.sqrt(np.mean(d * d)))


def actin_table(shared=SHARED):
    """RMS and maximum distance of 1-8 fitted ellipsoids (k-means) and the 4 subdomains to the actin
    subunit's own Gaussian molecular surface; writes section ``blobby_actin``."""
    from nephele.core.muscle.molecules import atom_gaussians, fit_ellipsoids, read_pqr, subdomain_of

    pqr = shared / "molecules" / "mol1.pqr"
    if not pqr.exists():
        print(f"skipping the actin fit: {pqr} not found")
        return
    atoms = read_pqr(pqr)
    t, target = timed(lambda: atom_gaussians(atoms).surface(0.05))
    rows = []
    for k in range(1, 9):
        sec, fit = timed(lambda k=k: fit_ellipsoids(atoms, k, target=target))
        rows.append([k, "k-means", fit.rms, fit.max, sec])
        print(rows[-1], flush=True)
    sec, fit = timed(lambda: fit_ellipsoids(atoms, 4, groups=subdomain_of(atoms), target=target))
    rows.append([4, "subdomains 1-4 (shipped)", fit.rms, fit.max, sec])
    body = (
        f"Actin subunit `mol1.pqr` ({len(atoms.xyz)} atoms): the atoms' Gaussian molecular surface "
        f"(blobbiness 2.3, lone atom = its van der Waals sphere; {len(target.vertices)} vertices at 0.05 nm, "
        f"meshed in {t:.1f} s) against the blobby surface of k fitted ellipsoids at the same spacing. "
        "Distances in nm, symmetric, vertex to the nearest vertex or triangle centroid of the other "
        "surface (an upper bound by under half a triangle, about 0.02 nm). For scale: the subunit is "
        "about 5.5 x 5.5 x 3.5 nm. Fit seconds include meshing the fitted surface.\n\n"
        + md_table(["ellipsoids", "clusters", "rms (nm)", "max (nm)", "fit seconds"], rows)
    )
    write_section("blobby_actin", body, title="Actin subunit as Gaussian ellipsoids (fit to the atoms)")


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def timed_cpu(fn):
    """Wall seconds, CPU seconds of this process (all its threads) and the result."""
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - t, time.process_time() - c, out


def peak_rss(fn):
    """The result of ``fn()`` and the process's peak resident memory (GiB) while it ran: Linux's VmHWM,
    reset first through /proc/self/clear_refs (None where that is not available)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return fn(), None
    out = fn()
    with open("/proc/self/status") as f:
        hwm = next(int(line.split()[1]) for line in f if line.startswith("VmHWM"))
    return out, hwm / 2**20


def numpy_twins(fn):
    """``fn()`` with the compiled kernels switched off (what platforms without the wheel run)."""
    kept = native._module
    native._module = lambda: None
    try:
        return fn()
    finally:
        native._module = kept


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: 100 and 300 ellipsoids, 500 error samples")
    ap.add_argument("--sizes", type=int, nargs="*", default=None)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--metaballs", action=argparse.BooleanOptionalAction, default=True,
                    help="time Blender's metaballs beside (needs bpy)")
    ap.add_argument("--metaball-max", type=int, default=1000,
                    help="largest scene given to the metaballs (they grow about as n^2 on the 2-core test machine: "
                         "18-21 CPU s at 1000, 74-89 at 2000, 508 at 5000)")
    ap.add_argument("--numpy-max", type=int, default=5000,
                    help="largest scene also meshed by the kernels' NumPy twins (when the compiled ones are installed)")
    ap.add_argument("--sample", type=int, default=None, help="vertices checked against the exact sum")
    ap.add_argument("--actin", action=argparse.BooleanOptionalAction, default=None,
                    help="also fit 1-8 ellipsoids to the actin subunit (default: not with --quick)")
    ap.add_argument("--actin-only", action="store_true", help="only the actin fit table")
    args = ap.parse_args()
    if args.actin_only:
        actin_table()
        return
    # Beyond 5,000 the meshes pass 6M vertices: long for the shared 2-core test machine (pass --sizes
    # for 20,000: 24M vertices, 2.2 GiB peak for the mesher; 100,000: 120M vertices, see the docstring).
    sizes = args.sizes or ([100, 300] if args.quick else [100, 1000, 5000])
    sample = args.sample or (500 if args.quick else 5000)
    h = SIGMA[0] / 4
    rng = np.random.default_rng(1)
    load0 = os.getloadavg()[0]
    compiled = native.identity() != "numpy"
    rows = []
    ours, balls, peaks = {}, {}, {}
    for n in sizes:
        blobs, side = scene(n)
        for box in (None, np.full(3, side)):
            (t, cpu, mesh), peak = peak_rss(
                lambda blobs=blobs,
                box=box: timed_cpu(lambda: blobby_surface(*blobs, LEVEL, h, box=box, cutoff=CUTOFF,
                                                          threads=args.threads)))
            nv, nf = len(mesh.vertices), len(mesh.faces)
            vertices = mesh.vertices
            mesh = None  # (only the vertices are checked; the next mesh is made without this one)
            emax, erms = error(vertices, blobs, box, sample, rng)
            del vertices
            kind = "ours, periodic box" if box is not None else "ours"
            if box is None:
                ours[n] = (t, cpu)
            if peak is not None:
                peaks[n, kind] = peak
            rows.append([n, kind, t, cpu, nv, nf, erms, emax])
            print(rows[-1], f"peak RSS {peak:.2f} GiB" if peak is not None else "", flush=True)
            if box is None and compiled and n <= args.numpy_max:
                t, cpu, mesh = numpy_twins(lambda blobs=blobs: timed_cpu(
                    lambda: blobby_surface(*blobs, LEVEL, h, cutoff=CUTOFF, threads=args.threads)))
                emax, erms = error(mesh.vertices, blobs, None, sample, rng)
                rows.append([n, "ours, NumPy kernels (no wheel)", t, cpu, len(mesh.vertices), len(mesh.faces), erms,
                             emax])
                mesh = None
                print(rows[-1], flush=True)
        nodes = float(np.ceil((side + 2 * CUTOFF * SIGMA[1]) / h) + 1) ** 3
        if nodes <= DENSE_LIMIT:
            t, cpu, (v, f) = timed_cpu(lambda blobs=blobs: dense_anchor(*blobs, h))
            emax, erms = error(v, blobs, None, sample, rng)
            rows.append([n, "dense NumPy + skimage", t, cpu, len(v), len(f), erms, emax])
        else:
            rows.append([n, "dense NumPy + skimage", f"not run ({nodes / 1e6:.0f}M nodes)", "", "", "", "", ""])
        print(rows[-1], flush=True)
        if nodes * 8 <= DENSE_LIMIT:
            t, cpu, (v, f) = timed_cpu(lambda blobs=blobs: dense_anchor(*blobs, h / 2))
            emax, erms = error(v, blobs, None, sample, rng)
            rows.append([n, "dense NumPy + skimage at spacing/2", t, cpu, len(v), len(f), erms, emax])
            print(rows[-1], flush=True)
        if args.metaballs and n <= args.metaball_max:
            cpu = time.process_time()
            t, nv, nf = metaballs(*blobs, h)
            cpu = time.process_time() - cpu  # (includes building the elements: an upper bound)
            balls[n] = (t, cpu)
            rows.append([n, "Blender metaballs (own falloff)", t, cpu, nv, f"{nf} quads/tris", "n/a", "n/a"])
            print(rows[-1], flush=True)
        elif args.metaballs:
            rows.append([n, "Blender metaballs (own falloff)", f"not run (--metaball-max {args.metaball_max})", "", "",
                         "", "", ""])
    load1 = os.getloadavg()[0]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux
    ratios = "; ".join(f"{n}: {balls[n][0] / ours[n][0]:.1f}x wall, {balls[n][1] / ours[n][1]:.1f}x CPU"
                       for n in sizes if n in balls and n in ours)
    speed = (f" Ours (no box) against the metaballs in this run, seconds ratio: {ratios} (goal: 10x at 5,000 "
             "ellipsoids, in 2 s)." if ratios else "")
    mem = ""
    if peaks:
        big = max(sizes)
        mem = (f" Peak resident memory of the process while ours meshed {big} ellipsoids (its mesh included, "
               "the scene and the run's earlier arrays too): "
               + " and ".join(f"{v:.1f} GiB {'in the periodic box' if 'box' in k else 'without box'}"
                            for (n, k), v in peaks.items() if n == big) + ".")
    kernels = (f"Ours ran the compiled kernels (nephele_native {native.identity()}); the rows 'NumPy kernels' "
               "are the same code with them switched off, as on a platform without the wheel." if compiled else
               "Ours ran the NumPy kernels (no nephele_native wheel installed).")
    body = (
        f"Random Gaussian ellipsoids (sigmas {SIGMA[0]}-{SIGMA[1]} per axis, random rotations, weights 1-2, "
        f"level {LEVEL}, one per {VOLUME_PER_BLOB:g} volume units), spacing sigma_min/4 = {h}, cutoff {CUTOFF} sigma, "
        f"threads {args.threads or 'default'}. {kernels}"
        f" Error: first-order distance |f - level| / |grad f| of {sample} sampled "
        "vertices to the exact uncut sum (every periodic image), in sigma_min; the goal is 0.01. "
        "The anchor evaluates the same cut sum on a dense grid with NumPy (one sub-box per Gaussian) and "
        "contours it with skimage.measure.marching_cubes at the same spacing (and at half of it, "
        "to show what its linear interpolation needs to approach the goal). Blender's metaballs: ellipsoid elements "
        "with the same centres, axes and lone-blob semi-axes at the same resolution, timed through the "
        "depsgraph to a mesh; their falloff is Blender's polynomial, not a Gaussian, so their surface is "
        "not the same and has no error column. CPU seconds: the process's (all threads, "
        "time.process_time; the metaballs' include building the elements); wall seconds grow with the "
        f"machine's load. Load average {load0:.1f} at the start, "
        f"{load1:.1f} at the end, {os.cpu_count()} cores shared.{speed}{mem} Peak memory of the whole run "
        f"(resident): {peak:.1f} GiB; this machine has 24.\n\n"
        + md_table(["ellipsoids", "method", "seconds", "CPU seconds", "vertices", "triangles", "rms error",
                    "max error"], rows)
    )
    write_section("blobby", body, title="Blobby surfaces (sums of Gaussian ellipsoids)")
    if args.actin if args.actin is not None else not args.quick:
        actin_table()


if __name__ == "__main__":
    main()
