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

DEFAULTS = {
    "source": "demo",
    "level": 0.15,
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.climate.grid.DEFAULT_EXAGGERATION
    "method": "cubes",
    "haze": "volume",  # "volume", "shell" (cheap, closed form) or "none"
    "camera_lon": -40.0,
    "camera_lat": 22.0,
    "camera_distance": 4.5,
    "frames": (1, 24),
    "size": (640, 480),
    "samples": 32,
}


def build(**options):
    """Build the Fig. 1 scene into the current scene; returns a dict of the main objects.

    Options (see :data:`DEFAULTS`): ``source``, ``level``, ``hours_per_frame``,
    ``exaggeration``, ``method``, ``haze``, ``camera_lon``, ``camera_lat``,
    ``camera_distance``, ``frames`` (first, last), ``size`` (w, h), ``samples``.
    """
    from nephele.addon import contour_ops, frame, globe_ops, globe_scene

    o = globe_scene.merge_options(DEFAULTS, options)
    scene = bpy.context.scene
    haze = {True: "volume", False: "none"}.get(o["haze"], o["haze"])
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(0.55, -0.75, 0.35), haze=haze != "none",
                                         haze_mode=haze if haze != "none" else "volume")
    clouds = contour_ops.add_contour("cloud", o["level"], scene=scene, color_var="altitude",
                                     method=o["method"], name="Clouds 15%")
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])
    globe_scene.render_settings(scene, o["size"], o["samples"])
    frame.install()
    return {"globe": globe, "clouds": clouds, "camera": camera, **sky}


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
          hours_per_frame=args.hours_per_frame, haze=args.haze)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
