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

DEFAULTS = {
    "source": "demo:small",
    "hours_per_frame": 1.0,
    "exaggeration": None,
    "extinction": 60.0,
    "contrast": 0.8,
    "camera_lon": -30.0,
    "camera_lat": 30.0,
    "camera_distance": 3.6,
    "frames": (1, 1),
    "size": (320, 240),
    "samples": 4,
}


def build(**options):
    """Build the Fig. 3 scene into the current scene; returns a dict of the main objects."""
    import nephele
    from nephele.addon import globe_ops, globe_scene, splat_ops

    o = globe_scene.merge_options(DEFAULTS, options)
    scene = bpy.context.scene
    if not hasattr(bpy.types.Scene, "nephele_splats"):
        nephele.register()
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=False)
    p = scene.nephele_splats
    p.extinction, p.contrast = o["extinction"], o["contrast"]
    assert bpy.ops.nephele.add_wind_splats() == {"FINISHED"}
    splats = bpy.context.view_layer.objects.active
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    scene.cycles.use_denoising = False  # the denoiser smears the streaks
    splat_ops.render_settings(scene)
    return {"globe": globe, "splats": splats, "camera": camera, **sky}


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--extinction", type=float, default=DEFAULTS["extinction"])
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, frames=args.frames, size=args.size, samples=args.samples, extinction=args.extinction)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
