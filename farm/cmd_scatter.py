"""``nephele scatter --out DIR``: the Fig. 6 cloud's multiple-scattering solve, then views.

Builds the droplet density (Perlin noise on three ellipsoids), runs the binned
shooting solve once (96 bins, ``6 n^2`` with ``--bins-per-face n``; ``DIR/solution.npz``:
the total and received flux per bin, no pickle) and renders ``--views`` cameras
looping around the cloud, each as ``DIR/view_0001.png`` (tone-mapped, one exposure for all views) and
``DIR/view_0001.npy`` (radiance).  ``--vdb`` also writes
``DIR/scatter_0001.vdb`` … with ``density`` and ``emission`` toward each view's
camera, a volume sequence Blender renders as an emission-absorption medium.
``--sky-map IMAGE`` lights the cloud with a sky from every direction: an
equirectangular image (an HDRI, a rendered Blender world) binned into the solve's
directions.

``--evolve drift`` makes the cloud change during the film: its noise drifts through the
ellipsoids (``--drift`` box units over the film), and ``--evolve climate`` cuts the cloud from
the demo climate's hourly cloud field (the 10 days spread over the views); each view is then its
own frame, solved warm-started from the frame before (``DIR/solution_0001.npz`` ...), its VDB
(``--vdb``) with that frame's density: a sequence Blender and ``nephele render`` play as any
volume sequence.
"""

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from ..core.errors import UsageError
from ..core.parse import parse_size

HELP = "solve multiple scattering in a cloud (Fig. 6) and render orbit views (PNG, radiance, optional VDB)"


def add_arguments(p):
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--grid", default="24x24x18", metavar="NXxNYxNZ", help="voxels (default 24x24x18, the paper's)")
    p.add_argument("--box", default="1,1,0.75", metavar="LX,LY,LZ", help="box size (default 1,1,0.75)")
    p.add_argument("--extinction", type=float, default=40.0, help="extinction at density 1 (default 40)")
    p.add_argument("--albedo", type=float, default=0.99, help="single-scattering albedo (default 0.99)")
    p.add_argument("--g", type=float, default=0.8, help="Henyey-Greenstein asymmetry (default 0.8)")
    p.add_argument("--noise", type=float, default=0.7, help="noise amplitude (default 0.7)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--sun-elevation", type=float, default=38.0, help="degrees (default 38)")
    p.add_argument("--sun-azimuth", type=float, default=-30.0, help="degrees from +x toward +y (default -30)")
    p.add_argument("--irradiance", type=float, default=1.0, help="sun irradiance (default 1)")
    p.add_argument("--sky", type=float, default=0.0, help="sky radiance from above (default 0)")
    p.add_argument("--sky-map", metavar="IMAGE",
                   help="a sky from every direction instead: an equirectangular image of radiance (EXR, HDR, ...) "
                        "in Blender's environment layout (+x at the centre, +z up), its luminance binned into the "
                        "solve's direction bins")
    p.add_argument("--sky-strength", type=float, default=1.0, help="scale of --sky-map (default 1)")
    p.add_argument("--tol", type=float, default=1e-3, help="stop when unshot < tol x entered power (default 1e-3)")
    p.add_argument("--max-passes", type=int, default=100, help="pass limit (default 100)")
    p.add_argument("--bins-per-face", type=int, default=4, metavar="N",
                   help="direction bins per cube-face side, even, 2 to 8: 6 N^2 bins (default 4: the paper's 96; "
                        "6: 216, closer to exact for the sharp forward peak, 2.7x the solve time, 2.2x the memory)")
    p.add_argument("--total", action="store_true",
                   help="also sum the paper's total flux (power through each voxel per bin) into the saved solutions "
                        "(the views read the received flux; the total costs time and an array like it)")
    p.add_argument("--views", type=int, default=8, help="orbit views (default 8)")
    p.add_argument("--size", default="300x255", metavar="WxH", help="image size (default 300x255, the paper's)")
    p.add_argument("--distance", type=float, default=1.7, help="camera distance from the box centre (default 1.7)")
    p.add_argument("--elevation", type=float, default=15.0, help="camera elevation, degrees (default 15)")
    p.add_argument("--vdb", action="store_true", help="also write per-view VDB grids for Blender")
    p.add_argument("--evolve", choices=("still", "drift", "climate"), default="still",
                   help="a cloud that changes from view to view: its noise drifting, or cut from the demo "
                        "climate's cloud field; one solve a view, each from the one before (default still)")
    p.add_argument("--drift", default="0.25,0.1,0.02", metavar="DX,DY,DZ",
                   help="--evolve drift: how far the noise moves over the film, box units (default 0.25,0.1,0.02)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _ints(text, n, name, sep="x"):
    try:
        v = [int(t) for t in text.lower().split(sep)]
    except ValueError:
        v = []
    if len(v) != n or min(v) < 1:
        raise UsageError(f"{name} must be {n} positive integers separated by '{sep}', got {text!r}")
    return v


def _floats(text, n, name, positive=True):
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) != n or (positive and min(v) <= 0) or not all(map(math.isfinite, v)):
        kind = "positive numbers" if positive else "numbers"
        raise UsageError(f"{name} must be {n} {kind} separated by ',', got {text!r}")
    return v


def sky_from_map(path, strength=1.0, bins_per_face=4):
    """The ``6 n^2`` per-bin radiances (``n = bins_per_face``) of an equirectangular sky image
    times ``strength``."""
    from ..core.errors import DataError
    from ..core.light.sky import luminance, panorama_radiance
    from ..fileio import read_image

    if not Path(path).is_file():
        raise DataError("no such file", path=path, field="--sky-map")
    px = read_image(path)
    if px.shape[2] < 3:
        px = np.repeat(px[..., :1], 3, axis=2)  # a grey image
    h, w = px.shape[:2]
    if w != 2 * h:
        raise DataError(f"an equirectangular sky is twice as wide as high, got {w}x{h}", path=path, field="--sky-map")
    lum = luminance(px)
    if not np.all(np.isfinite(lum)) or lum.min() < 0:
        raise DataError("the sky's radiance must be finite and >= 0", path=path, field="--sky-map")
    return strength * panorama_radiance(lum, bins_per_face=bins_per_face)


def tone_map(img, white):
    """Linear radiance to 8-bit sRGB-ish grey (gamma 2.2), ``white`` maps to 255."""
    return (np.clip(img / white, 0.0, 1.0) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)


def run(args):
    from ..core.errors import DataError
    from ..core.light import scatter
    from ..core.light.phase import check_per_face
    from ..core.volume import cloud_density as cd

    nx, ny, nz = _ints(args.grid, 3, "--grid")
    box = _floats(args.box, 3, "--box")
    w, h = parse_size(args.size, lo=1)
    if args.views < 1:
        raise UsageError("--views must be >= 1")
    if not 0 <= args.albedo <= 1 or not -1 < args.g < 1:
        raise UsageError("--albedo must be in [0, 1] and --g in (-1, 1)")
    if args.sky_map and args.sky:
        raise UsageError("give --sky (uniform) or --sky-map, not both")
    if args.sky_strength < 0:
        raise UsageError("--sky-strength must be >= 0")
    try:
        check_per_face(args.bins_per_face)
    except DataError as exc:
        raise UsageError(f"--bins-per-face: {exc.problem}") from None
    sky = sky_from_map(args.sky_map, args.sky_strength, args.bins_per_face) if args.sky_map else args.sky
    out = Path(args.out)
    from ..core.light.scatter_task import check_solve_memory

    check_solve_memory((nz, ny, nx), args.bins_per_face)  # before anything is allocated or written
    out.mkdir(parents=True, exist_ok=True)
    params = cd.CloudParams(shape=(nz, ny, nx), size=tuple(box), noise_amplitude=args.noise, seed=args.seed)
    drift = _floats(args.drift, 3, "--drift", positive=False)
    density = _densities(args, params, drift)
    e, a = math.radians(args.sun_elevation), math.radians(args.sun_azimuth)
    sun = (math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e))
    say = (lambda *m: None) if args.quiet else (lambda *m: print(*m, file=sys.stderr, flush=True))
    kw = dict(albedo=args.albedo, g=args.g, sun_dir=sun, sun_irradiance=args.irradiance, sky_radiance=sky,
              tol=args.tol, max_passes=args.max_passes, bins_per_face=args.bins_per_face, total=args.total)

    def progress(p):
        if p.group == p.groups:
            say(f"pass {p.pass_index}: residual {p.residual:.3e}")

    t0 = time.perf_counter()
    sigma = density(0)
    sol = scatter.solve(sigma, box, progress=progress, **kw)
    t_solve = time.perf_counter() - t0
    scatter.save_solution(sol, out / "solution.npz")
    say(f"solve {nx}x{ny}x{nz}: {t_solve:.1f} s, {sol.report}")
    solves = [(t_solve, sol.report)]
    if args.vdb:
        from ..fileio import dense_grids, write_vdb  # needs bpy's bundled openvdb
    import imageio.v3 as iio

    from ..core.files import atomic_write

    white = None
    times = []
    for i in range(args.views):
        if i and args.evolve != "still":  # this view's own frame, from the frame before
            t = time.perf_counter()
            sigma = density(i)
            sol = scatter.solve(sigma, box, warm=sol, **kw)
            solves.append((time.perf_counter() - t, sol.report))
            scatter.save_solution(sol, out / f"solution_{i + 1:04d}.npz")
            say(f"frame {i + 1}: solve {solves[-1][0]:.1f} s, {sol.report}")
        t = time.perf_counter()
        cam = scatter.orbit_camera(2 * math.pi * i / args.views, box, distance=args.distance,
                                   elevation=math.radians(args.elevation), width=w, height=h)
        src = scatter.view_source(sol, cam.position)
        # the grid's planes, 2 samples per voxel: the ray march `render` at 1/10 of its cost (README, Fig. 6)
        img = scatter.march_planes(sigma, src, box, cam, samples=2)
        times.append(time.perf_counter() - t)
        if white is None:
            white = float(np.percentile(img, 99.7)) or 1.0
        with atomic_write(out / f"view_{i + 1:04d}.npy") as tmp:
            np.save(tmp, img)
        with atomic_write(out / f"view_{i + 1:04d}.png") as tmp:
            iio.imwrite(tmp, tone_map(img, white))
        if args.vdb:
            write_vdb(out / f"scatter_{i + 1:04d}.vdb", dense_grids({"density": sigma, "emission": src}, box))
        say(f"view {i + 1}/{args.views}: {times[-1]:.2f} s")
    with atomic_write(out / "scatter.json") as tmp:
        tmp.write_text(json.dumps({
            "grid": [nx, ny, nz], "box": box, "extinction": args.extinction, "albedo": args.albedo, "g": args.g,
            "sun_dir": sun, "irradiance": args.irradiance, "sky": args.sky,
            "sky_map": str(Path(args.sky_map).resolve()) if args.sky_map else None,
            "sky_strength": args.sky_strength, "bins_per_face": args.bins_per_face, "report": sol.report,
            "passes": sol.passes, "residual": sol.residual, "converged": sol.converged,
            "solve_seconds": t_solve, "view_seconds": times, "views": args.views, "size": [w, h],
            "evolve": args.evolve, "drift": drift if args.evolve == "drift" else None,
            "frame_solves": [{"seconds": s, "report": r} for s, r in solves]}, indent=1))
    if args.evolve != "still" and len(solves) > 1:
        warm = np.mean([s for s, _ in solves[1:]])
        print(f"{args.views} frames: first solve {t_solve:.1f} s (cold), then {warm:.1f} s a frame (warm-started), "
              f"views median {np.median(times):.2f} s -> {out}")
        return 0
    print(f"{sol.report}; solve {t_solve:.1f} s, {args.views} views, median {np.median(times):.2f} s each -> {out}")
    return 0


def _densities(args, params, drift):
    """``frame -> extinction`` of the cloud (the same every frame when still)."""
    from ..core.light import evolving
    from ..core.volume import cloud_density as cd

    if args.evolve == "drift":
        return lambda i: evolving.drifting_cloud(params, i, args.views, drift, args.extinction)
    if args.evolve == "climate":
        from ..core.climate.synthetic import demo_dataset

        data = demo_dataset()
        steps = len(data.times)
        return lambda i: evolving.climate_cloud(data, i * steps // args.views, shape=params.shape,
                                                extinction=args.extinction)
    sigma = args.extinction * cd.cloud_density(params)
    return lambda i: sigma
