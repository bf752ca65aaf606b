"""Volume clouds: voxel size against active voxels, memory, resampling time and opacity error.

The error is measured along rays against the exact curvilinear reference
(:func:`nephele.core.exact_ray.reference_optical_depth`: the field trilinear
in each curvilinear cell, integrated through the piecewise-linear transfer
function in closed form, Williams & Max 1992), for rays from the Fig. 2
camera and random rays through the atmosphere shell.  Opacity
``1 - exp(-extinction * tau)`` is compared in % of full scale (opacity 1).

    .venv/bin/python benchmarks/bench_volume.py [--quick]
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402


from nephele.core.exact_ray import (  # noqa: E402
    opacity, ray_samples, reference_optical_depth, segment_optical_depth, volume_optical_depth,
)
from nephele.core.grid import height_from_radius, lonlat_to_xyz  # noqa: E402
from nephele.core.readers import open_dataset  # noqa: E402
from nephele.core.transfer import TransferFunction  # noqa: E402
from nephele.core.volume import DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE, CurvilinearField, resample  # noqa: E402

TF = TransferFunction.ramp(0.3, 0.7)  # the Fig. 2 example's transfer function


def rays(n, rng):
    """Half from a Fig. 2-like camera (lon -110, lat 25, distance 2.7) over the visible disc, half random
    chords through the shell (many grazing)."""
    eye = lonlat_to_xyz(-110.0, 25.0, 2.7)
    m = n // 2
    target = rng.normal(size=(m, 3))
    target *= (rng.uniform(0, 1, (m, 1)) ** 0.5) / np.linalg.norm(target, axis=1)[:, None]
    d1 = target - eye
    o1 = np.broadcast_to(eye, d1.shape)
    u = rng.normal(size=(n - m, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    o2 = 3.0 * u
    aim = rng.normal(size=(n - m, 3))
    aim *= (rng.uniform(0.9, 1.06, (n - m, 1))) / np.linalg.norm(aim, axis=1)[:, None]
    d2 = aim - o2
    o = np.concatenate([o1, o2])
    d = np.concatenate([d1, d2])
    return o, d / np.linalg.norm(d, axis=1)[:, None]


def timed(fn, repeat):
    best_wall, best_cpu, out = np.inf, np.inf, None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        best_wall = min(best_wall, time.perf_counter() - w)
        best_cpu = min(best_cpu, time.process_time() - c)
    return out, best_wall, best_cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer rays and voxel sizes")
    ap.add_argument("--source", default="demo")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    load = os.getloadavg()
    ds = open_dataset(args.source)
    step_index = 0
    values = ds.read("cloud", step_index)
    grid = ds.grid
    nk, nj, ni = grid.shape
    n_rays = 400 if args.quick else 4000
    o, d = rays(n_rays, rng)
    field = CurvilinearField.from_grid(grid, {"v": values})

    # The anchor: the exact reference, at two steps to show it has converged.
    ref_step = 0.00025
    (tau, t0, t1), ref_wall, ref_cpu = timed(lambda: reference_optical_depth(field, "v", TF, o, d, ref_step), 1)
    tau2, _, _ = reference_optical_depth(field, "v", TF, o, d, 2 * ref_step)
    a_ref = opacity(tau, DEFAULT_EXTINCTION)
    conv = np.abs(opacity(tau2, DEFAULT_EXTINCTION) - a_ref).max() * 100

    sizes = (0.008, 0.004, DEFAULT_VOXEL_SIZE) if args.quick else (0.008, 0.006, 0.004, 0.003, 0.0027, 0.0025, 0.002, 0.0015)
    families = (("Fig. 2 camera", slice(0, n_rays // 2)), ("chords", slice(n_rays // 2, n_rays)))

    def errors(err):
        """Per ray family: max, 99.9th and 99th percentile, rms of |error| in %FS."""
        out = []
        for _, sl in families:
            e = np.abs(err[sl]) * 100
            out += [f"{e.max():.2f}", f"{np.percentile(e, 99.9):.2f}", f"{np.percentile(e, 99):.2f}", f"{np.sqrt(np.mean(e**2)):.2f}"]
        return out

    # The whole atmosphere shell as one dense grid, for scale.
    r_in, r_out = field.radius_range()
    shell = 4.0 / 3.0 * np.pi * (r_out**3 - r_in**3)
    rows = []
    for vs in sizes:
        repeat = 1 if vs < 0.0025 else 3
        vol, wall, cpu = timed(lambda: resample(grid, values, TF, voxel_size=vs, color_name="altitude", workers=1), repeat)
        (_, wall2, cpu2) = timed(lambda: resample(grid, values, TF, voxel_size=vs, color_name="altitude", workers=2), repeat)
        tv = volume_optical_depth(vol, o, d, t0, t1, min(vs / 4, 0.0005))
        err = opacity(tv, DEFAULT_EXTINCTION) - a_ref
        if vs == DEFAULT_VOXEL_SIZE:
            default_vol, default_err = vol, err
        st = vol.stats
        dense_mb = shell / vs**3 * 8 / 1e6  # two float32 grids over the shell
        rows.append([
            f"{vs:g}" + (" (default)" if vs == DEFAULT_VOXEL_SIZE else ""),
            f"{vs * 6371 / 30 * 1000:.0f} / {vs * 6371:.0f}",
            st["blocks"], st["active_voxels"], f"{st['bytes'] / 1e6:.1f}", f"{dense_mb:.0f}",
            f"{wall:.2f}", f"{cpu:.2f}", f"{wall2:.2f}", *errors(err),
        ])
        print(rows[-1], flush=True)

    # Where the error comes from: the worst rays' optical-depth error by height band.
    worst = np.argsort(-np.abs(default_err))[:10]
    bands = (0, 1000, 3000, 5000, 20001)  # metres; the top band takes the grid top (20 km)
    band_err = np.zeros(len(bands) - 1)
    near = 0.0
    for r in worst:
        pts, seg = ray_samples(o[r:r + 1], d[r:r + 1], t0[r:r + 1], t1[r:r + 1], ref_step)
        p = pts[0]
        s = field.sample("v", p)
        ref_seg = segment_optical_depth(TF, s[:-1], s[1:], seg[0])
        vd = default_vol.sample(p)
        dv = seg[0] * 0.5 * (vd[:-1] + vd[1:]) - ref_seg
        hb = height_from_radius(np.linalg.norm(0.5 * (p[:-1] + p[1:]), axis=1))
        band_err += [np.abs(dv[(hb >= a) & (hb < b)].sum()) for a, b in zip(bands[:-1], bands[1:])]
        # Error where the field stays within 0.05 of the threshold (the transfer function's kink).
        near += np.abs(dv[np.abs(0.5 * (s[:-1] + s[1:]) - TF.values[0]) < 0.05].sum())
    share = band_err / max(band_err.sum(), 1e-300) * 100
    near_share = near / max(np.abs(band_err).sum(), 1e-300) * 100

    # Interpolate the scalar, then apply the transfer function per sample (the
    # "post-classification" route: the grid would hold the cloud value and the
    # material would apply the transfer function).  Stored: the value where it
    # exceeds 0.12 (far under the threshold), so interpolation near the threshold is exact.
    step_tf = TransferFunction(points=((0.12, 0.0), (0.12, 0.12), (1.0, 1.0)))
    post_rows = []
    for vs in (0.004, DEFAULT_VOXEL_SIZE):
        svol, swall, scpu = timed(lambda: resample(grid, values, step_tf, voxel_size=vs), 1)
        pts, seg = ray_samples(o, d, t0, t1, min(vs / 4, 0.0005))
        sv = np.concatenate([svol.sample(c) for c in np.array_split(pts.reshape(-1, 3), 40)]).reshape(seg.shape[0], -1)
        dens = TF(sv)
        e2 = opacity((seg * 0.5 * (dens[:, :-1] + dens[:, 1:])).sum(axis=1), DEFAULT_EXTINCTION) - a_ref
        pre = next(r for r in rows if r[0].startswith(f"{vs:g}"))
        post_rows.append([f"{vs:g}", "opacity in the grid (ours)", pre[3], *pre[9:]])
        post_rows.append([f"{vs:g}", "scalar in the grid, TF per sample", svol.stats["active_voxels"], *errors(e2)])
        print(post_rows[-1], flush=True)
        if vs == DEFAULT_VOXEL_SIZE:
            # Both grids in one material, combined per sample: the opacity capped
            # near the scalar's (kills the threshold bias, cuts thin layers).
            pv = np.concatenate([default_vol.sample(c) for c in np.array_split(pts.reshape(-1, 3), 40)]).reshape(seg.shape[0], -1)
            both = svol.stats["active_voxels"] + default_vol.stats["active_voxels"]
            for name, mix in (("both, min(opacity, TF(scalar) + 0.01)", np.minimum(pv, dens + 0.01)),
                              ("both, opacity where scalar > threshold", pv * (sv > TF.values[0])),
                              ("both, sqrt(opacity × TF(scalar))", np.sqrt(pv * dens))):
                e3 = opacity((seg * 0.5 * (mix[:, :-1] + mix[:, 1:])).sum(axis=1), DEFAULT_EXTINCTION) - a_ref
                post_rows.append([f"{vs:g}", name, both, *errors(e3)])
                print(post_rows[-1], flush=True)

    # Memory follows the cloudy volume: vary the threshold at the default voxel size.
    mem_rows = []
    for thr in (0.1, 0.3, 0.5, 0.7, 0.9):
        tf = TransferFunction.ramp(thr, max(thr + 0.05, 0.7))
        vol = resample(grid, values, tf, voxel_size=DEFAULT_VOXEL_SIZE, color_name="altitude")
        cells = vol.stats["candidate_cells"]
        mem_rows.append([f"{thr:g}", f"{np.mean(values > thr) * 100:.1f}", cells, vol.stats["active_voxels"],
                         vol.stats["blocks"], f"{vol.stats['bytes'] / 1e6:.1f}",
                         f"{vol.stats['bytes'] / max(vol.stats['active_voxels'], 1):.1f}"])

    default_row = next(r for r in rows if r[0].endswith("(default)"))
    goal_p99 = ", ".join(f"{name} {default_row[11 + 4 * n]}%" for n, (name, _) in enumerate(families))
    goal_met = all(float(default_row[11 + 4 * n]) <= 2.0 for n in range(len(families)))
    default_worst = np.abs(default_err).max() * 100
    finest = rows[-1]
    worst_note = (": the maximum falls only slowly with the voxel size (at "
                  f"{finest[0]}, {finest[3]} active voxels and {finest[7]} CPU-s, it is still "
                  f"{max(float(finest[9]), float(finest[13])):.1f}%), because of where it comes from:"
                  if default_worst > 2 else ".  Where the largest errors come from:")
    body = f"""
Demo grid {ni}×{nj}×{nk} (`open_dataset("{args.source}")`, step {step_index}, cloud {np.mean(values > 0.3) * 100:.1f}% of
grid points above 0.3), transfer function {TF.points} (the Fig. 2 example's), extinction {DEFAULT_EXTINCTION:g}
per scene unit at opacity 1, exaggeration 30, colour grid = altitude.  Error: opacity along {n_rays} rays
(half from a Fig. 2-like camera, half random chords through the shell) of the resampled volume (trilinear
between voxels, as Cycles samples a VDB) against the **exact curvilinear reference** (the anchor: trilinear
in each curvilinear cell, piecewise-linear between samples {ref_step:g} apart, Williams & Max closed form
through the transfer function; {ref_wall:.1f} s wall / {ref_cpu:.1f} s CPU for all rays; halving its step
changes the opacity by at most {conv:.3f}% of full scale).  Mean reference opacity
{a_ref.mean():.3f}, {np.mean(a_ref > 0.01) * 100:.0f}% of rays see cloud.

Times: best wall-clock and CPU seconds of one time step (resampling only) with one thread, and
wall-clock with two threads ("2 thr", the default on this 2-core machine: the voxel work runs in
threads, numpy releasing the GIL).  1-minute load average {load[0]:.2f} before the run and
{os.getloadavg()[0]:.2f} after it, on 2 cores: other jobs may have shared the machine, so wall-clock
times are upper bounds.  Memory: the kept blocks (density + colour float32
+ coordinates); "dense shell" is what two float32 grids covering the whole atmosphere shell would take.
Errors: |opacity error| in % of full scale per ray family ({n_rays // 2} rays each): maximum,
99.9th and 99th percentiles, rms.

{md_table(["voxel (scene units)", "voxel height m / width km", "blocks (8³)", "active voxels", "memory MB",
           "dense shell MB", "wall s", "CPU s", "2 thr wall s",
           *(f"{f} {m}" for f, _ in families for m in ("max", "p99.9", "p99", "rms"))], rows)}

**At the default voxel size {DEFAULT_VOXEL_SIZE:g}:** 99th percentile {goal_p99} (≤ 2% in both families:
{"met" if goal_met else "NOT met"}); two-thread resampling {default_row[8]} s (≤ 2 s on 2 cores:
{"met" if float(default_row[8]) <= 2 else "NOT met"}).  The worst single ray is {default_worst:.1f}% off{worst_note}

along the 10 worst rays at {DEFAULT_VOXEL_SIZE:g}, the optical-depth error
by height band is {", ".join(f"{a // 1000}–{b // 1000} km {x:.0f}%" for a, b, x in zip(bands[:-1], bands[1:], share))};
{near_share:.0f}% of it lies where the cloud value is within 0.05 of the threshold.  Interpolating the
opacity between voxels averages the transfer function across its kink at the threshold, which
over-estimates it where the field hovers just around the threshold (a ray running along such a
surface collects that bias over a long path), and it smooths layers thinner than a few voxels
(the data's levels are 350 m apart at the ground and about 1 km at 4 km, against a voxel height of
{DEFAULT_VOXEL_SIZE * 6371e3 / 30:.0f} m).  A voxel is cubic in scene units, so with the 30× vertical exaggeration it is
30 times wider than tall in metres: the height is what falls short, but a VDB voxel is a cube
(one linear transform for the whole globe, whose vertical turns everywhere), so a finer height costs
the cube of the refinement in voxels.  The percentiles fall fast with the voxel size, the maximum slowly.

The paper's alternative, interpolating the scalar and then applying the transfer function
("post-classification"; in Blender a Float Curve on the grid), measured with the same rays
and reference:

{md_table(["voxel", "route", "active voxels", *(f"{f} {m}" for f, _ in families for m in ("max", "p99.9", "p99", "rms"))], post_rows)}

Post-classification has no threshold bias, so its worst rays are far better, but it is worse at
the percentiles: trilinear interpolation of the scalar flattens the peaks of thin layers before the
steep transfer function (0.3 → 0.7) is applied (interpolating the opacity flattens them too, but its
threshold bias partly makes up for it), and it needs about twice the active voxels (the scalar must
be stored below the threshold too).  Combining both grids per sample (the last rows, as a material
could) trades the worst rays against the 99th percentile; none brings both to 2%.  The grids keep
the opacity, which meets the goal at the 99th percentile for the rays of the Fig. 2 view only.

Memory against cloudy volume at the default voxel size ({DEFAULT_VOXEL_SIZE:g}): the threshold sets how much
of the atmosphere is cloud; bytes per active voxel stay about constant, so memory is proportional to the
cloudy volume, not to the globe.

{md_table(["threshold", "% grid points above", "candidate cells", "active voxels", "blocks", "memory MB",
           "bytes / active voxel"], mem_rows)}
"""
    write_section("volume", body, title="Volume clouds: voxel size vs memory, time and opacity error")
    return 0


if __name__ == "__main__":
    sys.exit(main())
