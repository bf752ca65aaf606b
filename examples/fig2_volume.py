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

import argparse
import sys
from pathlib import Path

import bpy

DEFAULTS = {
    "source": "demo",
    "threshold": 0.3,
    "full": 0.7,
    "extinction": None,  # None: nephele.core.volume.DEFAULT_EXTINCTION
    "voxel_size": None,  # None: nephele.core.volume.DEFAULT_VOXEL_SIZE
    "color_var": "altitude",
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.grid.DEFAULT_EXAGGERATION
    "haze": True,
    "camera_lon": -115.0,
    "camera_lat": 28.0,
    "camera_distance": 3.0,
    "engine": "CYCLES",
    "frames": (1, 24),
    "size": (640, 480),
    "samples": 32,
    "vdb_dir": None,  # None: beside the saved .blend, else out/fig2_volume_vdb
    "bake": "all",  # "lazy": each frame's .vdb written when shown (farm: after nephele precompute)
}


def build(**options):
    """Build the Fig. 2 scene into the current scene; returns a dict of the main objects.

    Options (see :data:`DEFAULTS`): ``source``, ``threshold``, ``full``,
    ``extinction``, ``voxel_size``, ``color_var``, ``hours_per_frame``,
    ``exaggeration``, ``haze``, ``camera_lon``, ``camera_lat``,
    ``camera_distance``, ``engine`` (CYCLES or BLENDER_EEVEE), ``frames``
    (first, last), ``size`` (w, h), ``samples``, ``vdb_dir``, ``bake``
    (``"all"`` now, or ``"lazy"``: per frame when shown, from the cache
    that ``nephele precompute`` fills in parallel).
    """
    from nephele.addon import data_ops, frame, globe_ops, volume_ops
    from nephele.core.grid import DEFAULT_EXAGGERATION
    from nephele.core.transfer import TransferFunction
    from nephele.core.volume import DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE

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
    sky = globe_ops.add_sky_and_haze(scene, haze=bool(o["haze"]), sun_direction=(-0.075, -0.863, 0.5),
                                     sun_strength=4.5)
    vdb_dir = o["vdb_dir"]
    if vdb_dir is None and not bpy.data.filepath:
        vdb_dir = str(Path(__file__).resolve().parent.parent / "out" / "fig2_volume_vdb")
    clouds, infos = volume_ops.add_volume_clouds(
        "cloud", TransferFunction.ramp(float(o["threshold"]), float(o["full"])), scene=scene,
        color_var=o["color_var"],
        voxel_size=DEFAULT_VOXEL_SIZE if o["voxel_size"] is None else float(o["voxel_size"]),
        extinction=DEFAULT_EXTINCTION if o["extinction"] is None else float(o["extinction"]),
        directory=vdb_dir, bake=o["bake"],
    )
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])

    render = scene.render
    render.engine = o["engine"]
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(o["samples"])
    scene.cycles.use_denoising = True
    # Clouds lit by the sun and by each other (a few volume bounces).
    scene.cycles.volume_bounces = 4
    scene.eevee.taa_render_samples = int(o["samples"])
    volume_ops.eevee_volume_settings(scene)
    render.resolution_x, render.resolution_y = (int(v) for v in o["size"])
    render.resolution_percentage = 100
    render.image_settings.file_format = "PNG"
    render.film_transparent = False
    frame.install()
    return {"globe": globe, "clouds": clouds, "camera": camera, "bake": infos, **sky}


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
    ap.add_argument("--save", help="save the scene to this .blend (the .vdb files go beside it)")
    ap.add_argument("--frames", type=_parse_frames, default=DEFAULTS["frames"], help="A-B (default 1-24)")
    ap.add_argument("--size", type=_parse_size, default=DEFAULTS["size"], help="WxH (default 640x480)")
    ap.add_argument("--samples", type=int, default=DEFAULTS["samples"])
    ap.add_argument("--source", default=DEFAULTS["source"], help='"demo", "demo:small", a .nc or a .ctl')
    ap.add_argument("--threshold", type=float, default=DEFAULTS["threshold"], help="opacity is zero below it")
    ap.add_argument("--voxel-size", type=float, help="scene units between voxels (default 0.003)")
    ap.add_argument("--engine", choices=("CYCLES", "BLENDER_EEVEE"), default=DEFAULTS["engine"])
    ap.add_argument("--vdb-dir", help="where the .vdb sequence goes")
    ap.add_argument("--no-haze", action="store_true", help="leave out the blue haze")
    args = ap.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    vdb_dir = args.vdb_dir
    if args.save:
        # Save first, so the sequence lands beside the .blend and is linked relatively.
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    build(source=args.source, threshold=args.threshold, voxel_size=args.voxel_size, frames=args.frames,
          size=args.size, samples=args.samples, haze=not args.no_haze, engine=args.engine, vdb_dir=vdb_dir)
    scene = bpy.context.scene
    if args.save:
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
