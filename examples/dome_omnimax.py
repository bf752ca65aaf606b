"""The Fig. 1 globe and clouds for a dome theatre: an Omnimax frame and a domemaster, in stereo.

``build()`` makes the Fig. 1 scene (:mod:`fig1_contours`: relief globe, 15%
cloudiness contours, sky and sun) and puts a dome audience in orbit, the globe
ahead of them and 25 deg up, where a tilted dome's audience looks.  ``main()``
renders, per preset, the left and right eyes (``<preset>_L.png``,
``<preset>_R.png``: Cycles' fisheye renders the final frame) and a picture of
the Omnimax frame beside the domemaster (left eyes, the audience's horizon
and zenith marked in orange).

    .venv/bin/python examples/dome_omnimax.py --out out/dome            # small, for CI
    .venv/bin/python examples/dome_omnimax.py --out out/dome --full     # 2048x1500 and 2048x2048
    .venv/bin/python examples/dome_omnimax.py --out out/dome --engine eevee --mono   # cube-map route

A film through the farm (``build()`` options with ``--set``; frame f shows the
climate at ``hours_per_frame * (f - 1)`` h; stereo frames come out as
``frame_NNNN_L.png`` / ``frame_NNNN_R.png``, EEVEE goes through the cube-map route)::

    nephele render examples/dome_omnimax.py --frames 1-48 --out out/omni --set size='[512,375]'
    nephele render examples/dome_omnimax.py --frames 1-48 --out out/dm --set preset=domemaster --set stereo=false
    nephele post stereo out/omni --out out/omni_stereo

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Figs. 1 and 7.
"""

import argparse
import math
import sys
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

HERE = Path(__file__).resolve().parent

DEFAULTS = {
    "preset": "omnimax",
    "stereo": True,
    "separation": 0.03,  # scene units (the Earth's radius is 1): hyperstereo for a planet
    "distance": 1.7,
    "elevation": 25.0,
    "source": "demo:small",
    "haze": False,
    "size": None,
    "samples": 16,
    "frames": (1, 1),
    "hours_per_frame": 1.0,
    "annotations": False,
}
SMALL = {"omnimax": (256, 188), "domemaster": (192, 192)}
FULL = {"omnimax": (2048, 1500), "domemaster": (2048, 2048)}


def _fig1():
    sys.path.insert(0, str(HERE))
    import fig1_contours

    return fig1_contours


def aim_rig(rig, eye, target, elevation):
    """Turn the dome rig at ``eye`` so ``target`` lies straight ahead, ``elevation`` deg up."""
    g = (Vector(target) - Vector(eye)).normalized()
    z = Vector((0.0, 0.0, 1.0))
    u = (z - z.dot(g) * g) if abs(z.dot(g)) < 0.99 else Vector((0.0, 1.0, 0.0))
    u.normalize()
    e = math.radians(elevation)
    front = math.cos(e) * g - math.sin(e) * u
    up = math.sin(e) * g + math.cos(e) * u
    right = front.cross(up)
    rig.matrix_world = Matrix.Translation(Vector(eye)) @ Matrix([right, front, up]).transposed().to_4x4()


def build(**options):
    """Build Fig. 1 and a dome rig; returns the Fig. 1 objects plus ``"rig"``.

    Options (:data:`DEFAULTS`): ``preset``, ``stereo``, ``separation``,
    ``distance`` (of the audience from the globe's centre), ``elevation`` (of
    the globe's centre above the dome's front horizon), ``source``, ``haze``,
    ``size`` (w, h; default small), ``samples``, ``frames`` (first, last: the
    scene's frame range), ``hours_per_frame`` (climate hours per frame) and ``annotations`` (the
    caption and the model date and time over the frame's corners; Cycles' fisheye only).
    """
    from nephele.addon import dome_ops
    from nephele.core.climate.grid import lonlat_to_xyz

    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise TypeError(f"unknown options {sorted(unknown)}; known: {sorted(DEFAULTS)}")
    o = dict(DEFAULTS, **options)
    size = o["size"] or SMALL[o["preset"]]
    objs = _fig1().build(source=o["source"], haze=o["haze"], samples=o["samples"], frames=tuple(o["frames"]),
                         hours_per_frame=o["hours_per_frame"], size=size)
    rig = dome_ops.add_dome_camera(o["preset"], width=size[0], height=size[1], stereo=o["stereo"],
                                   separation=o["separation"])
    eye = o["distance"] * lonlat_to_xyz(-40.0, 22.0)
    aim_rig(rig, eye, (0.0, 0.0, 0.0), o["elevation"])
    if o["annotations"]:
        from nephele.addon import annotate_ops

        annotate_ops.add_annotations(bpy.context.scene, figure="dome", legend=False)
    return {**objs, "rig": rig}


def render(out, preset, engine="cycles", **options):
    """Build and render one preset into ``out``; returns the written paths (``_L``/``_R`` in stereo)."""
    from nephele.addon import dome_ops

    bpy.ops.wm.read_factory_settings(use_empty=True)
    build(preset=preset, **options)
    scene = bpy.context.scene
    path = (Path(out) / f"{preset}.png").resolve()
    if engine == "eevee":
        scene.render.engine = "BLENDER_EEVEE"
        return dome_ops.render_dome_eevee(path, scene=scene)
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if scene.render.use_multiview:
        return [path.with_name(f"{path.stem}_{s}{path.suffix}") for s in "LR"]
    return [path]


def draw_horizon(img, camera, color=(1.0, 0.55, 0.1)):
    """Mark the audience's horizon (elevation 0, all azimuths) and the zenith on a dome frame."""
    az = np.radians(np.linspace(-180.0, 180.0, 20000))
    d = np.stack([np.sin(az), np.cos(az), np.zeros_like(az)], axis=-1)
    col, row, vis = camera.direction_to_pixel(d)
    zc, zr, zvis = camera.direction_to_pixel(np.array([[0.0, 0.0, 1.0]]))
    h, w = img.shape[:2]
    t = max(1, w // 400)
    sizes = np.r_[np.full(vis.sum(), t), np.full(zvis.sum(), 4 * t)]  # the zenith a larger dot
    for c, r, k in zip(np.r_[col[vis], zc[zvis]], np.r_[row[vis], zr[zvis]], sizes):
        img[max(0, int(r) - k) : int(r) + k + 1, max(0, int(c) - k) : int(c) + k + 1, :3] = color
    return img


def _shrink(img, height):
    """Box-filtered resize to ``height`` rows (keeps the aspect)."""
    h, w = img.shape[:2]
    width = round(w * height / h)
    rows = np.minimum((np.arange(height + 1) * h / height).astype(int), h)
    cols = np.minimum((np.arange(width + 1) * w / width).astype(int), w)
    cs = np.cumsum(np.cumsum(np.pad(img, ((1, 0), (1, 0), (0, 0))), 0), 1)
    s = (cs[rows[1:]][:, cols[1:]] - cs[rows[:-1]][:, cols[1:]]
         - cs[rows[1:]][:, cols[:-1]] + cs[rows[:-1]][:, cols[:-1]])
    area = np.outer(np.diff(rows), np.diff(cols))[..., None]
    return (s / area).astype(np.float32)


def side_by_side(left_png, right_png, out_png, height=375, gap=12, cameras=None):
    """Two frames at one height, side by side on black; with ``cameras`` the horizon is marked."""
    from nephele.addon.dome_ops import read_image, write_image

    tiles = []
    for i, p in enumerate((left_png, right_png)):
        img = read_image(p)[..., :3].copy()
        if cameras:
            draw_horizon(img, cameras[i])
        tiles.append(_shrink(img, height))
    sep = np.zeros((height, gap, 3), np.float32)
    return write_image(out_png, np.concatenate([tiles[0], sep, tiles[1]], axis=1))


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/dome", help="output folder")
    ap.add_argument("--full", action="store_true", help="full size: 2048x1500 Omnimax, 2048x2048 domemaster")
    ap.add_argument("--width", type=int, help="frame width for both presets (Omnimax keeps 2048:1500)")
    ap.add_argument("--samples", type=int, default=None, help="Cycles samples (default 16, full size 64)")
    ap.add_argument("--mono", action="store_true", help="one eye only")
    ap.add_argument("--engine", choices=("cycles", "eevee"), default="cycles",
                    help="eevee: six cube faces per eye remapped by the core (slow without a GPU)")
    ap.add_argument("--source", default=DEFAULTS["source"], help='climate source ("demo", "demo:small", .nc, .ctl)')
    ap.add_argument("--haze", action="store_true", help="add Fig. 1's blue haze (slower)")
    ap.add_argument("--picture", help="also write the Omnimax | domemaster picture here (PNG)")
    ap.add_argument("--save", help="save the Omnimax scene to this .blend")
    args = ap.parse_args(argv)
    samples = args.samples or (64 if args.full else 16)
    sizes = FULL if args.full else SMALL
    if args.width:
        sizes = {"omnimax": (args.width, round(args.width * 1500 / 2048)), "domemaster": (args.width, args.width)}
    out = Path(args.out)
    written = {}
    for preset in ("omnimax", "domemaster"):
        written[preset] = render(out, preset, args.engine, stereo=not args.mono, size=sizes[preset], samples=samples,
                                 source=args.source, haze=args.haze)
        if args.save and preset == "omnimax":
            bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.save).resolve()))
        print(preset, *written[preset])
    from nephele.core.camera import dome

    cams = [dome.dome_camera(p, width=sizes[p][0], height=sizes[p][1]) for p in ("omnimax", "domemaster")]
    pic = side_by_side(written["omnimax"][0], written["domemaster"][0], Path(args.picture or out / "dome.png"),
                       cameras=cams)
    print("picture", pic)
    return 0


if __name__ == "__main__":
    sys.exit(main())
