"""Render docs/images/contour.png for the README: the demo climate's 15% cloudiness contour
(marching cubes, seam and poles closed) over the relief globe, seen from 20°N and from above the
North Pole.  Cycles on the CPU, 420×420 per view, ~1 min on 2 cores.

    .venv/bin/python docs/contour_figure.py [--step 12] [--level 0.15] [--samples 12]
"""

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--step", type=int, default=12)
    ap.add_argument("--level", type=float, default=0.15)
    ap.add_argument("--samples", type=int, default=12)
    ap.add_argument("--size", type=int, default=420)
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "contour.png"))
    args = ap.parse_args(argv)

    import bpy
    import mathutils

    import nephele
    from nephele.addon.globe_ops import add_globe
    from nephele.addon.mesh import new_object
    from nephele.core.climate.grid import lonlat_to_xyz
    from nephele.core.climate.readers import open_dataset
    from nephele.core.surface.contour import isosurface

    bpy.ops.wm.read_factory_settings(use_empty=True)
    nephele.register()
    scene = bpy.context.scene

    ds = open_dataset("demo")
    periodic = ds.grid.periodic_lon
    mesh = isosurface(ds.grid.points(exaggeration=30), ds.read("cloud", args.step), args.level,
                      periodic_lon=periodic, close_poles=periodic)
    clouds = new_object("clouds", mesh)
    if clouds.name not in scene.collection.objects:
        scene.collection.objects.link(clouds)
    white = bpy.data.materials.new("cloud")
    white.use_nodes = True
    bsdf = white.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.92, 0.93, 0.95, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.6
    clouds.data.materials.append(white)
    add_globe(exaggeration=30, radius=1.0, scene=scene)

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 4.0
    sun.rotation_euler = mathutils.Vector((0.6, -1.0, 0.7)).to_track_quat("Z", "Y").to_euler()
    scene.collection.objects.link(sun)
    scene.world = bpy.data.worlds.new("space")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.01, 0.012, 0.02, 1.0)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.cycles.use_denoising = True
    scene.render.resolution_x = scene.render.resolution_y = args.size
    scene.render.image_settings.file_format = "PNG"

    out = Path(args.out)
    views = []
    for name, (lon, lat, dist) in {"globe": (-30.0, 20.0, 3.4), "pole": (-30.0, 89.9, 2.6)}.items():
        cam.location = tuple(lonlat_to_xyz(lon, lat, dist))
        cam.rotation_euler = (-mathutils.Vector(cam.location)).to_track_quat("-Z", "Y").to_euler()
        scene.render.filepath = str(out.with_name(f".{out.stem}_{name}.png"))
        bpy.ops.render.render(write_still=True)
        img = bpy.data.images.load(scene.render.filepath)
        views.append(np.array(img.pixels[:]).reshape(args.size, args.size, 4))
        Path(scene.render.filepath).unlink()
    gap = np.ones((args.size, 6, 4))
    both = np.concatenate([views[0], gap, views[1]], axis=1)
    img = bpy.data.images.new("contour", both.shape[1], both.shape[0], alpha=True)
    img.pixels[:] = both.ravel()
    tmp = out.with_name(f".{out.name}.tmp.png")
    img.filepath_raw = str(tmp)
    img.file_format = "PNG"
    img.save()
    tmp.replace(out)
    print(f"{out}: {len(mesh.faces)} triangles")


if __name__ == "__main__":
    main()
