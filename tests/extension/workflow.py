"""The artist's workflow in a Python that has only what Blender ships.

Run by ``test_extension.py`` with the interpreter of a venv holding nothing but
the ``bpy`` wheel and its dependencies::

    BLENDER_USER_RESOURCES=/tmp/x python workflow.py ZIP OUT_DIR [NETCDF_FILE]

It installs the zip through Blender's extension API, drives every sidebar
operator in order, renders one small frame, disables and re-enables the
extension, and prints one ``RESULT {json}`` line.  Any failed step raises
(non-zero exit).
"""

import importlib.util
import json
import os
import sys
import time
from pathlib import Path

ZIP, OUT = Path(sys.argv[1]), Path(sys.argv[2])
NETCDF = Path(sys.argv[3]) if len(sys.argv) > 3 else None
MODULE = "bl_ext.user_default.nephele"
# Every operator of the add-on is driven below; a new one must be added here.
DRIVEN = {"import_dataset", "add_contour", "update_frame", "add_advected_texture", "add_globe", "add_sky",
          "add_camera", "add_volume_clouds", "add_scattering_cloud", "add_dome_camera", "render_dome_cube",
          "add_flow_volume", "update_flow_volume", "add_muscle_film", "clear_cache", "cancel_jobs", "delete_layer",
          "sync_layers", "paper_figure", "add_wind_splats", "bake_volume", "add_annotations", "remove_annotations"}
# Registered but not driven here: the status-bar watcher is a modal operator that needs a window
# (headless, work is synchronous and never needs watching).
WINDOW_ONLY = {"watch_jobs"}

resources = Path(os.environ["BLENDER_USER_RESOURCES"])
# The environment must really lack what the extension bundles, or the test proves nothing.
absent = {m: importlib.util.find_spec(m) is None
          for m in ("scipy", "xarray", "netCDF4", "pandas", "cftime", "nephele", "nephele_native")}
assert all(absent.values()), f"the Blender-only Python already has {[m for m, a in absent.items() if not a]}"

import bpy  # noqa: E402
import numpy as np  # noqa: E402  (Blender's own)

bpy.ops.wm.read_factory_settings(use_empty=True)
times = {}
t0 = time.perf_counter()
assert bpy.ops.extensions.package_install_files(
    filepath=str(ZIP), repo="user_default", enable_on_install=True) == {"FINISHED"}
times["install"] = time.perf_counter() - t0
assert MODULE in sys.modules, "the extension did not load"
assert hasattr(bpy.types, "NEPHELE_PT_main"), "the Nephele sidebar tab is not registered"

import netCDF4  # noqa: E402
import scipy.ndimage  # noqa: E402
import xarray  # noqa: E402

import nephele_native  # noqa: E402  (the compiled kernels: linux-x64 zips carry them)

# The bundled wheels, from the extension's own site-packages.
for mod in (scipy, xarray, netCDF4, nephele_native):
    assert Path(mod.__file__).resolve().is_relative_to(resources.resolve()), mod.__file__

ops = bpy.ops.nephele
registered = {name for name in dir(ops) if not name.startswith("_")}
assert registered == DRIVEN | WINDOW_ONLY, f"operators not driven by this workflow: " \
    f"{sorted(registered - DRIVEN - WINDOW_ONLY)}; gone: {sorted((DRIVEN | WINDOW_ONLY) - registered)}"
scene = bpy.context.scene
results = {}


def step(name, call):
    t = time.perf_counter()
    res = call()
    times[name] = time.perf_counter() - t
    results[name] = sorted(res)
    assert res == {"FINISHED"}, f"{name} returned {res}"


def active(name_part):
    obj = bpy.context.view_layer.objects.active
    assert obj is not None and name_part in obj.name and obj.select_get(), \
        f"the new {name_part!r} object is not selected and active (active: {obj and obj.name})"
    assert [o.name for o in bpy.context.view_layer.objects.selected] == [obj.name]
    return obj


if NETCDF is not None:  # xarray + netCDF4 from the wheels, on a real file
    step("import_netcdf", lambda: ops.import_dataset(kind="FILE", filepath=str(NETCDF)))
step("import_demo", lambda: ops.import_dataset(kind="DEMO_SMALL"))
scene.frame_start, scene.frame_end = 1, 2
scene.frame_set(1)
step("add_contour", lambda: ops.add_contour(var="cloud", level=0.15))
active("")
assert ops.add_advected_texture.poll(), "Add advected cloud texture is greyed out after Add contour"
step("add_advected_texture", lambda: ops.add_advected_texture(strategy="restart", period=8))
# A second layer, listed and then deleted through the layer list's operator.
ops.add_contour(var="cloud", level=0.5)
second = bpy.context.view_layer.objects.active.name
step("delete_layer", lambda: ops.delete_layer(name=second))
assert second not in bpy.data.objects
step("sync_layers", lambda: ops.sync_layers())
step("cancel_jobs", lambda: ops.cancel_jobs())
step("update_frame", lambda: ops.update_frame())
fv = scene.nephele_flowvol
fv.hours, fv.sides, fv.steps = 6.0, 8, 4
step("add_flow_volume", lambda: ops.add_flow_volume())
active("")
step("update_flow_volume", lambda: ops.update_flow_volume())
spl = scene.nephele_splats
spl.stride = 2
step("add_wind_splats", lambda: ops.add_wind_splats())
assert len(active("Splats").data.vertices) > 0
step("add_globe", lambda: ops.add_globe())
active("Globe")
step("add_sky", lambda: ops.add_sky())
step("add_camera", lambda: ops.add_camera())
active("Camera")
vol = scene.nephele_volume
vol.current_only = True
vol.directory = str(OUT / "volume")
step("add_volume_clouds", lambda: ops.add_volume_clouds())
step("bake_volume", lambda: ops.bake_volume())
active("Clouds")
sc = scene.nephele_scatter
sc.resolution = (8, 8, 6)
sc.tolerance = 1e-2
sc.orbit_camera = False
sc.directory = str(OUT / "scatter")
step("add_scattering_cloud", lambda: ops.add_scattering_cloud())
active("cloud")
globe_camera = scene.camera
step("clear_cache", lambda: ops.clear_cache())
step("add_dome_camera", lambda: ops.add_dome_camera(preset="domemaster", width=32, height=32))
dome = bpy.context.view_layer.objects.active
assert dome is not None and dome.select_get()
# The cube-map route works with any engine: Workbench keeps its six renders quick.
scene.render.engine = "BLENDER_WORKBENCH"
step("render_dome_cube", lambda: ops.render_dome_cube(filepath=str(OUT / "dome.png")))
assert (OUT / "dome.png").stat().st_size > 0

# One small Cycles frame through the globe camera, everything in the scene.
scene.camera = globe_camera
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 2
scene.render.resolution_x, scene.render.resolution_y = 64, 48
scene.render.resolution_percentage = 100
scene.render.filepath = str(OUT / "frame.png")
# The annotation layer (heading, model time, legend) over the render, through the compositor.
step("add_annotations", lambda: ops.add_annotations(heading="Workflow"))
annotate = importlib.import_module(MODULE + ".addon.annotate_ops")
layer = bpy.data.images[annotate.IMAGE]
assert tuple(layer.size) == (64, 48) and np.array(layer.pixels[:])[3::4].max() > 0.5, "the annotation layer is empty"
step("render", lambda: bpy.ops.render.render(write_still=True))
times["install_to_frame"] = time.perf_counter() - t0
img = bpy.data.images.load(str(OUT / "frame.png"))
pixels = np.array(img.pixels[:], dtype=np.float32).reshape(48, 64, 4)[..., :3]
assert pixels.std() > 0.02 and pixels.max() > 0.1, "the rendered frame is blank"
step("remove_annotations", lambda: ops.remove_annotations())
assert annotate.annotations_object(scene) is None and annotate.IMAGE not in bpy.data.images

# The muscle film (its own world and lattice), small: one box, a coarse grid.
step("add_muscle_film", lambda: ops.add_muscle_film(frames=2, spacing=1.5, tiles=(1, 1, 1), camera=False))
# its meshes were made by the compiled kernels, not their NumPy twins
assert importlib.import_module(MODULE + ".core.native").identity() == nephele_native.BUILD_ID
active("")

# A panel's "Make the paper's figure" preset, into a scene of its own (it replaces the scene's objects;
# headless the operator runs without its confirm dialog).
fig_scene = bpy.data.scenes.new("Paper figure")
with bpy.context.temp_override(scene=fig_scene):
    step("paper_figure", lambda: ops.paper_figure(figure="FIG1"))
assert any(o.type == "MESH" for o in fig_scene.objects) and fig_scene.camera is not None

# Disable: nothing of the add-on stays registered (recorded, checked by the test).
addon_classes = [c for name, mod in list(sys.modules.items()) if name.startswith(MODULE)
                 for c in getattr(mod, "CLASSES", ())]
assert len(addon_classes) > 10 and all(c.is_registered for c in addon_classes)
bpy.ops.preferences.addon_disable(module=MODULE)
left = {
    "panel": hasattr(bpy.types, "NEPHELE_PT_main"),
    "operators": [n for n in dir(bpy.ops.nephele) if not n.startswith("_")],
    "classes": [c.__name__ for c in addon_classes if c.is_registered],
    "scene_properties": [p.identifier for p in bpy.types.Scene.bl_rna.properties
                         if p.identifier.startswith("nephele")],
    "handlers": [f"{h}: {f.__module__}.{f.__name__}" for h in dir(bpy.app.handlers) if not h.startswith("_")
                 and isinstance(getattr(bpy.app.handlers, h), list) for f in getattr(bpy.app.handlers, h)
                 if getattr(f, "__module__", "").startswith(MODULE)],
}

# Re-enable in the same session: registers again and works.
bpy.ops.preferences.addon_enable(module=MODULE)
assert hasattr(bpy.types, "NEPHELE_PT_main")
step("add_globe_again", lambda: bpy.ops.nephele.add_globe())

print("RESULT " + json.dumps({"times": times, "results": results, "left_after_disable": left,
                              "bpy": bpy.app.version_string, "python": sys.version.split()[0]}), flush=True)
