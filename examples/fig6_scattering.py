"""Fig. 6: a cloud lit by multiple scattering, the camera looping around it.

Builds the paper's cloud (Perlin noise on three ellipsoids, 24x24x18), solves
multiple scattering of sunlight and skylight with 96 direction bins (albedo
0.99, Henyey-Greenstein g = 0.8), and writes one VDB per frame holding the
extinction and the light scattered toward that frame's camera; Cycles then
renders an emission-absorption volume, no path-traced scattering.

``--sky uniform`` (default): a uniform sky of radiance 0.35 lights the cloud from
above, the background is plain blue.  ``--sky world``: Blender's physical Sky
Texture (the multiple-scattering Nishita model) with its sun where the cloud's
sun is; Cycles renders that world alone as a panorama, binned into the 96
directions, and that light (less the sun disc: the sun lights the cloud as its
own parallel beam) enters the solve; the camera orbits 20 degrees below the
cloud, so the background is that sky (AgX view transform for its bright horizon).

    .venv/bin/python examples/fig6_scattering.py --out out/fig6 --frames 1-4 --size 300x255
    .venv/bin/python examples/fig6_scattering.py --out out/fig6_sky --frames 1 --sky world
    .venv/bin/python examples/fig6_scattering.py --save out/fig6.blend
"""

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def build(frames=120, grid=(24, 24, 18), sun_irradiance=7.0, sky_radiance=0.35, directory=None,
          size=(300, 255), samples=32, sky="uniform", annotations=False, volume_biased=False, **_):
    """Build the Fig. 6 scene into the current (empty) scene (:func:`nephele.addon.presets.fig6`); returns the cloud.

    ``annotations``: the figure's caption over every render (:mod:`nephele.addon.annotate_ops`);
    ``volume_biased``: Cycles' ray marching instead of null scattering (a preview: far less set-up a frame)."""
    import bpy

    import nephele
    from nephele.addon import presets

    if not hasattr(bpy.types.Scene, "nephele_scatter"):
        nephele.register()
    return presets.fig6(bpy.context.scene, frames=frames, grid=grid, sun_irradiance=sun_irradiance,
                        sky_radiance=sky_radiance, directory=directory, size=size, samples=samples,
                        sky=sky, annotations=bool(annotations), volume_biased=bool(volume_biased))["cloud"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="render frames into this directory")
    ap.add_argument("--save", help="save the scene as a .blend")
    ap.add_argument("--frames", default="1-120", help="frames to render, e.g. 1-120 or 1,60 (the orbit has 120)")
    ap.add_argument("--size", default="300x255", help="WxH (the paper: 300x255)")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--step", type=int, default=1, help="render every STEP-th frame")
    ap.add_argument("--grid", default="24x24x18")
    ap.add_argument("--sky", choices=("uniform", "world"), default="uniform",
                    help="uniform sky from above, or a Sky Texture world lighting the cloud")
    ap.add_argument("--annotations", action="store_true", help="lay the figure's caption over every render")
    args = ap.parse_args(argv)

    import bpy

    sys.path.insert(0, str(ROOT.parent))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from nephele.core.errors import UsageError
    from nephele.core.parse import parse_size
    from nephele.farm.frames import parse_frames

    try:
        w, h = parse_size(args.size)
        picked = parse_frames(args.frames)[::max(args.step, 1)]
    except UsageError as exc:
        ap.error(str(exc))  # (one line, exit 2)
    out = Path(args.out).resolve() if args.out else None
    directory = (out / "vdb") if out else None
    build(frames=max(120, picked[-1]), grid=tuple(int(v) for v in args.grid.split("x")), size=(w, h),
          samples=args.samples, directory=directory, sky=args.sky, annotations=args.annotations)
    scene = bpy.context.scene
    if args.save:
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    if out:
        out.mkdir(parents=True, exist_ok=True)
        for f in picked:
            scene.frame_set(f)
            scene.render.filepath = str(out / f"fig6_{f:04d}.png")
            bpy.ops.render.render(write_still=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
