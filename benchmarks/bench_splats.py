"""Splats (Fig. 3): kernel normalisation, footprint error, renderer speed against error, beside anchors.

Part 1 — partition of unity: the worst deviation of the summed weights from 1
at random points (and lattice points, cell centres, face/edge midpoints) for
our windowed Gaussian, the paper's truncated Gaussian (σ 0.65, R 2.5), and
VTK's ``vtkGaussianSplatter`` (sum mode, radius 2.5 cells, its default
exponent −5) sampled 4× per cell; then ours on a sheared lattice and on the
demo's curvilinear globe cells (even levels, and the demo's own stretched
terrain-following levels: ``vertical="native"``), and over the whole demo
interior both natively and on shells (the default layout, ``core.splats.partition``),
summing each splat's own weight times its opacity as the renderers draw it.

Part 2 — footprints: the exact footprint (Gauss–Legendre) and the renderer's
ρ² table against scipy ``quad`` line integrals, and their costs.

Part 3 — renderer speed against error: a Gaussian cloud (colour changing along
the view) splatted at shrinking spacing, against the exact emission–absorption
ray integral of the same kernel-reconstructed medium (``ray_integral``), whose
time is shown.

Part 4 — a Fig. 3 frame of the demo climate (640×480, streaks, globe
occluding): samples, projection and render times against the number of
splats, beside the anchors on the same samples in the same run:
``vtkGaussianSplatter`` resampling them into a 128³ volume and the project's
own volume resampling (``core.volume.resample``, the Fig. 2 clouds) of the
same step.

Usage: ``python benchmarks/bench_splats.py [--quick]`` (``--quick``: smaller
cases, prints only, does not write docs/benchmarks.md).
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402

from nephele.core.climate.dataset import ArrayDataset, hourly  # noqa: E402
from nephele.core.climate.grid import GlobeGrid  # noqa: E402
from nephele.core.climate.synthetic import demo_dataset  # noqa: E402
from nephele.core.splats import (  # noqa: E402
    Camera,
    Splats,
    footprint_table,
    principal_axes,
    ray_integral,
    reconstruct,
    render_splats,
    sphere_depth,
    splat_kernel,
    splat_samples,
    streak_maps,
)
from nephele.core.splats.partition import shell_heights, shell_reach, stencil_weights, widening  # noqa: E402
from nephele.core.volume.sparse import resample  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402

TF = TransferFunction.ramp(0.3, 0.8)


def timed(f, repeat=1):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return out, best


def probe_points(n, seed=0):
    pts = np.random.default_rng(seed).random((n, 3))
    special = np.array([[0, 0, 0], [0.5, 0.5, 0.5], [0.5, 0, 0], [0.5, 0.5, 0], [0.25, 0.25, 0.25]])
    return np.vstack([pts, special])


def lattice_deviation(kernel, pts):
    n = int(np.ceil(kernel.radius)) + 1
    g = np.arange(-n, n + 2)
    lat = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    s = sum(kernel.weight(pts - k) for k in lat)
    return float(np.abs(s - 1).max()), float((s.max() - s.min()) / s.mean())


def drawn_sum(sp, layout, kernel, f, reach, exaggeration=30.0):
    """Σ opacity_s w_s (each splat's own axes and opacity: what the renderers draw) at points of
    fractional layout indices ``f``, and whether all layout samples within ``reach`` are splats."""
    from scipy import ndimage

    shape = layout.shape
    p = layout.points(1.0, exaggeration, dtype=np.float64)
    k, j, i = sp.index.T
    to_cell = np.tile(np.eye(3), shape + (1, 1))
    fac = np.zeros(shape)
    present = np.zeros(shape, bool)
    to_cell[k, j, i] = sp.radius * np.linalg.inv(sp.axes)
    fac[k, j, i] = sp.opacity
    present[k, j, i] = True
    row, kk, jj, ii, w = stencil_weights(p, to_cell, f, kernel, reach)
    total = np.bincount(row, w * fac[kk, jj, ii], minlength=len(f))
    size = tuple(2 * r + 2 for r in reach)
    full = ndimage.minimum_filter(present.astype(np.uint8), size=size, origin=(-1, -1, -1),
                                  mode=("nearest", "nearest", "wrap"))
    b = np.floor(f).astype(int)
    return total, full[b[:, 0], b[:, 1], b[:, 2] % shape[2]].astype(bool)


def demo_sweep(vertical, m, size="full"):
    """|Σ opacity·w − 1| over ``m`` random points of the whole demo interior (3 levels/shells from
    the bottom and top, 3 rows from the poles, all longitudes) for a constant field of opacity 1;
    ``size``: the demo's."""
    full = demo_dataset(size).grid
    k = splat_kernel()
    ds = ArrayDataset(full, hourly("2000-01-01", 1), {"cloud": np.ones((1,) + full.shape, np.float32)})
    sp, sec = timed(lambda: splat_samples(ds, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), kernel=k,
                                          vertical=vertical))
    nk, nj, ni = full.shape
    if vertical == "shells":
        h = shell_heights(full)
        layout = GlobeGrid(full.lon, full.lat, np.broadcast_to(h[:, None, None], full.shape).copy())
        rk, rj, ri = shell_reach(full.lat, h, k.radius, *widening(full.lat, h, k.radius))
        reach = (int(rk[3 : nk - 3].max()), rj, int(ri[3 : nj - 3].max()))
    else:
        layout, reach = full, (4, 4, 4)
    rng = np.random.default_rng(0)
    f = np.column_stack([rng.uniform(3, nk - 4, m), rng.uniform(3, nj - 4, m), rng.uniform(0, ni, m)])
    s, ok = drawn_sum(sp, layout, k, f, reach)
    e = np.abs(s - 1)
    lat = np.abs(np.interp(f[:, 1], np.arange(nj), full.lat))
    return e, ok, lat, f[:, 0], sec


def vtk_splatter(points, scalars, dims, bounds, radius):
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    poly = vtk.vtkPolyData()
    vp = vtk.vtkPoints()
    vp.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
    poly.SetPoints(vp)
    if scalars is not None:
        poly.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(scalars, dtype=np.float64), deep=True))
    sp = vtk.vtkGaussianSplatter()
    sp.SetInputData(poly)
    sp.SetSampleDimensions(*dims)
    sp.SetModelBounds(*bounds)
    sp.SetRadius(radius)
    sp.SetAccumulationModeToSum()
    sp.SetScalarWarping(scalars is not None)
    sp.NormalWarpingOff()
    sp.CappingOff()
    sp.Update()
    return vtk_to_numpy(sp.GetOutput().GetPointData().GetScalars()).reshape(dims[::-1])


def part_kernels(quick):
    pts = probe_points(1000 if quick else 4000)
    rows = []
    for kind, label in (("gaussian", "ours: exp(-r²/2σ²)(1-r²/R²)², σ 0.85, R 2.5"),
                        ("paper", "paper: truncated Gaussian σ 0.65, R 2.5")):
        k = splat_kernel(kind)
        (worst, ripple), sec = timed(lambda k=k: lattice_deviation(k, pts))
        rows.append([label, f"{worst:.2e}", f"{ripple:.2e}", "-"])
    n, sub = 16, 4
    g = np.arange(n, dtype=np.float64)
    lat = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    dims = ((n - 1) * sub + 1,) * 3
    vol, sec = timed(lambda: vtk_splatter(lat, None, dims, (0, n - 1) * 3, 2.5 / (n - 1)))
    inner = vol[4 * sub : -4 * sub, 4 * sub : -4 * sub, 4 * sub : -4 * sub]
    ideal = np.pi ** 1.5 * (2.5**2 / 5) ** 1.5  # ∫ exp(-5 r²/R²) d³x, untruncated: VTK's mean should be near it
    rows.append(
        [
            f"vtkGaussianSplatter (sum, R 2.5 cells, exponent -5), {sub}× per cell; mean / ideal integral "
            f"{inner.mean() / ideal:.4f}",
            f"{np.abs(inner / inner.mean() - 1).max():.2e}",
            f"{(inner.max() - inner.min()) / inner.mean():.2e}",
            f"{sec:.2f}",
        ]
    )
    table1 = md_table(["kernel", "worst abs(Σw − 1) (VTK: vs its mean)", "(max − min) / mean", "VTK time (s)"], rows)

    k = splat_kernel()
    rows = []
    jac = 0.1 * np.array([[1.0, 0.4, 0.1], [0.0, 0.8, 0.3], [0.2, 0.0, 1.3]])
    g = np.arange(12, dtype=np.float64)
    idx = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    m = len(idx)
    sp = Splats(idx @ jac.T, principal_axes(np.broadcast_to(jac, (m, 3, 3)), k.radius), np.ones((m, 3)), np.ones(m),
                np.zeros((m, 3)), k.radius)
    u = np.random.default_rng(1).uniform(4, 7, (1500, 3))
    rows.append(["sheared, anisotropic lattice (12³)", f"{np.abs(reconstruct(sp, k, u @ jac.T) - 1).max():.2e}", "", "",
                 ""])
    full = demo_dataset("full").grid
    for label, even in (("native: globe cells 1.125°, 19 even levels (31×31 block, 22–57°N)", True),
                        ("native: demo cells, stretched terrain-following levels (same block)", False)):
        h = full.height[:, 100:131, :31]
        if even:
            h = np.broadcast_to(np.linspace(0.0, 20000.0, full.shape[0])[:, None, None], h.shape).copy()
        grid = GlobeGrid(full.lon[:31], full.lat[100:131], h)
        ds = ArrayDataset(grid, hourly("2000-01-01", 1), {"cloud": np.ones((1,) + grid.shape)})
        spl = splat_samples(ds, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), kernel=k, vertical="native")
        nk, nj, ni = grid.shape
        rng = np.random.default_rng(0)
        mm = 300 if quick else 1000
        f = np.column_stack([rng.uniform(3, nk - 4, mm), rng.uniform(3, nj - 4, mm), rng.uniform(3, ni - 4, mm)])
        p = grid.points(1.0, 30.0, dtype=np.float64)
        b = np.floor(f).astype(int)
        fr = f - b
        x = np.zeros((mm, 3))
        for corner in np.ndindex(2, 2, 2):
            wgt = np.prod([fr[:, a] if c else 1 - fr[:, a] for a, c in enumerate(corner)], axis=0)
            x += wgt[:, None] * p[b[:, 0] + corner[0], b[:, 1] + corner[1], b[:, 2] + corner[2]]
        rows.append([label, f"{np.abs(reconstruct(spl, k, x, values=spl.opacity) - 1).max():.2e}", "", "", ""])
    mm = 1000 if quick else 3000
    for label, vertical in (("native: whole demo interior (terrain-following levels)", "native"),
                            ("**shells (default)**: whole demo interior, widened kernels, factors in the opacity",
                             "shells")):
        e, ok, lat, lev, sec = demo_sweep(vertical, mm, "small" if quick else "full")
        low, polar = ok & (lev < 6), ok & (lat > 75)
        worst = [f"{e[m].max():.2e}" if m.any() else "no point" for m in (ok, low, polar)]  # (the small demo's)
        rows.append([f"{label}; {ok.sum()} of {mm} points with all neighbours above ground; splat_samples {sec:.1f} s",
                     worst[0], f"{np.median(e[ok]):.2e}" if ok.any() else "no point", *worst[1:]])
    table2 = md_table(["ours, Σ opacity·w with the splats' own axes (constant field)", "worst abs(Σ − 1)", "median",
                       "levels 3–6 worst", "abs(lat) > 75° worst"], rows)
    return table1 + "\n\n" + table2


def part_footprints(quick):
    from scipy.integrate import quad

    rows = []
    rng = np.random.default_rng(2)
    npts = 60 if quick else 200
    for kind in ("gaussian", "paper"):
        k = splat_kernel(kind)
        p = rng.uniform(-k.radius, k.radius, (npts, 2))
        ref = np.array([quad(lambda z, k=k, x=x, y=y: k.weight([[x, y, z]])[0], -3, 3, limit=200, epsabs=1e-13)[0]
                        for x, y in p])
        exact = np.abs(k.footprint(p) - ref).max() / k.peak
        table = np.abs(k.footprint_rho2(np.sum(p * p, axis=1)) - ref).max() / k.peak
        t64 = footprint_table(k, 64)
        c = -k.radius + (np.arange(64) + 0.5) * (2 * k.radius / 64)
        sel = rng.integers(0, 64, (20, 2))
        tex = max(abs(t64[j, i] - quad(lambda z, k=k, c=c, i=i, j=j: k.weight([[c[i], c[j], z]])[0], -3, 3,
                                       limit=200)[0]) for j, i in sel) / k.peak
        big = rng.uniform(-k.radius, k.radius, (10**6, 2))
        _, t_exact = timed(lambda k=k, big=big: k.footprint(big))
        _, t_table = timed(lambda k=k, big=big: k.footprint_rho2(np.sum(big * big, axis=1)), 3)
        rows.append([kind, f"{k.peak:.4f}", f"{exact:.1e}", f"{tex:.1e}", f"{table:.1e}", f"{t_exact * 1e3:.0f}",
                     f"{t_table * 1e3:.0f}"])
    return md_table(["kernel", "peak F(0) (cells)", "exact vs quad / peak", "64² texture vs quad / peak",
                     "ρ² table vs quad / peak", "exact ms / 10⁶", "table ms / 10⁶"], rows)


def blob(h, k):
    g = np.arange(-1.2, 1.2 + 1e-9, h)
    c = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    o = np.exp(-np.sum(c * c, axis=1) / (2 * 0.35**2))
    c, o = c[o > 1e-4], o[o > 1e-4]
    t = np.clip(0.5 + 1.2 * c[:, 2], 0, 1)
    col = np.column_stack([t, np.full_like(t, 0.3), 1 - t])
    m = len(c)
    return Splats(c, principal_axes(np.broadcast_to(np.eye(3) * h, (m, 3, 3)), k.radius), col, o, np.zeros((m, 3)),
                  k.radius)


def part_convergence(quick):
    k = splat_kernel()
    rows = []
    cams = [("orthographic", Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.4)),
            ("perspective 45°", Camera.look_at((0.6, 0.4, 3), (0, 0, 0), up=(0, 1, 0), fov=45))]
    for label, cam in cams[:1] if quick else cams:
        for h in (0.3, 0.15) if quick else (0.3, 0.15, 0.075):
            sp = blob(h, k)
            img, t_r = timed(lambda sp=sp, cam=cam: render_splats(sp, k, cam, 48, 48, extinction=5.0, prefilter=0.0),
                             1 if quick else 3)
            ref, t_x = timed(lambda sp=sp, cam=cam: ray_integral(sp, k, cam, 48, 48, extinction=5.0, steps=300))
            d = np.abs(img - ref)
            rows.append([label, h, len(sp), f"{t_r:.3f}", f"{d[..., :3].max():.2e}",
                         f"{np.sqrt(np.mean(d[..., :3] ** 2)):.2e}", f"{d[..., 3].max():.1e}", f"{t_x:.1f}"])
    return md_table(["camera", "spacing h", "splats", "render s (48²)", "worst colour error", "rms colour error",
                     "worst alpha error", "exact ray integral s"], rows)


def part_frame(quick, picture=None):
    ds = demo_dataset("small" if quick else "full")
    k = splat_kernel()
    cam = Camera.look_at((2.2, -2.0, 1.6), (0, 0, 0), fov=40)
    w, h = (320, 240) if quick else (640, 480)
    depth = sphere_depth(cam, w, h)
    maps = streak_maps()
    rows = []
    out = None
    for stride in ((2, 1) if quick else (4, 2, 1)):
        sp, t_s = timed(lambda stride=stride: splat_samples(ds, "cloud", 12.0, TF, color_var="altitude", stride=stride,
                                                            kernel=k))
        img, t_r = timed(lambda sp=sp: render_splats(sp, k, cam, w, h, streaks=maps, hours=12.0, depth=depth))
        rows.append([f"splats, stride {stride}", len(sp), f"{t_s:.2f}", f"{t_r:.2f}", f"{w}×{h}, streaks, globe depth"])
        if stride == 1:
            out = img
    # Anchors on the same stride-1 samples / the same step.
    lo, hi = sp.centers.min(0) - 0.06, sp.centers.max(0) + 0.06
    side = float((hi - lo).max())
    semi = np.sort(np.linalg.norm(sp.axes, axis=1), axis=1)  # cut-off semi-axes, smallest first
    cell = np.median(semi, axis=0) / k.radius
    for n in ((64,) if quick else (128, 256)):
        # VTK splats spheres: give them our kernels' median largest cut-off radius (a fraction of the box side).
        radius = float(np.median(semi[:, 2])) / side
        _, t_v = timed(lambda n=n,
                       radius=radius: vtk_splatter(sp.centers, sp.opacity, (n, n, n),
                                                   (lo[0], lo[0] + side, lo[1], lo[1] + side, lo[2], lo[2] + side),
                                                   radius))
        rows.append([f"anchor: vtkGaussianSplatter → {n}³ volume", len(sp), "-", f"{t_v:.2f}",
                     f"voxel {side / (n - 1):.4f}; median cell {cell[2]:.4f} × {cell[1]:.4f} × {cell[0]:.4f}"])
    cloud = ds.read_at("cloud", 12.0)
    vol, t_vol = timed(lambda: resample(ds.grid, cloud, TF, color_values=None, color_name="altitude"))
    rows.append(["anchor: core.volume.resample (Fig. 2 clouds)", f"{vol.stats['active_voxels']} voxels", "-",
                 f"{t_vol:.2f}", "voxel 0.0027 (default), sparse 8³ blocks"])
    if picture is not None and out is not None:
        save_png(out, picture, globe_image(cam, w, h, depth))
    return md_table(["method", "samples", "samples s", "render / resample s", "notes"], rows)


def globe_image(cam, w, h, depth):
    """A plain Lambert-shaded globe (ocean blue) under the splats, dark sky elsewhere."""
    f = cam.pixels_per_unit(w)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = np.stack([(cols - w / 2) / f, -(rows - h / 2) / f, -np.ones_like(cols)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    world = d @ cam.world_to_camera[:3, :3]  # camera-space directions to scene
    hit = np.isfinite(depth)
    p = cam.position + np.where(hit, depth, 0.0)[..., None] * world
    sun = np.array([0.6, -0.7, 0.4]) / np.linalg.norm([0.6, -0.7, 0.4])
    shade = 0.15 + 0.85 * np.clip(p @ sun, 0, 1)
    return np.where(hit[..., None], np.array([0.03, 0.08, 0.2]) * shade[..., None], np.array([0.005, 0.005, 0.012]))


def save_png(img, path, background):
    """Composite over ``background`` (linear RGB) and write an 8-bit sRGB PNG (via matplotlib)."""
    import matplotlib.image as mpimg

    rgb = np.clip(img[..., :3] + (1 - img[..., 3:]) * background, 0, 1)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(path).with_suffix(".tmp.png")
    mpimg.imsave(tmp, srgb)
    os.replace(tmp, path)


BLENDER_CASES = [
    # (label, scene, width, height, splats seen by camera rays only); "eevee": EEVEE, 1 sample, no shadows
    ("splats in EEVEE (Mesa llvmpipe: software OpenGL, no GPU here)", "eevee", 640, 480, True),
    ("splats, camera rays only (the add-on's setting)", "splats", 640, 480, True),
    ("anchor: volume clouds (Fig. 2 material, exact mode), same camera", "volume", 640, 480, True),
    ("splats, camera rays only", "splats", 160, 120, True),
    ("splats seen by all rays (shadow, diffuse, glossy: the previous setting)", "splats", 160, 120, False),
]


def blender_child(scene_kind, w, h, camera_only):
    """In a fresh Blender-Python process: build Fig. 3 (or the same view of the Fig. 2 volume clouds)
    from the full demo at 0 h, render one Cycles frame at 1 spp on 2 threads (or EEVEE, 1 sample);
    prints one JSON line."""
    import json

    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    import nephele

    nephele.register()
    from nephele.addon import presets

    view = {k: presets.FIG3_DEFAULTS[k] for k in ("camera_lon", "camera_lat", "camera_distance")}
    scene = bpy.context.scene
    t0 = time.perf_counter()
    if scene_kind in ("splats", "eevee"):
        objs = presets.fig3(scene, source="demo", size=(w, h), samples=1, frames=(1, 1))
        n = len(objs["splats"].data.vertices)
        if not camera_only:
            o = objs["splats"]
            o.visible_shadow = o.visible_diffuse = o.visible_glossy = o.visible_transmission = True
    else:
        presets.fig2(scene, size=(w, h), samples=1, frames=(1, 1), haze=False, **view)
        n = 0
    scene.frame_set(1)  # 0 h
    build = time.perf_counter() - t0
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    if scene_kind == "eevee":
        scene.render.engine = "BLENDER_EEVEE"
        scene.eevee.taa_render_samples = 1
        scene.eevee.use_shadows = False  # llvmpipe: the shadow pass alone takes minutes
    scene.render.filepath = str(Path(tempfile.gettempdir()) / f"nephele_bench_splats_{scene_kind}_{w}.png")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    render = time.perf_counter() - t0
    nxt = None
    if scene_kind == "eevee":  # a film's next frame: the splats refilled for 1 h later, then rendered
        scene.frame_end = 2
        t0 = time.perf_counter()
        scene.frame_set(2)
        bpy.ops.render.render(write_still=True)
        nxt = time.perf_counter() - t0
    print("BENCH " + json.dumps({"build": build, "render": render, "next": nxt, "splats": n}), flush=True)


def part_blender():
    import json
    import subprocess

    rows = []
    for label, kind, w, h, cam_only in BLENDER_CASES:
        cmd = [sys.executable, __file__, "--blender-child", kind, str(w), str(h), str(int(cam_only))]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        r = json.loads(next(line for line in out.splitlines() if line.startswith("BENCH "))[6:])
        print(label, w, h, r, flush=True)
        nxt = "-" if r["next"] is None else f"{r['next']:.1f}"
        rows.append([label, f"{w}×{h}", r["splats"] or "-", f"{r['build']:.1f}", f"{r['render']:.1f}", nxt])
    return md_table(["scene (full demo, 0 h; Cycles CPU 1 spp, 2 threads, unless EEVEE)", "size", "splats", "build s",
                     "first frame render s", "next frame s (splats refilled + render)"], rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller cases; print only, do not write docs/benchmarks.md")
    ap.add_argument("--blender", action="store_true",
                    help="only the Blender frame times (Cycles), into their own section of docs/benchmarks.md")
    ap.add_argument("--blender-child", nargs=4, metavar=("SCENE", "W", "H", "CAMERA_ONLY"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.blender_child:
        kind, w, h, cam = args.blender_child
        blender_child(kind, int(w), int(h), bool(int(cam)))
        return
    if args.blender:
        load0 = os.getloadavg()[0]
        table = part_blender()
        load1 = os.getloadavg()[0]
        write_section(
            "splats-blender",
            f"Shared 2-core machine, other jobs running (1-minute load average {load0:.1f} at the start, {load1:.1f} "
            "at the end); each case in a fresh process (`benchmarks/bench_splats.py --blender`). Goal: ≤ 5 s for the "
            "640×480 splat frame.\n\n" + table,
            "Splats in Blender: a Fig. 3 frame beside the volume clouds",
        )
        return
    load0 = os.getloadavg()[0]
    picture = (None if args.quick
               else Path(__file__).resolve().parent.parent / "docs" / "images" / "splats_reference.png")
    parts = [
        ("Partition of unity (random points, lattice points, cell centres, face and edge midpoints)",
         part_kernels(args.quick)),
        ("Footprints: exact Gauss–Legendre integral, the 64² texture and the renderer's ρ² table against scipy quad",
         part_footprints(args.quick)),
        ("Renderer against the exact ray integral of the kernel-reconstructed medium (Gaussian cloud, extinction 5, "
         "no prefilter)", part_convergence(args.quick)),
        ("A Fig. 3 frame of the demo climate at 12 h (cloud ramp 0.3..0.8), reference renderer, beside the anchors on "
         "the same step", part_frame(args.quick, picture)),
    ]
    load1 = os.getloadavg()[0]
    body = (
        f"Shared 2-core machine, other jobs running (1-minute load average {load0:.1f} at the start, {load1:.1f} at "
        f"the end){'; --quick' if args.quick else ''}.\n\n" + "\n\n".join(f"**{t}**\n\n{b}" for t, b in parts)
    )
    if picture is not None:
        body += f"\n\n![reference splat render](images/{picture.name})"
    if args.quick:
        print(body)
    else:
        write_section("splats", body, "Splats with a flowing wind texture (Fig. 3)")


if __name__ == "__main__":
    main()
