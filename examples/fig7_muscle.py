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
    .venv/bin/python examples/fig7_muscle.py --out out/fig7 --dome --stereo --anaglyph half  # + red-cyan

The README pictures (frame 40; Cycles on 2 CPU cores, minutes, see ``--help``)::

    .venv/bin/python examples/fig7_muscle.py --out out/fig7 --frame 40 --full --dome
    .venv/bin/python examples/fig7_muscle.py --out out/fig7 --frame 40 --full --dome --stereo --size 1024 750 \\
        --anaglyph half

Few samples are affordable because ``--denoise`` runs Blender's
OpenImageDenoise on the beauty pass with its albedo and normal passes;
``--bounces`` caps the light paths below Cycles' 12 (the lattice is lit by a
headlight beside the eye, so the picture is mostly direct light).

A film through the farm (``nephele muscle`` wraps this)::

    nephele render examples/fig7_muscle.py --frames 1-24 --out out/fig7_film --set dome=omnimax --set stereo=true

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 7.
"""

import argparse
import sys
import time
from pathlib import Path

import bpy

from nephele.addon import presets
from nephele.core.camera.anaglyph import MODES as ANAGLYPH_MODES
from nephele.core.camera.anaglyph import red_cyan

DEFAULTS = presets.FIG7_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 7 scene in a fresh empty file (:func:`nephele.addon.presets.fig7`);
    returns ``{"film": obj, "camera": camera or rig}``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return presets.fig7(bpy.context.scene, **options)


def render_settings(scene, *, samples=None, denoise=False, bounces=None):
    """Cycles settings for an affordable CPU render: ``samples`` per pixel, OpenImageDenoise
    (with albedo and normal passes) when ``denoise``, and at most ``bounces`` bounces per path."""
    c = scene.cycles
    if samples is not None:
        c.samples = int(samples)
    c.use_denoising = bool(denoise)
    if denoise:
        c.denoiser = "OPENIMAGEDENOISE"
        c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        c.denoising_prefilter = "ACCURATE"
    if bounces is not None:
        presets.cap_bounces(scene, bounces)


def write_anaglyph(left, right, out, mode="half"):
    """Red-cyan anaglyph (:func:`nephele.core.camera.anaglyph.red_cyan`) of two rendered eyes, written to ``out``."""
    from nephele.fileio import read_image, write_image

    return write_image(out, red_cyan(read_image(left), read_image(right), mode))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/fig7", help="output folder")
    ap.add_argument("--frame", type=int, default=1, help="scene frame to render (default 1)")
    ap.add_argument("--dome", action="store_true", help="Omnimax dome frame instead of a perspective view")
    ap.add_argument("--stereo", action="store_true", help="both eyes (with --dome)")
    ap.add_argument("--full", action="store_true",
                    help="2048x1500 (1600x1200 perspective), 0.5 nm grid, 16 samples, denoised, 3 bounces")
    ap.add_argument("--size", type=int, nargs=2, metavar=("W", "H"), help="image size (overrides --full's)")
    ap.add_argument("--spacing", type=float, help="blobby grid spacing in nm (0.8 default, 0.5 with --full)")
    ap.add_argument("--samples", type=int, help="Cycles samples per pixel (8 default, 16 with --full)")
    ap.add_argument("--denoise", action=argparse.BooleanOptionalAction,
                    help="OpenImageDenoise with albedo and normal passes (default: with --full only)")
    ap.add_argument("--bounces", type=int, help="at most this many bounces per light path (Cycles' 12; 3 with --full)")
    ap.add_argument("--anaglyph", choices=ANAGLYPH_MODES,
                    help="with --dome --stereo: also write a red-cyan anaglyph of the two eyes in this mode")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--annotations", action="store_true",
                    help="lay the caption and the molecules' colours over the render")
    ap.add_argument("--film-frames", type=int, default=DEFAULTS["film_frames"], help="simulated film length")
    args = ap.parse_args(argv)
    if args.anaglyph and not (args.dome and args.stereo):
        ap.error("--anaglyph needs --dome --stereo")
    if args.samples is not None and args.samples < 1:
        ap.error("--samples must be >= 1")
    if args.bounces is not None and args.bounces < 0:
        ap.error("--bounces must be >= 0")
    if args.size is not None and min(args.size) < 8:
        ap.error("--size must be at least 8 8")
    if args.spacing is not None and not args.spacing > 0:
        ap.error("--spacing must be > 0")
    opts = {"seed": args.seed, "film_frames": max(args.film_frames, args.frame), "annotations": args.annotations}
    if args.dome:
        opts.update(dome="omnimax", stereo=args.stereo, size=(256, 188))
    if args.full:
        opts.update(size=(2048, 1500) if args.dome else (1600, 1200), spacing=0.5, samples=16)
    if args.size is not None:
        opts["size"] = tuple(args.size)
    if args.spacing is not None:
        opts["spacing"] = args.spacing
    t0 = time.perf_counter()
    build(**opts)
    scene = bpy.context.scene
    render_settings(scene, samples=args.samples, denoise=args.full if args.denoise is None else args.denoise,
                    bounces=3 if args.full and args.bounces is None else args.bounces)
    scene.frame_set(args.frame)
    t1 = time.perf_counter()
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
    t2 = time.perf_counter()
    if args.anaglyph:
        paths.append(write_anaglyph(paths[0], paths[1], path.with_name(f"{path.stem}_anaglyph{path.suffix}"),
                                    args.anaglyph))
    r = scene.render
    print(f"{r.resolution_x}x{r.resolution_y}, {scene.cycles.samples} samples, denoise {scene.cycles.use_denoising}, "
          f"max bounces {scene.cycles.max_bounces}: scene and frame {t1 - t0:.1f} s, render {t2 - t1:.1f} s")
    for p in paths:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else None))
