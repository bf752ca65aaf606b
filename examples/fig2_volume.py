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

DEFAULTS = {
    "source": "demo",
    "threshold": 0.3,
    "full": 0.7,
    "extinction": None,  # None: nephele.core.volume.sparse.DEFAULT_EXTINCTION
    "mode": None,  # None: "exact" for Cycles, "voxels" for EEVEE (which renders the exact shader striped)
    "voxel_size": None,  # None: nephele.core.volume.sparse.DEFAULT_VOXEL_SIZE (voxel mode)
    "color_var": "altitude",
    "hours_per_frame": 1.0,
    "exaggeration": None,  # None: nephele.core.climate.grid.DEFAULT_EXAGGERATION
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
    ``extinction``, ``mode`` (``"exact"``: the material evaluates the
    curvilinear field per sample; ``"voxels"``: a resampled VDB),
    ``voxel_size``, ``color_var``, ``hours_per_frame``,
    ``exaggeration``, ``haze``, ``camera_lon``, ``camera_lat``,
    ``camera_distance``, ``engine`` (CYCLES or BLENDER_EEVEE), ``frames``
    (first, last), ``size`` (w, h), ``samples``, ``vdb_dir``, ``bake``
    (``"all"`` now, or ``"lazy"``: per frame when shown, from the cache
    that ``nephele precompute`` fills in parallel).
    """
    from nephele.addon import frame, globe_ops, globe_scene, volume_ops
    from nephele.core.volume.transfer import TransferFunction
    from nephele.core.volume.sparse import DEFAULT_EXTINCTION, DEFAULT_VOXEL_SIZE

    o = globe_scene.merge_options(DEFAULTS, options)
    scene = bpy.context.scene
    globe, sky = globe_scene.globe_scene(scene, o, sun_direction=(-0.075, -0.863, 0.5), haze=bool(o["haze"]))
    vdb_dir = o["vdb_dir"]
    if vdb_dir is None and not bpy.data.filepath:
        vdb_dir = str(Path(__file__).resolve().parent.parent / "out" / "fig2_volume_vdb")
    clouds, infos = volume_ops.add_volume_clouds(
        "cloud", TransferFunction.ramp(float(o["threshold"]), float(o["full"])), scene=scene,
        color_var=o["color_var"],
        voxel_size=DEFAULT_VOXEL_SIZE if o["voxel_size"] is None else float(o["voxel_size"]),
        extinction=DEFAULT_EXTINCTION if o["extinction"] is None else float(o["extinction"]),
        directory=vdb_dir, bake=o["bake"],
        mode=o["mode"] or ("voxels" if o["engine"] == "BLENDER_EEVEE" else "exact"),
    )
    camera = globe_ops.add_camera(scene, lon=o["camera_lon"], lat=o["camera_lat"], distance=o["camera_distance"])

    globe_scene.render_settings(scene, o["size"], o["samples"], engine=o["engine"])
    # Clouds lit by the sun and by each other (a few volume bounces).
    scene.cycles.volume_bounces = 4
    scene.eevee.taa_render_samples = int(o["samples"])
    volume_ops.eevee_volume_settings(scene)
    frame.install()
    return {"globe": globe, "clouds": clouds, "camera": camera, "bake": infos, **sky}


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
          size=args.size, samples=args.samples, haze=not args.no_haze, engine=args.engine, vdb_dir=vdb_dir)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
