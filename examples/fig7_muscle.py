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
import math
import sys
from pathlib import Path

import bpy
import numpy as np

DEFAULTS = {
    "seed": 0,
    "film_frames": 240,
    "spacing": 0.8,  # nm; 0.5 for the full-quality film
    "tiles": (3, 3, 1),
    "dome": None,  # or "omnimax" / "domemaster"
    "stereo": False,
    "separation": 0.006,  # scene units (1 = 100 nm): a 0.6 nm eye base, about 1/30 of the nearest molecules
    "size": (320, 240),
    "samples": 8,
}


def build(**options):
    """Build the Fig. 7 scene; returns ``{"film": obj, "camera": camera or rig}``."""
    from nephele.addon import dome_ops, frame, muscle_ops

    o = {**DEFAULTS, **options}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(o["samples"])
    scene.cycles.use_denoising = False
    frame.install()
    obj = muscle_ops.add_muscle_film(seed=o["seed"], frames=o["film_frames"], spacing=o["spacing"],
                                     tiles=tuple(o["tiles"]), scene=scene)
    cam = scene.camera
    w, h = (int(v) for v in o["size"])
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    if o["dome"]:
        # The dome's front is +y: turn the lattice so its fibre (local z) runs along +y, keeping it centred.
        rot = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)  # rotation by -90 degrees about x
        obj.rotation_euler = (-math.pi / 2, 0.0, 0.0)
        obj.location = tuple(rot @ np.array(obj.location))
        eye = rot @ np.array(cam.location)
        bpy.data.objects.remove(cam, do_unlink=True)
        cam = dome_ops.add_dome_camera(o["dome"], stereo=bool(o["stereo"]), separation=float(o["separation"]),
                                       location=tuple(eye), width=w, height=h, scene=scene)
        light = bpy.data.objects.get("Muscle light")  # the headlight rides with the audience
        if light is not None:
            light.parent = cam
            light.location = (0.03, 0.03, 0.0)
    return {"film": obj, "camera": cam}


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
