"""Fig. 6 in motion: a cloud that changes during the film, lit by multiple scattering.

The paper's cloud (Perlin noise on three ellipsoids) with its noise drifting through the
ellipsoids over the film; each frame's scattering is solved warm-started from the frame before
(the passes shoot only the difference the new density makes), and each frame's VDB holds that
frame's density and the light scattered toward that frame's camera, which loops once around the
cloud.  Cycles renders the emission-absorption volume, no path-traced scattering.  The scene is
the Fig. 6 preset (:func:`nephele.addon.presets.fig6`) with the panel's "Motion: Drifting noise".

    .venv/bin/python examples/fig6_evolving.py --out out/fig6_evolving --size 120x102 --samples 8
    .venv/bin/python examples/fig6_evolving.py --out out/fig6_evolving --frames 1-240 --step 24
    .venv/bin/python examples/fig6_evolving.py --out out/fig6_evolving --frames 1,120,121,122,240
    .venv/bin/python examples/fig6_evolving.py --save out/fig6_evolving.blend
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def build(frames=240, grid=(24, 24, 18), drift=(0.25, 0.1, 0.02), directory=None, size=(300, 255), samples=32):
    """The Fig. 6 scene with a drifting cloud, solved frame by frame; returns the cloud object."""
    import bpy

    import nephele
    from nephele.addon import presets
    from nephele.addon.scatter_scene import OBJECT_NAME

    if not hasattr(bpy.types.Scene, "nephele_scatter"):
        nephele.register()
    scene = bpy.context.scene
    # the preset's world, sun, camera orbit and render settings, on a one-frame still cloud first...
    presets.fig6(scene, frames=1, grid=grid, directory=directory, size=size, samples=samples)
    bpy.data.objects.remove(bpy.data.objects[OBJECT_NAME])
    # ... then the film: the orbit over all frames, a solve a frame
    scene.frame_start, scene.frame_end = 1, int(frames)
    for name in ("Scatter orbit", "Scatter orbit pivot"):  # the one-frame orbit: the operator makes the film's
        if name in bpy.data.objects:
            bpy.data.objects.remove(bpy.data.objects[name])
    p = scene.nephele_scatter
    p.evolve, p.drift, p.live_update = "DRIFT", tuple(drift), False
    if bpy.ops.nephele.add_scattering_cloud() != {"FINISHED"}:
        raise RuntimeError(f"Add scattering cloud failed: {p.status}")
    return bpy.data.objects[OBJECT_NAME]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="render frames into this directory")
    ap.add_argument("--save", help="save the scene as a .blend")
    ap.add_argument("--film", type=int, default=240, help="frames in the film (default 240)")
    ap.add_argument("--frames", default=None, help="frames to render, A-B or A,B,C (default: the whole film)")
    ap.add_argument("--step", type=int, default=1, help="render every STEP-th frame")
    ap.add_argument("--size", default="300x255", help="WxH (the paper: 300x255)")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--grid", default="24x24x18")
    ap.add_argument("--drift", default="0.25,0.1,0.02", help="how far the noise moves over the film (box units)")
    args = ap.parse_args(argv)

    import bpy

    sys.path.insert(0, str(ROOT.parent))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from nephele.core.errors import UsageError
    from nephele.core.parse import parse_size
    from nephele.farm.frames import parse_frames

    try:
        w, h = parse_size(args.size)
        picked = parse_frames(args.frames or f"1-{args.film}")[::max(args.step, 1)]
    except UsageError as exc:
        ap.error(str(exc))  # (one line, exit 2)
    out = Path(args.out).resolve() if args.out else None
    t0 = time.perf_counter()
    cloud = build(frames=args.film, grid=tuple(int(v) for v in args.grid.split("x")),
                  drift=tuple(float(v) for v in args.drift.split(",")), directory=(out / "vdb") if out else None,
                  size=(w, h), samples=args.samples)
    print(f"{args.film} frames solved in {time.perf_counter() - t0:.1f} s: {bpy.context.scene.nephele_scatter.status}",
          flush=True)
    scene = bpy.context.scene
    if args.save:
        bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
    if out:
        out.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        for f in picked:
            scene.frame_set(f)
            scene.render.filepath = str(out / f"fig6_evolving_{f:04d}.png")
            bpy.ops.render.render(write_still=True)
        print(f"rendered {len(picked)} frames in {time.perf_counter() - t0:.1f} s "
              f"-> {out} ({cloud.name})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
