"""Volume clouds: exact shading and voxels against memory, build time and opacity error.

Two routes: the exact mode (:mod:`nephele.core.volume.volume_atlas`: the shader
evaluates the curvilinear field from texture atlases, a coarse support grid
bounds where it looks) and voxels (:func:`nephele.core.volume.sparse.resample`).
The error is measured along rays against the exact curvilinear reference
(:func:`nephele.core.volume.exact_ray.reference_optical_depth`: the field trilinear
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

from nephele.core.climate.grid import height_from_radius, lonlat_to_xyz  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.volume.exact_ray import (  # noqa: E402
    opacity,
    ray_samples,
    reference_optical_depth,
    segment_optical_depth,
    sphere_span,
    volume_optical_depth,
)
from nephele.core.volume.sparse import DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE, CurvilinearField, resample  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402
from nephele.core.volume.volume_atlas import DEFAULT_SUPPORT_SIZE, atlas_layout, exact_volume  # noqa: E402

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


def exact_optical_depths(field, evs, o, d, t_end, step, rays_per_chunk=300):
    """Optical depth along the reference's own sample points for each exact volume in ``evs``,
    and the reference recomputed on them (to show they are the same points).

    :func:`reference_optical_depth` samples each ray over its whole shell span
    (:func:`ray_samples`, one sample count for all rays) and keeps the segments
    before the ray meets the ground (``t_end``); the same arithmetic here, a
    few hundred rays at a time.  The exact route's value is
    :meth:`ExactVolume.sample` (the shader's field, NaN where its density is
    forced to zero): the atlas part is shared by all ``evs`` (same values
    atlas), only the support test differs.  Returns ``(taus (len(evs), n),
    tau_ref (n,), cloudy_outside (len(evs),), samples)``: ``cloudy_outside``
    counts the reference's cloudy samples (opacity > 0) outside each support.
    """
    r_in, r_out = field.radius_range()
    s0, s1 = sphere_span(o, d, r_out, r_in)
    span = s1 - s0
    m = max(int(np.ceil(span.max() / step)) + 1 if span.max() > 0 else 2, 2)
    u = np.linspace(0.0, 1.0, m)
    n = o.shape[0]
    taus = np.zeros((len(evs), n))
    tau_ref = np.zeros(n)
    outside = np.zeros(len(evs), np.int64)
    layout = evs[0].layout
    for a in range(0, n, rays_per_chunk):
        c = slice(a, a + rays_per_chunk)
        t = s0[c, None] + span[c, None] * u[None, :]  # as ray_samples
        seg = np.diff(t, axis=1)
        pts = (o[c, None, :] + t[..., None] * d[c, None, :]).reshape(-1, 3)
        t_samples = s0[c, None] + np.concatenate([np.zeros((seg.shape[0], 1)), np.cumsum(seg, axis=1)], axis=1)
        keep = t_samples[:, :-1] < t_end[c, None]  # as reference_optical_depth
        ref = field.sample("v", pts).reshape(seg.shape[0], m)
        tau_ref[c] = np.where(keep, segment_optical_depth(TF, ref[:, :-1], ref[:, 1:], seg), 0.0).sum(axis=1)
        value, _, ok = layout.shade(evs[0].values, pts, below=evs[0].below)
        cloudy = np.nan_to_num(TF(ref.reshape(-1))) > 0
        for e, ev in enumerate(evs):
            inside = ev.in_support(pts)
            outside[e] += np.count_nonzero(cloudy & ~inside)
            sv = np.where(ok & inside, value, np.nan).reshape(seg.shape[0], m)
            taus[e, c] = np.where(keep, segment_optical_depth(TF, sv[:, :-1], sv[:, 1:], seg), 0.0).sum(axis=1)
    return taus, tau_ref, outside, n * m


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: the small demo, fewer rays and voxel sizes")
    ap.add_argument("--source", help="dataset (default: the demo; the small demo with --quick)")
    args = ap.parse_args(argv)
    args.source = args.source or ("demo:small" if args.quick else "demo")
    rng = np.random.default_rng(0)
    load = os.getloadavg()
    ds = open_dataset(args.source)
    step_index = 0
    values = ds.read("cloud", step_index)
    grid = ds.grid
    nk, nj, ni = grid.shape
    n_rays = 100 if args.quick else 4000
    o, d = rays(n_rays, rng)
    field = CurvilinearField.from_grid(grid, {"v": values})

    # The anchor: the exact reference, at two steps to show it has converged.
    ref_step = 0.001 if args.quick else 0.00025
    (tau, t0, t1), ref_wall, ref_cpu = timed(lambda: reference_optical_depth(field, "v", TF, o, d, ref_step), 1)
    tau2, _, _ = reference_optical_depth(field, "v", TF, o, d, 2 * ref_step)
    a_ref = opacity(tau, DEFAULT_EXTINCTION)
    conv = np.abs(opacity(tau2, DEFAULT_EXTINCTION) - a_ref).max() * 100

    sizes = (0.004, DEFAULT_VOXEL_SIZE) if args.quick else (0.008, 0.006, 0.004, 0.003, 0.0027, 0.0025, 0.002, 0.0015)
    families = (("Fig. 2 camera", slice(0, n_rays // 2)), ("chords", slice(n_rays // 2, n_rays)))

    def errors(err, digits=2):
        """Per ray family: max, 99.9th and 99th percentile, rms of |error| in %FS."""
        out = []
        for _, sl in families:
            e = np.abs(err[sl]) * 100
            out += [f"{x:.{digits}f}"
                    for x in (e.max(), np.percentile(e, 99.9), np.percentile(e, 99), np.sqrt(np.mean(e**2)))]
        return out

    # The whole atmosphere shell as one dense grid, for scale.
    r_in, r_out = field.radius_range()
    shell = 4.0 / 3.0 * np.pi * (r_out**3 - r_in**3)
    rows = []
    for vs in sizes:
        repeat = 1 if vs < 0.0025 or args.quick else 3
        vol, wall, cpu = timed(lambda vs=vs: resample(grid, values, TF, voxel_size=vs, color_name="altitude",
                                                      workers=1), repeat)
        (_, wall2, cpu2) = timed(lambda vs=vs: resample(grid, values, TF, voxel_size=vs, color_name="altitude",
                                                        workers=2), repeat)
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
        svol, swall, scpu = timed(lambda vs=vs: resample(grid, values, step_tf, voxel_size=vs), 1)
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
            pv = np.concatenate([default_vol.sample(c)
                                 for c in np.array_split(pts.reshape(-1, 3), 40)]).reshape(seg.shape[0], -1)
            both = svol.stats["active_voxels"] + default_vol.stats["active_voxels"]
            for name, mix in (("both, min(opacity, TF(scalar) + 0.01)", np.minimum(pv, dens + 0.01)),
                              ("both, opacity where scalar > threshold", pv * (sv > TF.values[0])),
                              ("both, sqrt(opacity × TF(scalar))", np.sqrt(pv * dens))):
                e3 = opacity((seg * 0.5 * (mix[:, :-1] + mix[:, 1:])).sum(axis=1), DEFAULT_EXTINCTION) - a_ref
                post_rows.append([f"{vs:g}", name, both, *errors(e3)])
                print(post_rows[-1], flush=True)

    # Memory follows the cloudy volume: vary the threshold at the default voxel and support sizes.
    mem_rows = []
    layout = atlas_layout(grid)
    for thr in (0.1, 0.3, 0.5, 0.7, 0.9):
        tf = TransferFunction.ramp(thr, max(thr + 0.05, 0.7))
        vol = resample(grid, values, tf, voxel_size=DEFAULT_VOXEL_SIZE, color_name="altitude")
        cells = vol.stats["candidate_cells"]
        nsup = exact_volume(grid, values, tf, support_size=DEFAULT_SUPPORT_SIZE, layout=layout).support.shape[0]
        mem_rows.append([f"{thr:g}", f"{np.mean(values > thr) * 100:.1f}", cells, nsup, f"{nsup * 4 / 1e6:.1f}",
                         vol.stats["active_voxels"], vol.stats["blocks"], f"{vol.stats['bytes'] / 1e6:.1f}",
                         f"{vol.stats['bytes'] / max(vol.stats['active_voxels'], 1):.1f}"])

    # The exact mode, on the same rays against the same reference.
    support_sizes = (DEFAULT_SUPPORT_SIZE,) if args.quick else (0.02, DEFAULT_SUPPORT_SIZE, 0.005)
    layout, layout_wall, layout_cpu = timed(lambda: atlas_layout(grid), 3)
    evs, exact_rows = [], []
    for ss in support_sizes:
        ev, wall, cpu = timed(lambda ss=ss: exact_volume(grid, values, TF, support_size=ss, color_name="altitude",
                                                   layout=layout), 3)
        evs.append(ev)
        exact_rows.append([f"{ss:g}" + (" (default)" if ss == DEFAULT_SUPPORT_SIZE else ""),
                           f"{ss * 6371 / 30 * 1000:.0f} / {ss * 6371:.0f}", ev.support.shape[0],
                           f"{(ev.values.nbytes + layout.heights.nbytes) / 1e6:.1f}",
                           f"{ev.support.shape[0] * 4 / 1e6:.1f}", f"{wall:.2f}", f"{cpu:.2f}"])
    assert all(np.array_equal(ev.values, evs[0].values) for ev in evs)
    (taus, tau_same, outside, n_samples), exact_wall, exact_cpu = timed(
        lambda: exact_optical_depths(field, evs, o, d, t1, ref_step), 1)
    same_points = np.abs(opacity(tau_same, DEFAULT_EXTINCTION) - a_ref).max() * 100
    exact_errs = []
    for row, tau_e, out in zip(exact_rows, taus, outside):
        err = opacity(tau_e, DEFAULT_EXTINCTION) - a_ref
        exact_errs.append(err)
        row += [*errors(err, 4), int(out)]
        print(row, flush=True)
    exact_default = next(r for r in exact_rows if r[0].endswith("(default)"))
    exact_max = max(float(exact_default[7]), float(exact_default[11]))
    exact_goal = exact_max <= 2.0
    exact_build_goal = float(exact_default[5]) <= 2.0
    ex_worst = max(np.abs(e).max() for e in exact_errs) * 100

    default_row = next(r for r in rows if r[0].endswith("(default)"))
    goal_p99 = ", ".join(f"{name} {default_row[11 + 4 * n]}%" for n, (name, _) in enumerate(families))
    goal_met = all(float(default_row[11 + 4 * n]) <= 2.0 for n in range(len(families)))
    default_worst = np.abs(default_err).max() * 100
    finest = rows[-1]
    worst_note = (": the maximum falls only slowly with the voxel size (at "
                  f"{finest[0]}, {finest[3]} active voxels and {finest[7]} CPU-s, it is still "
                  f"{max(float(finest[9]), float(finest[13])):.1f}%), because of where it comes from:"
                  if default_worst > 2 else ".  Where the largest errors come from:")
    fam = [name for name, _ in families]
    exact_same = all(np.array_equal(e, exact_errs[0]) for e in exact_errs)
    same_note = ("The support size changes where the renderer looks, not what it sees: the errors are identical "
                 "in every row." if exact_same else "The rows' errors differ: a support hides cloud.")
    same_note += (" No cloudy sample lies outside a support, so the remaining error" if not outside.any()
                  else " The remaining error")
    same_note += (f" (worst {ex_worst:.4f}% over all rows) is that of the shader's float32 program against the "
                  "float64 reference.")
    body = f"""
Demo grid {ni}×{nj}×{nk} (`open_dataset("{args.source}")`, step {step_index}, \
cloud {np.mean(values > 0.3) * 100:.1f}% of
grid points above 0.3), transfer function {TF.points} (the Fig. 2 example's), extinction {DEFAULT_EXTINCTION:g}
per scene unit at opacity 1, exaggeration 30, colour = altitude.  Error: opacity along {n_rays} rays
(half from a Fig. 2-like camera, half random chords through the shell, many grazing the cloud layers)
against the **exact curvilinear reference** (the anchor: the field trilinear in each curvilinear cell,
piecewise-linear between samples {ref_step:g} apart, Williams & Max closed form through the transfer
function; {ref_wall:.1f} s wall / {ref_cpu:.1f} s CPU for all rays; halving its step changes the opacity by
at most {conv:.3f}% of full scale).  Mean reference opacity {a_ref.mean():.3f}, {np.mean(a_ref > 0.01) * 100:.0f}% of
rays see cloud.  Errors: |opacity error| in % of full scale per ray family ({n_rays // 2} rays each):
maximum, 99.9th and 99th percentiles, rms.  Both routes below are measured in the same run, on the same
rays, against the same reference.  1-minute load average {load[0]:.2f} before the run and
{os.getloadavg()[0]:.2f} after it, on 2 cores: other jobs may have shared the machine, so wall-clock
times are upper bounds.

### Exact shading (the default mode)

"Add volume clouds" renders in the exact mode by default (`core/volume/volume_atlas.py`): the material
evaluates the curvilinear field itself at every volume sample, from a values atlas (a tile per level)
and a heights atlas (four levels per texel), with the transfer function as clamped ramps; a coarse
support grid (a VDB of voxels `support_size` apart whose trilinear footprint covers every cell that may
be cloudy) only bounds where the renderer looks.  The error here is that of the **shader's field**:
`ExactVolume.sample` (the node graph's program in float32, texel for texel as Cycles' linear image
lookup, NaN where its density is forced to zero) at the reference's own {n_samples} sample points,
integrated exactly as the reference is (recomputing the reference on those points reproduces its opacity
to {same_points:.1e}% of full scale: the same points; {exact_wall:.1f} s wall / {exact_cpu:.1f} s CPU for all \
support sizes, the atlas
lookups shared).  Cycles adds Monte-Carlo noise of its volume sampling on top of this; a render test
checks the node graph in Cycles, and no number for that noise is given here.

Build: best of 3 wall-clock and CPU seconds of `exact_volume` for one frame (values atlas + support
voxels), the layout passed in: `atlas_layout` (axes and heights atlas, time-independent, once per grid)
takes {layout_wall:.3f} s wall / {layout_cpu:.3f} s CPU.  Memory: "atlas MB" the values and heights
atlases (float32 RGBA), "support MB" the support voxels × 4 bytes (roughly a NanoVDB float grid).
"cloudy outside" counts the reference's samples with non-zero opacity outside the support (must be 0).

{md_table(["support size (scene units)", "support voxel height m / width km", "support voxels", "atlas MB",
           "support MB", "build wall s", "build CPU s",
           *(f"{f} {m}" for f in fam for m in ("max", "p99.9", "p99", "rms")), "cloudy outside"], exact_rows)}

**At the default support size {DEFAULT_SUPPORT_SIZE:g}:** worst ray {exact_default[7]}% (Fig. 2 camera) and
{exact_default[11]}% (chords) of full scale (≤ 2% on every ray: {"met" if exact_goal else "NOT met"}); one frame
builds in {exact_default[5]} s wall (≤ 2 s: {"met" if exact_build_goal else "NOT met"}).  {same_note}
A finer support costs build time and memory and only saves the renderer empty steps.

### Voxels (option: `mode="voxels"`)

The voxel route resamples opacity into cubic voxels (`resample`) that Cycles interpolates trilinearly.
Times: best wall-clock and CPU seconds of one time step (resampling only) with one thread, and
wall-clock with two threads ("2 thr", the default on this 2-core machine: the voxel work runs in
threads, numpy releasing the GIL).  Memory: the kept blocks (density + colour float32 + coordinates);
"dense shell" is what two float32 grids covering the whole atmosphere shell would take.

{md_table(["voxel (scene units)", "voxel height m / width km", "blocks (8³)", "active voxels", "memory MB",
           "dense shell MB", "wall s", "CPU s", "2 thr wall s",
           *(f"{f} {m}" for f in fam for m in ("max", "p99.9", "p99", "rms"))], rows)}

**At the voxel mode's default voxel size {DEFAULT_VOXEL_SIZE:g}:** 99th percentile {goal_p99} (≤ 2% in both families:
{"met" if goal_met else "NOT met"}); two-thread resampling {default_row[8]} s (≤ 2 s on 2 cores:
{"met" if float(default_row[8]) <= 2 else "NOT met"}).  The worst single ray is {default_worst:.1f}% off (≤ 2% on every
ray: {"met" if default_worst <= 2 else "NOT met"}){worst_note}

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
This is why the exact mode is the default.

The paper's alternative, interpolating the scalar and then applying the transfer function
("post-classification"; in Blender a Float Curve on the grid), measured with the same rays
and reference:

{md_table(["voxel", "route", "active voxels",
           *(f"{f} {m}" for f in fam for m in ("max", "p99.9", "p99", "rms"))], post_rows)}

Post-classification has no threshold bias, so its worst rays are far better, but it is worse at
the percentiles: trilinear interpolation of the scalar flattens the peaks of thin layers before the
steep transfer function (0.3 → 0.7) is applied (interpolating the opacity flattens them too, but its
threshold bias partly makes up for it), and it needs about twice the active voxels (the scalar must
be stored below the threshold too).  Combining both grids per sample (the last rows, as a material
could) trades the worst rays against the 99th percentile; none brings both to 2%.

### Memory against cloudy volume

The threshold sets how much of the atmosphere is cloud; the exact mode's support voxels (at
{DEFAULT_SUPPORT_SIZE:g}) and the voxel mode's active voxels (at {DEFAULT_VOXEL_SIZE:g}) both follow the \
cloudy volume, not
the globe (the exact mode's atlases, {exact_default[3]} MB, do not depend on the threshold).

{md_table(["threshold", "% grid points above", "candidate cells", "exact: support voxels", "exact: support MB",
           "voxels: active voxels", "voxels: blocks", "voxels: memory MB", "voxels: bytes / active voxel"], mem_rows)}
"""
    write_section("volume", body,
                  title="Volume clouds: exact shading and voxels vs memory, build time and opacity error")
    write_section("volume-curvilinear", curvilinear(args.quick),
                  title="Exact volume mode on a curvilinear grid: the column index map")
    return 0


def curvilinear(quick):
    """The exact mode on a WRF-like Lambert conformal grid: the shader finds a point's column in an index
    map (bilinear texels); the anchor is ColumnLocator (float64 search and Newton inversion), timed on the
    same points.  Errors at random points inside the grid's columns."""
    import pyproj

    from nephele.core.climate.grid import GlobeGrid, globe_radius
    from nephele.core.volume.volume_atlas import index_map

    nx, ny, nk, dx = (100, 75, 10, 30e3) if quick else (200, 150, 30, 15e3)
    crs = pyproj.CRS.from_proj4("+proj=lcc +lat_1=30 +lat_2=60 +lat_0=40 +lon_0=-97 +R=6371000")
    to_lonlat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    x, y = np.meshgrid((np.arange(nx) - (nx - 1) / 2) * dx, (np.arange(ny) - (ny - 1) / 2) * dx)
    lon, lat = to_lonlat.transform(x, y)
    ground = np.maximum(0.0, 2500.0 * np.sin(np.deg2rad(3 * lon)) * np.cos(np.deg2rad(2 * lat)))
    s = np.linspace(0.0, 1.0, nk)[:, None, None] ** 1.5
    grid = GlobeGrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), ground + (16000.0 - ground) * s,
                     lon2d=lon, lat2d=lat)
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    values = (0.5 + 0.45 * np.sin(9 * lam + 1.0) * np.cos(6 * phi) * np.cos(grid.height / 4000.0)).astype(np.float32)
    field = CurvilinearField.from_grid(grid, {"value": values})
    rng = np.random.default_rng(1)
    n = 20000 if quick else 200000
    i, j = rng.uniform(0, nx - 1, n), rng.uniform(0, ny - 1, n)
    # Bilinear in the cell's corner positions, then onto the sphere: inside the columns (up to the curvature).
    i0, j0 = np.minimum(i.astype(int), nx - 2), np.minimum(j.astype(int), ny - 2)
    fi, fj = i - i0, j - j0
    corner = lonlat_to_xyz(lon, lat, 1.0)
    pts = ((1 - fj) * (1 - fi))[:, None] * corner[j0, i0] + ((1 - fj) * fi)[:, None] * corner[j0, i0 + 1] \
        + (fj * (1 - fi))[:, None] * corner[j0 + 1, i0] + (fj * fi)[:, None] * corner[j0 + 1, i0 + 1]
    pts /= np.linalg.norm(pts, axis=1)[:, None]
    pts *= globe_radius(rng.uniform(500.0, 15000.0, n))[:, None]
    (ri, rj), loc_wall, loc_cpu = timed(lambda: field.columns(pts), 1)
    flat, f, _, ok = field.locate(pts)
    ref = field.interpolate("value", flat, f, ok)
    rows = []
    for texels in (2, 4, 8):
        im, wall, cpu = timed(lambda texels=texels: index_map(field.columns, texels=texels), 1)
        p32 = pts.astype(np.float32)
        (ci, cj, _), look_wall, _ = timed(lambda im=im, p32=p32: im.lookup(p32), 3)
        e = np.maximum(np.abs(ci - ri), np.abs(cj - rj))
        layout = atlas_layout(grid)
        layout.index = im
        value, _, sok = layout.shade(layout.values_atlas(field), pts)
        both = sok & np.isfinite(ref)
        ve = np.abs(value[both] - ref[both])
        rows.append([f"{texels}" + (" (default)" if texels == 4 else ""), f"{im.image.shape[1]}×{im.image.shape[0]}",
                     f"{im.image.nbytes / 1e6:.1f}", f"{wall:.2f}", f"{cpu:.2f}", f"{look_wall * 1e3:.0f}",
                     f"{e.max():.4f}", f"{np.percentile(e, 99.9):.4f}", f"{np.mean(sok != np.isfinite(ref)) * 100:.3f}",
                     f"{ve.max():.1e}", f"{np.percentile(ve, 99.9):.1e}"])
        print(rows[-1], flush=True)
    return f"""
A Lambert conformal grid as WRF writes it ({nx}×{ny} columns {dx / 1e3:g} km apart, {nk} terrain-following
levels; 2-D latitude/longitude from pyproj), a field of order 1 varying by ~0.1 per cell.  The shader
locates a point's column by an index map: the gnomonic chart coordinates about the grid's centre (three
dot products, two divisions) look up fractional column indices in a float32 texture filled by
ColumnLocator (past the edge, the edge cells' own bilinear maps), bilinear between texels.  {n} random
points inside the columns, 0.5–15 km up.  The anchor, ColumnLocator itself on the same points (float64
raster guess, walk, Newton inversion): {loc_wall:.2f} s wall / {loc_cpu:.2f} s CPU.  Columns: texels per
cell along each axis, the map's size and memory, its build time, the NumPy emulation's lookup time for all
points, the index error (cells) against ColumnLocator, the share of points whose inside/outside decision
differs from the reference, and the shaded value's error against the float64 reference (trilinear in
the curvilinear cell).  Load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.

{md_table(["texels per cell", "map", "MB", "build s (wall)", "build s (CPU)", "lookup ms", "index error max",
           "index error p99.9", "inside differs %", "value error max", "value error p99.9"], rows)}
"""


if __name__ == "__main__":
    sys.exit(main())
