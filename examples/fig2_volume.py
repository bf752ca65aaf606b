"""Fig. 2 of Max & Crawfis: volume-rendered clouds over the terrain.

``build()`` makes the scene in the current Blender scene: the embedded demo
climate's cloudiness resampled into a sparse VDB sequence (opacity from a
piecewise-linear transfer function that is zero below a threshold, colour
from altitude), the relief globe coloured land/sea, sky, sun and the blue
haze thinning exponentially with altitude, and a camera looking down on the
clouds at an angle.

    .venv/bin/python examples/fig2_volume.py --out out/fig2 --frames 1-1 --size 640x480 --samples 32
    .venv/bin/python examples/fig2_volume.py --save out/fig2.blend --frames 1-24

The ``.vdb`` files go beside the saved .blend (or into ``--vdb-dir``, default
``out/fig2_volume_vdb``); Blender reads them natively, so a farm render
of the saved .blend needs no add-on.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2
   ("Volume rendered clouds").
"""

import sys
from pathlib import Path

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG2_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 2 scene into the current scene (:func:`nephele.addon.presets.fig2`); returns a dict of the
    main objects.  ``vdb_dir`` None in an unsaved file: ``out/fig2_volume_vdb``."""
    if options.get("vdb_dir") is None and not bpy.data.filepath:
        options["vdb_dir"] = str(Path(__file__).resolve().parent.parent / "out" / "fig2_volume_vdb")
    return presets.fig2(bpy.context.scene, **options)


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--threshold", type=float, default=DEFAULTS["threshold"], help="opacity is zero below it")
    ap.add_argument("--mode", choices=("exact", "voxels"),
                    help="exact: the shader evaluates the curvilinear field (default with Cycles); voxels: a VDB")
    ap.add_argument("--voxel-size", type=float, help="voxel mode: scene units between voxels (default 0.0027)")
    ap.add_argument("--engine", choices=("CYCLES", "BLENDER_EEVEE"), default=DEFAULTS["engine"])
    ap.add_argument("--vdb-dir", help="where the .vdb sequence goes")
    ap.add_argument("--no-haze", action="store_true", help="leave out the blue haze")
    args = ap.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    vdb_dir = args.vdb_dir
    if args.save:
        # Save first, so the sequence lands beside the .blend and is linked relatively.
        globe_scene.save(args.save)
    build(source=args.source, threshold=args.threshold, mode=args.mode, voxel_size=args.voxel_size, frames=args.frames,
          size=args.size, samples=args.samples, haze=not args.no_haze, engine=args.engine, vdb_dir=vdb_dir,
          annotations=args.annotations)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
