"""Contour surfaces in Blender: they follow the frame through model time, come from the
cache, and render the same in a fresh process that only calls frame.install()."""

import json
import subprocess
import sys
import textwrap

import bpy
import numpy as np
import pytest

from nephele.addon import contour_ops, data_ops, frame, globe_ops
from nephele.addon.mesh import mesh_arrays, point_attribute
from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, xyz_to_lonlat
from nephele.core.pipeline import sources

SPEED = 5.0  # degrees of longitude per hour


def moving_blob():
    """A cloud blob centred at lon 30 + 5 t, lat 0, 6 km up: it moves east 5° per hour."""
    lon = np.arange(0.0, 360.0, 4.0)
    lat = np.linspace(-90.0, 90.0, 46)
    levels = np.linspace(0.0, 12000.0, 7)
    height = np.broadcast_to(levels[:, None, None], (7, 46, 90)).copy()
    grid = GlobeGrid(lon, lat, height)
    t = np.arange(25)
    dlon = (lon[None, None, None, :] - 30.0 - SPEED * t[:, None, None, None] + 180.0) % 360.0 - 180.0
    d2 = (dlon / 20.0) ** 2 + (lat[None, None, :, None] / 15.0) ** 2 + ((height[None] - 6000.0) / 4000.0) ** 2
    cloud = np.exp(-d2).astype(np.float32)
    return ArrayDataset(grid, hourly("2000-01-01", 25), {"cloud": cloud}, source="moving blob")


@pytest.fixture()
def blob_source(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    name = sources.register_source("memory:moving-blob", moving_blob())
    data_ops.set_settings(empty_scene, source=name, hours_per_frame=1.0, frame_start=1)
    return name


def mean_lon(obj):
    v, _ = mesh_arrays(obj.data)
    lon, lat, _ = xyz_to_lonlat(v)
    return float(np.rad2deg(np.angle(np.exp(1j * np.deg2rad(lon)).mean())))


def test_contour_follows_the_frame(blob_source, tmp_path):
    scene = bpy.context.scene
    scene.frame_set(1)
    obj = contour_ops.add_contour("cloud", 0.5, scene=scene)
    assert frame.params(obj)["kind"] == "contour"
    n1 = len(obj.data.polygons)
    assert n1 > 50
    assert mean_lon(obj) == pytest.approx(30.0, abs=1.0)
    scene.frame_set(13)
    assert obj["nephele_hours"] == 12.0
    assert mean_lon(obj) == pytest.approx(30.0 + 12 * SPEED, abs=1.0)
    # The material's attribute exists on the refilled mesh.
    alt = point_attribute(obj.data, "altitude")
    assert alt.min() > 0 and alt.max() < 12000
    assert obj.active_material.node_tree.nodes["Nephele attribute"].attribute_name == "altitude"
    # Every frame shown went through the cache.
    assert len(list((tmp_path / "cache" / "contour").rglob("*.npz"))) == 2


def test_hours_per_frame_and_interpolation(blob_source):
    scene = bpy.context.scene
    data_ops.set_settings(scene, hours_per_frame=0.5)
    obj = contour_ops.add_contour("cloud", 0.5, scene=scene)
    scene.frame_set(3)  # 1 h
    assert obj["nephele_hours"] == 1.0
    assert mean_lon(obj) == pytest.approx(30.0 + SPEED, abs=1.0)
    scene.frame_set(2)  # half-way between the steps at 0 h and 1 h
    assert obj["nephele_hours"] == 0.5
    assert 30.0 < mean_lon(obj) < 30.0 + SPEED
    scene.frame_set(1000)  # past the data: the last step
    assert obj["nephele_hours"] == 24.0


def test_updater_skips_a_frame_already_shown(blob_source, monkeypatch):
    scene = bpy.context.scene
    contour_ops.add_contour("cloud", 0.5, scene=scene)
    calls = []
    real = contour_ops.run_cached
    monkeypatch.setattr(contour_ops, "run_cached", lambda *a: calls.append(a) or real(*a))
    scene.frame_set(scene.frame_current)
    assert calls == []
    scene.frame_set(scene.frame_current + 1)
    assert len(calls) == 1


def test_operators(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    scene = bpy.context.scene
    assert scene.nephele_data.source == "demo:small"
    assert json.loads(scene[data_ops.MIRROR_KEY])["source"] == "demo:small"
    ds = data_ops.dataset(scene=scene)
    assert (scene.frame_start, scene.frame_end) == (1, 1 + int(ds.hours[-1]))
    scene.nephele_data.exaggeration = 20.0  # the panel's field reaches the mirror
    assert data_ops.settings(scene)["exaggeration"] == 20.0
    assert bpy.ops.nephele.add_contour(var="cloud", level=0.15, color_var="temperature") == {"FINISHED"}
    obj = next(o for o in scene.objects if frame.params(o).get("kind") == "contour")
    p = frame.params(obj)
    assert p["exaggeration"] == 20.0 and p["source"] == "demo:small" and p["color_var"] == "temperature"
    assert len(obj.data.polygons) > 100 and "temperature" in obj.data.attributes
    # A bad file is reported (bpy.ops turns an ERROR report into RuntimeError) and changes nothing.
    bad = tmp_path / "bad.nc"
    bad.write_text("not netcdf")
    with pytest.raises(RuntimeError, match="bad.nc"):
        bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(bad))
    assert scene.nephele_data.source == "demo:small"


def _pixels(path):
    img = bpy.data.images.load(str(path))
    a = np.empty(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(a)
    bpy.data.images.remove(img)
    return a.reshape(-1, 4)[:, :3]


def _render(scene, path):
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return path


FRESH = textwrap.dedent("""
    import sys, bpy
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False)
    assert not hasattr(bpy.types.Scene, "nephele_data"), "the add-on must not be registered"
    from nephele.addon import data_ops, frame
    frame.install()
    scene = bpy.context.scene
    assert data_ops.settings(scene)["hours_per_frame"] == 3.0  # the mirrored settings survived
    for f, out in ((13, sys.argv[2]), (1, sys.argv[3])):
        scene.frame_set(f)
        scene.render.filepath = out
        bpy.ops.render.render(write_still=True)
""")


@pytest.mark.slow
def test_saved_blend_renders_the_same_in_a_fresh_process(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "user_cache"))
    scene = empty_scene
    data_ops.set_settings(scene, source="demo:small", hours_per_frame=3.0)
    globe_ops.add_globe("flat", scene=scene)
    globe_ops.add_sky_and_haze(scene, haze=False)
    globe_ops.add_camera(scene, lon=0.0, lat=20.0, distance=3.2)
    scene.frame_set(1)
    obj = contour_ops.add_contour("cloud", 0.15, scene=scene)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    cache = frame.results_dir()
    assert cache.parent == tmp_path
    v1 = mesh_arrays(obj.data)[0].copy()
    scene.frame_set(13)
    assert not np.array_equal(mesh_arrays(obj.data)[0][:10], v1[:10]) or len(obj.data.vertices) != len(v1)
    in_session = _render(scene, tmp_path / "session13.png")

    import shutil

    shutil.rmtree(cache)  # the fresh process must compute the meshes itself
    res = subprocess.run([sys.executable, "-c", FRESH, str(blend), str(tmp_path / "fresh13.png"),
                          str(tmp_path / "fresh1.png")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert len(list(cache.rglob("*.npz"))) == 2

    a, b, c = _pixels(in_session), _pixels(tmp_path / "fresh13.png"), _pixels(tmp_path / "fresh1.png")
    assert np.abs(a - b).mean() < 0.005, np.abs(a - b).mean()
    # ... and the frame really changed the clouds.
    assert np.abs(b - c).mean() > 0.01


@pytest.mark.parametrize("name", ["model.ctl", "rectilinear_grid_3D.nc"])
def test_real_files_through_the_operators(empty_scene, shared_data, tmp_path, monkeypatch, name):
    # GrADS sample model output (NaN below ground) and ECHAM5 NetCDF: cloud from relative humidity.
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "cache"))
    path = shared_data / "climate" / name
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path)) == {"FINISHED"}
    scene = bpy.context.scene
    assert scene.nephele_data.source == str(path)
    assert bpy.ops.nephele.add_contour(var="cloud", level=0.15) == {"FINISHED"}
    obj = next(o for o in scene.objects if frame.params(o).get("kind") == "contour")
    v, f = mesh_arrays(obj.data)
    assert len(f) > 100 and np.isfinite(v).all()
    r = np.linalg.norm(v, axis=1)
    ds = data_ops.dataset(scene=scene)
    from nephele.core.climate.grid import globe_radius

    # Inside the grid's shell (pressure levels can lie below sea level: 1000 hPa over a low),
    # less the sagitta of a straight grid edge between points on a sphere.
    lo, hi = (
        globe_radius(h, 1.0, scene.nephele_data.exaggeration) for h in (ds.grid.height.min(), ds.grid.height.max())
    )
    step = np.deg2rad(max(np.diff(ds.grid.lon).max(), np.diff(ds.grid.lat).max()))
    assert r.min() >= lo * np.cos(step / 2) - 1e-5 and r.max() <= hi + 1e-5


def test_empty_contour(blob_source):
    scene = bpy.context.scene
    obj = contour_ops.add_contour("cloud", 5.0, scene=scene)  # the field never reaches 5
    assert len(obj.data.vertices) == 0 and len(obj.data.polygons) == 0
    scene.frame_set(5)
    assert len(obj.data.polygons) == 0 and obj["nephele_hours"] == 4.0


def test_tetra5_method(blob_source):
    scene = bpy.context.scene
    cubes = contour_ops.add_contour("cloud", 0.5, scene=scene, name="cubes")
    tetra = contour_ops.add_contour("cloud", 0.5, scene=scene, method="tetra5", name="tetra")
    assert frame.params(tetra)["method"] == "tetra5"
    # The paper's 5-tetrahedra split cuts more, smaller triangles through the same cells.
    assert len(tetra.data.polygons) > len(cubes.data.polygons)
    assert mean_lon(tetra) == pytest.approx(mean_lon(cubes), abs=1.0)


def test_settings_saved_without_the_addon_show_in_the_panel(empty_scene, tmp_path):
    import nephele

    nephele.unregister()
    try:
        assert not hasattr(bpy.types.Scene, "nephele_data")
        data_ops.set_settings(empty_scene, source="demo:small", exaggeration=12.0)
        blend = tmp_path / "plain.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    finally:
        nephele.register()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    assert scene.nephele_data.source == "demo:small" and scene.nephele_data.exaggeration == 12.0
    scene.nephele_data.radius = 3.0  # editing one field keeps the others
    assert data_ops.settings(scene) == dict(data_ops.DEFAULTS, source="demo:small", exaggeration=12.0, radius=3.0)
