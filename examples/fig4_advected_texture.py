"""Fig. 4 of Max & Crawfis: the clouds of Fig. 1 with a transparency texture carried by the wind.

``build()`` makes the scene in the current Blender scene: the embedded demo
climate, the relief globe, the 15% cloudiness contour whose front faces carry
the poor-man's fractal evaluated at each vertex's start coordinates (traced
backwards through the hourly winds, two copies restarted every 24 frames and
cross-faded), sky, sun, the blue haze thinning exponentially with altitude,
and a camera.  Every frame remakes the contour and its start coordinates, so
cloud shapes and texture move together in the wind.

    .venv/bin/python examples/fig4_advected_texture.py --out out/fig4 --frames 1-13 --size 480x360 --samples 16
    .venv/bin/python examples/fig4_advected_texture.py --save out/fig4.blend --frames 1-240

``--out`` also writes ``side_by_side.png``: the first, middle and last frames.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 4
   ("Clouds of fig. 1 with transparency texture").
.. [2] N. Max and R. Crawfis, "Visualizing wind velocities by advecting cloud
   textures", Proc. Visualization '92.
"""

import sys
from pathlib import Path

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG4_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 4 scene into the current scene (:func:`nephele.addon.presets.fig4`); returns a dict of
    the main objects."""
    return presets.fig4(bpy.context.scene, **options)


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--level", type=float, default=DEFAULTS["level"])
    ap.add_argument("--strategy", choices=("restart", "compose", "full"), default=DEFAULTS["strategy"])
    ap.add_argument("--period", type=int, default=DEFAULTS["period"], help="restart period in frames (even)")
    ap.add_argument("--vertical", choices=("auto", "w", "levels"), default=DEFAULTS["vertical"],
                    help="vertical motion from w, or keep levels (exact for the demo); default auto: "
                         "levels where the dataset's levels follow the air")
    ap.add_argument("--hours-per-frame", type=float, default=DEFAULTS["hours_per_frame"], help="model hours per frame")
    ap.add_argument("--camera", type=float, nargs=3, metavar=("LON", "LAT", "DIST"),
                    default=(DEFAULTS["camera_lon"], DEFAULTS["camera_lat"], DEFAULTS["camera_distance"]))
    ap.add_argument("--no-haze", action="store_true", help="leave out the blue haze (renders ~3x faster)")
    args = ap.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, level=args.level, frames=args.frames, size=args.size, samples=args.samples,
          haze=not args.no_haze, strategy=args.strategy, period=args.period, hours_per_frame=args.hours_per_frame,
          vertical=args.vertical,
          camera_lon=args.camera[0], camera_lat=args.camera[1], camera_distance=args.camera[2],
          annotations=args.annotations)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        out = Path(args.out)
        paths = globe_scene.render_frames(bpy.context.scene, args.frames, out)
        if len(paths) > 1:
            from nephele.farm.post import contact_sheet

            picks = sorted({0, len(paths) // 2, len(paths) - 1})
            contact_sheet([paths[i] for i in picks], out / "side_by_side.png", columns=len(picks),
                          thumb_width=args.size[0], labels=[f"frame {args.frames[0] + i}" for i in picks])
    return 0


if __name__ == "__main__":
    sys.exit(main())
