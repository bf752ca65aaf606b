"""Fig. 1 of Max & Crawfis: contour surfaces of 15% cloudiness over the globe.

``build()`` makes the scene in the current Blender scene: the embedded demo
climate, the relief globe, the cloudiness contour (coloured by altitude) that
follows the frame through model time, sky, sun and blue haze, and a camera.

    .venv/bin/python examples/fig1_contours.py --out out/fig1 --frames 1-1 --size 640x480 --samples 32
    .venv/bin/python examples/fig1_contours.py --save out/fig1.blend

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 1
   ("Contour surfaces of 15% cloudiness").
"""

import sys

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG1_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 1 scene into the current scene (:func:`nephele.addon.presets.fig1`); returns a dict of
    the main objects."""
    return presets.fig1(bpy.context.scene, **options)


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--level", type=float, default=DEFAULTS["level"])
    ap.add_argument("--hours-per-frame", type=float, default=DEFAULTS["hours_per_frame"])
    ap.add_argument("--haze", choices=("volume", "shell", "none"), default=DEFAULTS["haze"],
                    help="blue haze: a volume (default; ~3x render time), a closed-form shell (cheap) or none")
    args = ap.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, level=args.level, frames=args.frames, size=args.size, samples=args.samples,
          hours_per_frame=args.hours_per_frame, haze=args.haze, annotations=args.annotations)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
