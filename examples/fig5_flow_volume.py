"""Fig. 5 of Max & Crawfis: simulated smoke in the global air circulation (a flow volume).

``build()`` makes the scene in the current Blender scene: the demo climate,
the relief globe, a smoke generator facing the winds and the air that flowed
through it during ``hours`` (constant-colour emission-absorption smoke), and
a camera looking at it.

    .venv/bin/python examples/fig5_flow_volume.py --out out/fig5 --frames 1-1 --size 320x240 --samples 16

``--fire`` instead releases smoke above the fire in a room (``fire_ug.vtu``,
a steady 3-D flow read and interpolated without VTK): the room's floor and
two walls, the generator above the fastest updraft, one second of air.

    .venv/bin/python examples/fig5_flow_volume.py --fire --out out/fig5_fire --size 320x240 --samples 16

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 5
   ("Simulated smoke in global air circulation").
.. [2] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
"""

import sys
from pathlib import Path

import bpy

from nephele.addon import presets

DEFAULTS = presets.FIG5_DEFAULTS  # the add-on's recipe, also its panel's preset


def build(**options):
    """Build the Fig. 5 scene into the current scene (:func:`nephele.addon.presets.fig5`); returns a dict of
    the main objects."""
    import nephele

    if not hasattr(bpy.types.Scene, "nephele_flowvol"):
        nephele.register()
    return presets.fig5(bpy.context.scene, **options)


FIRE = {
    "path": str(Path(__file__).resolve().parent.parent / "tests" / "data" / "flow" / "fire_ug.vtu"),
    "seconds": 1.0,
    "radius": 0.1,
    "above": 0.1,
    "sides": 32,
    # Optical depth about 1 across the generator's diameter.
    "density": 6.0,
}


def _room(bounds):
    """Floor, back wall and left wall of the room's box (grey, diffuse) and a sun."""
    import numpy as np

    from nephele.addon.materials import enable_nodes
    from nephele.addon.mesh import new_object
    from nephele.core.surface.mesh import Mesh

    (x0, x1), (y0, y1), (z0, z1) = bounds
    quads = {"floor": [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
             "back wall": [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
             "left wall": [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)]}
    mat = bpy.data.materials.new("Room")
    enable_nodes(mat)
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.05, 0.05, 0.06, 1.0)
    for name, q in quads.items():
        v = np.array(q, dtype=np.float64)
        f = np.array([[0, 1, 2], [0, 2, 3]])
        n = np.cross(v[1] - v[0], v[2] - v[0])
        obj = new_object(name, Mesh(v, f, np.tile(n / np.linalg.norm(n), (4, 1))), smooth=False)
        obj.data.materials.append(mat)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 2.0
    sun.rotation_euler = (0.7, 0.2, 0.4)
    bpy.context.scene.collection.objects.link(sun)


def build_fire(**options):
    """Smoke above the fire in a room (a steady 3-D flow from a .vtu) into the current scene."""
    import numpy as np
    from mathutils import Vector

    import nephele
    from nephele.addon import globe_scene
    from nephele.core.flowvol import UnstructuredVelocity

    o = {**FIRE, **{k: v for k, v in options.items() if v is not None}}
    scene = bpy.context.scene
    if not hasattr(bpy.types.Scene, "nephele_flowvol"):
        nephele.register()
    world = bpy.data.worlds.new("Room world")
    world.color = (0.02, 0.02, 0.025)
    scene.world = world
    fire = UnstructuredVelocity(o["path"])
    _room(fire.bounds)
    p = scene.nephele_flowvol
    p.vtu_path, p.vtu_height, p.radius, p.hours, p.start_hour = o["path"], o["above"], o["radius"], o["seconds"], 0.0
    p.sides, p.steps, p.tolerance, p.density, p.live = o["sides"], 8, 0.05, o["density"], False
    p.color = (1.0, 0.85, 0.7)
    assert bpy.ops.nephele.add_flow_volume() == {"FINISHED"}, p.status
    smoke = bpy.data.objects["Flow volume smoke"]
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    co = np.array([v.co[:] for v in smoke.data.vertices])
    centre = 0.5 * (co.min(axis=0) + co.max(axis=0))  # look at the smoke, from the open front of the room
    cam.location = (centre[0] + 0.6, fire.bounds[1, 0] - 1.8, centre[2] + 0.9)
    cam.rotation_euler = (Vector(centre) - cam.location).to_track_quat("-Z", "Y").to_euler()
    cam.data.lens = 35
    globe_scene.render_settings(scene, o["size"], o["samples"])
    return {"smoke": smoke, "camera": cam, "velocity": fire}


def main(argv=None):
    from nephele.addon import globe_scene

    argv = sys.argv[1:] if argv is None else argv
    ap = globe_scene.argument_parser(__doc__.split("\n\n")[0], DEFAULTS)
    ap.add_argument("--hours", type=float, default=DEFAULTS["hours"], help="release window in hours")
    ap.add_argument("--radius", type=float, default=DEFAULTS["radius"], help="generator radius (globe radius 1)")
    ap.add_argument("--density", type=float, default=None, help="smoke density (per scene unit)")
    ap.add_argument("--fire", action="store_true",
                    help="smoke above the fire in a room (fire_ug.vtu) instead of the globe")
    ap.add_argument("--vtu", default=FIRE["path"], help="the .vtu of --fire")
    ap.add_argument("--seconds", type=float, default=None,
                    help=f"--fire: release window in seconds (default {FIRE['seconds']:g}; longer releases reach the "
                         "walls)")
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if args.fire:
        build_fire(path=args.vtu, size=args.size, samples=args.samples, density=args.density, seconds=args.seconds)
        if args.annotations:
            from nephele.addon import annotate_ops

            annotate_ops.add_annotations(bpy.context.scene, figure="fig5")
        print(bpy.context.scene.nephele_flowvol.status)
        if args.save:
            globe_scene.save(args.save)
        if args.out:
            globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
        return 0
    build(source=args.source, frames=args.frames, size=args.size, samples=args.samples, hours=args.hours,
          radius=args.radius,
          density=DEFAULTS["density"] if args.density is None else args.density, annotations=args.annotations)
    print(bpy.context.scene.nephele_flowvol.status)
    if args.save:
        globe_scene.save(args.save)
    if args.out:
        globe_scene.render_frames(bpy.context.scene, args.frames, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
