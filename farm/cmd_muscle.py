"""``nephele muscle --frames 1-24 --out DIR``: the muscle cross-bridge film (Fig. 7), rendered or exported.

Rendering goes through :func:`nephele.farm.render.render_sequence` with the
scene of ``examples/fig7_muscle.py`` (``build(**options)``), so frames are
resumable, checked and spread over Dask workers like any ``nephele render``;
``--dome omnimax --stereo`` gives the paper's Omnimax stereo film
(``frame_NNNN_L.png`` / ``_R.png``).  ``--export ply`` writes each frame's
molecule mesh (nm, attribute ``molecule``) without Blender.  ``--info``
prints the simulation's state counts per frame.
"""

import sys
from pathlib import Path

from ..core.errors import UsageError
from ..core.parse import parse_size
from .cmd_render import add_cluster_arguments, cluster_kwargs

HELP = "the muscle cross-bridge film (Fig. 7): render frames (Omnimax stereo with --dome) or export meshes"

SCENE = Path(__file__).resolve().parent.parent / "examples" / "fig7_muscle.py"


def add_arguments(p):
    p.add_argument("--frames", required=True, help="scene frames: 1-240, 1-240x2 or 1,5,9-12 (frame 1 = film start)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulation (default 0)")
    p.add_argument("--film-frames", type=int, default=240, help="simulated film length in frames (default 240)")
    p.add_argument("--spacing", type=float, default=0.8, help="blobby grid spacing in nm (default 0.8; 0.5 fine)")
    p.add_argument("--size", metavar="WxH", default="320x240", help="frame size (default 320x240)")
    p.add_argument("--samples", type=int, default=8, help="Cycles samples (default 8)")
    p.add_argument(
        "--dome", choices=("none", "omnimax", "domemaster"), default="none", help="dome frame (default none)"
    )
    p.add_argument("--stereo", action="store_true", help="left and right eyes (with --dome)")
    p.add_argument("--separation", type=float, default=0.006,
                   help="eye separation in scene units (1 = 100 nm; default 0.006)")
    p.add_argument("--export", choices=("ply", "glb", "obj"), help="write meshes (nm) instead of rendering")
    p.add_argument("--info", action="store_true", help="print the cross-bridge states per frame; render nothing")
    add_cluster_arguments(p)


def _check(args):
    from .frames import parse_frames

    try:
        frames = parse_frames(args.frames)
    except ValueError as exc:
        raise UsageError(f"--frames: {exc}") from None
    if not args.film_frames >= 1:
        raise UsageError(f"--film-frames must be >= 1, got {args.film_frames}")
    if not args.spacing > 0:
        raise UsageError(f"--spacing must be a positive number of nm, got {args.spacing}")
    if not args.samples >= 1:
        raise UsageError(f"--samples must be >= 1, got {args.samples}")
    w, h = parse_size(args.size, lo=1)
    if args.stereo and args.dome == "none":
        raise UsageError("--stereo needs --dome omnimax or domemaster")
    bad = [f for f in frames if not 1 <= f <= args.film_frames]
    if bad:
        raise UsageError(f"--frames {bad[0]} outside the film's 1-{args.film_frames} (see --film-frames)")
    return frames, (w, h)


def run(args):
    frames, size = _check(args)
    film = {"seed": args.seed, "frames": args.film_frames, "spacing": args.spacing}
    if args.info or args.export:
        return _core_only(args, frames, film)
    if not SCENE.is_file():
        raise UsageError(f"the film's scene script is missing: {SCENE}")
    from .render import render_sequence

    options = {"seed": args.seed, "film_frames": args.film_frames, "spacing": args.spacing, "size": list(size),
               "samples": args.samples, "dome": None if args.dome == "none" else args.dome, "stereo": args.stereo,
               "separation": args.separation}
    kwargs = cluster_kwargs(args)
    if args.dry_run:
        print(f"scene: {SCENE} (example)\nframes: {args.frames}\noptions: {options}")
        return 0
    result = render_sequence(SCENE, frames, args.out, scene_options=options, samples=args.samples,
                             resolution=size, **kwargs)
    print(f"nephele muscle: {len(result.frames) - len(result.failed)}/{len(result.frames)} frames valid in "
          f"{result.out_dir} in {result.seconds:.1f} s", file=sys.stderr)
    return 1 if result.failed else 0


def _core_only(args, frames, film):
    import numpy as np

    from ..core.muscle import brownian as br
    from ..core.muscle import film as core_film
    from ..core.surface.mesh import Mesh

    p = core_film.film_params(**film)
    cell, sim = core_film.simulate(p, upto=max(frames))
    if args.info:
        print("frame  " + "  ".join(f"{n:>10}" for n in br.STATE_NAMES) + "  slide_nm")
        for f in frames:
            fr = sim[f - 1]
            counts = np.bincount(fr.states, minlength=5)
            print(f"{f:5d}  " + "  ".join(f"{c:10d}" for c in counts) + f"  {fr.slide.mean():8.2f}")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for f in frames:
        a = core_film.frame_meshes(p, f - 1)
        nv = len(a["vertices"])
        mesh = Mesh(
            np.concatenate([a["vertices"], a["cyl_vertices"]]),
            np.concatenate([a["faces"], a["cyl_faces"] + nv]),
            np.concatenate([a["normals"], a["cyl_normals"]]),
            {"molecule": np.concatenate([a["molecule"], a["cyl_molecule"]]).astype(np.float32)},
        )
        path = mesh.save(out / f"frame_{f:04d}.{args.export}")
        print(path)
    return 0
