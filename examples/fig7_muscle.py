"""Fig. 7: muscle cross-bridges in motion, a still and an Omnimax stereo sequence.

``build()`` adds the muscle film (:mod:`nephele.addon.muscle_ops`: the
periodic 3-thick/6-thin unit cell, 270 myosin heads through the cross-bridge
cycle by Brownian dynamics, blobby molecules) and either a perspective camera
inside the lattice or, with ``dome="omnimax"``, the dome rig of
:mod:`nephele.addon.dome_ops` in the lattice, its front along the fibre.
``main()`` renders a still (Cycles CPU, tiny by default).

    .venv/bin/python examples/fig7_muscle.py --out out/fig7                 # tiny still, perspective
    .venv/bin/python examples/fig7_muscle.py --out out/fig7 --dome --stereo # Omnimax, both eyes
    .venv/bin/python examples/fig7_muscle.py --out out/fig7 --full --dome   # 2048x1500 Omnimax, one eye

A film through the farm (``nephele muscle`` wraps this)::

    nephele render examples/fig7_muscle.py --frames 1-24 --out out/fig7_film --set dome=omnimax --set stereo=true

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 7.
"""

import argparse
import sys
from pathlib import Path

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG7_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 7 scene in a fresh empty file (:func:`nephele.addon.presets.fig7`);
    returns ``{"film": obj, "camera": camera or rig}``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return presets.fig7(bpy.context.scene, **options)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/fig7", help="output folder")
    ap.add_argument("--frame", type=int, default=1, help="scene frame to render (default 1)")
    ap.add_argument("--dome", action="store_true", help="Omnimax dome frame instead of a perspective view")
    ap.add_argument("--stereo", action="store_true", help="both eyes (with --dome)")
    ap.add_argument("--full", action="store_true", help="2048x1500, 0.5 nm grid, 32 samples")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--film-frames", type=int, default=DEFAULTS["film_frames"], help="simulated film length")
    args = ap.parse_args(argv)
    opts = {"seed": args.seed, "film_frames": max(args.film_frames, args.frame)}
    if args.dome:
        opts.update(dome="omnimax", stereo=args.stereo, size=(256, 188))
    if args.full:
        opts.update(size=(2048, 1500) if args.dome else (1600, 1200), spacing=0.5, samples=32)
    build(**opts)
    scene = bpy.context.scene
    scene.frame_set(args.frame)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / (f"fig7_omnimax_{args.frame:04d}.png" if args.dome else f"fig7_{args.frame:04d}.png")
    if args.dome:
        from nephele.addon import dome_ops

        paths = dome_ops.render_dome_frame(path, scene=scene)
    else:
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        paths = [path]
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else None))
