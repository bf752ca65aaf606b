"""Helpers of the Blender tests: a tiny render, a curvilinear file imported through the panel."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")


def render_small(path, scene=None, engine="CYCLES", size=(64, 48), samples=4):
    """Render ``scene`` (default: current) to ``path`` at a tiny size; returns the path."""
    scene = scene or bpy.context.scene
    scene.render.engine = engine
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    if engine == "CYCLES":
        scene.cycles.samples = samples
        scene.cycles.device = "CPU"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return path


def import_sheared_file(path, fields, z, lat=(40.0, 50.0), lon=(-10.0, 5.0), shape=(12, 16)):
    """Write a CF file on sheared columns (2-D lat/lon, not a product grid: lon + 0.3 (lat - 45)),
    heights ``z`` (m) and two times 3 h apart, and import it through the Dataset panel.

    ``fields``: name -> ``(values_of(lat2d, lon2d, z3) -> array broadcasting to (nz, ny, nx), attrs)``.
    Returns ``(lat2d, lon2d)``.
    """
    xr = pytest.importorskip("xarray")
    ny, nx = shape
    la, lo = np.meshgrid(np.linspace(*lat, ny), np.linspace(*lon, nx), indexing="ij")
    lo = lo + 0.3 * (la - 45)
    zz = np.asarray(z, float)[:, None, None]
    data = {name: (("time", "z", "y", "x"),
                   np.repeat(np.broadcast_to(f(la, lo, zz), (len(z), ny, nx))[None], 2, 0).astype(np.float32), attrs)
            for name, (f, attrs) in fields.items()}
    xr.Dataset(
        data,
        coords={"time": ("time", [0.0, 3.0], {"units": "hours since 2020-01-01", "standard_name": "time"}),
                "z": ("z", np.asarray(z, float), {"units": "m", "standard_name": "height", "positive": "up"}),
                "lat": (("y", "x"), la, {"units": "degrees_north", "standard_name": "latitude"}),
                "lon": (("y", "x"), lo, {"units": "degrees_east", "standard_name": "longitude"})},
    ).to_netcdf(path)
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path)) == {"FINISHED"}
    return la, lo
