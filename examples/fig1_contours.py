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

import argparse
import sys
from pathlib import Path

import bpy

DEFAULTS = {
    "source": "demo",
    "level": 0.15,
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.grid.DEFAULT_EXAGGERATION
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
    from nephele.addon import contour_ops, data_ops, frame, globe_ops
    from nephele.core.grid import DEFAULT_EXAGGERATION

    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise TypeError(f"unknown options {sorted(unknown)}; known: {sorted(DEFAULTS)}")
    o = dict(DEFAULTS, **options)
    scene = bpy.context.scene
    exaggeration = DEFAULT_EXAGGERATION if o["exaggeration"] is None else float(o["exaggeration"])
    data_ops.set_settings(scene, source=o["source"], hours_per_frame=o["hours_per_frame"],
                          frame_start=int(o["frames"][0]), exaggeration=exaggeration, radius=1.0)
    scene.frame_start, scene.frame_end = int(o["frames"][0]), int(o["frames"][1])
    scene.frame_current = scene.frame_start

    globe = globe_ops.add_globe(scene=scene)
    haze = {True: "volume", False: "none"}.get(o["haze"], o["haze"])
    sky = globe_ops.add_sky_and_haze(scene, haze=haze != "none", haze_mode=haze if haze != "none" else "volume",
                                     sun_direction=(0.55, -0.75, 0.35), sun_strength=4.5)
    clouds = contour_ops.add_contour("cloud", o["level"], scene=scene, color_var="altitude",
                                     method=o["method"], name="Clouds 15%")
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])

    render = scene.render
    render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(o["samples"])
    scene.cycles.use_denoising = True
    render.resolution_x, render.resolution_y = (int(v) for v in o["size"])
    render.resolution_percentage = 100
    render.image_settings.file_format = "PNG"
    render.film_transparent = False
    frame.install()
    return {"globe": globe, "clouds": clouds, "camera": camera, **sky}


def _parse_frames(text):
    a, _, b = text.partition("-")
    return int(a), int(b or a)


def _parse_size(text):
    w, _, h = text.lower().partition("x")
    return int(w), int(h)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="render the frames into this directory (frame_####.png)")
    ap.add_argument("--save", help="save the scene to this .blend")
    ap.add_argument("--frames", type=_parse_frames, default=DEFAULTS["frames"], help="A-B (default 1-24)")
    ap.add_argument("--size", type=_parse_size, default=DEFAULTS["size"], help="WxH (default 640x480)")
    ap.add_argument("--samples", type=int, default=DEFAULTS["samples"])
    ap.add_argument("--source", default=DEFAULTS["source"], help='"demo", "demo:small", a .nc or a .ctl')
    ap.add_argument("--level", type=float, default=DEFAULTS["level"])
    ap.add_argument("--hours-per-frame", type=float, default=DEFAULTS["hours_per_frame"])
    ap.add_argument("--haze", choices=("volume", "shell", "none"), default=DEFAULTS["haze"],
                    help="blue haze: a volume (default; ~3x render time), a closed-form shell (cheap) or none")
    args = ap.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(source=args.source, level=args.level, frames=args.frames, size=args.size, samples=args.samples,
          hours_per_frame=args.hours_per_frame, haze=args.haze)
    scene = bpy.context.scene
    if args.save:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        for f in range(args.frames[0], args.frames[1] + 1):
            scene.frame_set(f)
            scene.render.filepath = str((out / f"frame_{f:04d}.png").resolve())
            bpy.ops.render.render(write_still=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
