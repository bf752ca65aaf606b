"""Fig. 3 of Max & Crawfis: clouds and wind velocity as texture splats.

``build()`` makes the scene in the current Blender scene: the demo climate,
the relief globe, one view-facing splat per cloudy sample (opacity from the
cloud transfer function, colour by altitude) whose streak texture flows
along the wind from frame to frame, and a camera looking at it.

    .venv/bin/python examples/fig3_splats.py --out out/fig3 --frames 1-4 --size 320x240 --samples 4

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3
   ("Clouds and wind velocity by hardware texture mapping").
.. [2] R. Crawfis and N. Max, "Texture splats for 3D scalar and vector field
   visualization", Proc. Visualization '93.
"""

import sys

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG3_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 3 scene into the current scene (:func:`nephele.addon.presets.fig3`); returns a dict of
    the main objects."""
    import nephele

    if not hasattr(bpy.types.Scene, "nephele_splats"):
        nephele.register()
    return presets.fig3(bpy.context.scene, **options)


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--extinction", type=float, default=DEFAULTS["extinction"])
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, frames=args.frames, size=args.size, samples=args.samples, extinction=args.extinction,
          annotations=args.annotations)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
