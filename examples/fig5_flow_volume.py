"""Fig. 5 of Max & Crawfis: simulated smoke in the global air circulation (a flow volume).

``build()`` makes the scene in the current Blender scene: the demo climate,
the relief globe, a smoke generator facing the winds and the air that flowed
through it during ``hours`` (constant-colour emission-absorption smoke), and
a camera looking at it.

    .venv/bin/python examples/fig5_flow_volume.py --out out/fig5 --frames 1-1 --size 320x240 --samples 16

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 5
   ("Simulated smoke in global air circulation").
.. [2] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
"""

import sys

import bpy

DEFAULTS = {
    "source": "demo:small",
    "hours_per_frame": 1.0,
    "exaggeration": None,
    "lon": -40.0,
    "lat": 35.0,
    "height": 2000.0,
    "radius": 0.05,
    "hours": 24.0,
    "sides": 32,
    # Optical depth about 1 across the generator's diameter: translucent smoke, as in the paper.
    "density": 10.0,
    "camera_lon": -40.0,
    "camera_lat": 38.0,
    "camera_distance": 2.2,
    "frames": (1, 1),
    "size": (320, 240),
    "samples": 16,
}


def _register():
    import nephele

    if not hasattr(bpy.types.Scene, "nephele_flowvol"):
        nephele.register()


def build(**options):
    """Build the Fig. 5 scene into the current scene; returns a dict of the main objects."""
    from nephele.addon import globe_ops, globe_scene

    o = globe_scene.merge_options(DEFAULTS, options)
    scene = bpy.context.scene
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=False)
    _register()
    p = scene.nephele_flowvol
    p.lon, p.lat, p.height, p.radius, p.hours, p.sides = o["lon"], o["lat"], o["height"], o["radius"], o["hours"], o["sides"]
    p.density = o["density"]
    p.live = False
    if o["exaggeration"] is not None:
        p.exaggeration = o["exaggeration"]
    assert bpy.ops.nephele.add_flow_volume() == {"FINISHED"}, p.status
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    return {"globe": globe, "smoke": bpy.data.objects["Flow volume smoke"], "camera": camera, **sky}


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--hours", type=float, default=DEFAULTS["hours"], help="release window in hours")
    ap.add_argument("--radius", type=float, default=DEFAULTS["radius"], help="generator radius (globe radius 1)")
    ap.add_argument("--density", type=float, default=DEFAULTS["density"], help="smoke density (per globe radius)")
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, frames=args.frames, size=args.size, samples=args.samples, hours=args.hours, radius=args.radius,
          density=args.density)
    print(bpy.context.scene.nephele_flowvol.status)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
