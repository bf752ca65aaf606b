"""NumPy-only algorithms of Nephele.  Nothing here imports Blender.

The code is grouped by domain (see ``docs/architecture.md``): :mod:`.climate`,
:mod:`.surface`, :mod:`.volume`, :mod:`.flow`, :mod:`.light`, :mod:`.camera`,
:mod:`.texture`, the task side :mod:`.pipeline`, and one package per figure
(:mod:`.splats`, :mod:`.flowvol`, :mod:`.muscle`).  The main entry points are attributes of
this package, imported on first use so that ``import nephele.core.errors`` stays cheap.
"""

import importlib
import warnings

# Former flat module name -> its module in the domain layout; deprecated, removed in 0.2.
_FORMER = {
    "grid": "climate.grid", "dataset": "climate.dataset", "readers": "climate.readers",
    "netcdf": "climate.netcdf", "grads": "climate.grads", "grib": "climate.grib",
    "zarrstore": "climate.zarrstore", "gridfile": "climate.gridfile", "synthetic": "climate.synthetic",
    "humidity": "climate.humidity", "relief": "climate.relief",
    "contour": "surface.contour", "mesh": "surface.mesh", "contour_task": "surface.contour_task",
    "volume_atlas": "volume.volume_atlas", "exact_ray": "volume.exact_ray",
    "transfer": "volume.transfer", "cloud_density": "volume.cloud_density",
    "advect": "flow.advect", "flows": "flow.flows",
    "scatter": "light.scatter", "phase": "light.phase",
    "dome": "camera.dome",
    "noise": "texture.noise", "fractal": "texture.fractal",
    "tasks": "pipeline.tasks", "cache": "pipeline.cache", "codehash": "pipeline.codehash",
}

# Main entry point -> the module defining it.
_ENTRY_POINTS = {
    "DataError": "errors",
    "GlobeGrid": "climate.grid", "open_dataset": "climate.readers", "demo_dataset": "climate.synthetic",
    "isosurface": "surface.contour", "Mesh": "surface.mesh",
    "resample": "volume.sparse", "SparseVolume": "volume.sparse", "exact_volume": "volume.volume_atlas",
    "TransferFunction": "volume.transfer",
    "WindField": "flow.advect", "trace": "flow.advect",
    "solve": "light.scatter",
    "dome_camera": "camera.dome", "remap": "camera.dome",
    "Cache": "pipeline.cache", "run_cached": "pipeline.tasks", "plan": "pipeline.tasks",
    # One package per figure.
    "splat_kernel": "splats", "footprint_table": "splats", "streak_maps": "splats", "Splats": "splats",
    "splat_samples": "splats", "render_splats": "splats", "Camera": "splats",
    "flow_volume": "flowvol", "FlowVolume": "flowvol",
    "blobby_surface": "muscle.blobby",
}

__all__ = sorted(_ENTRY_POINTS)


def __getattr__(name):
    if name in _ENTRY_POINTS:
        return getattr(importlib.import_module(f".{_ENTRY_POINTS[name]}", __name__), name)
    if name in _FORMER:
        warnings.warn(f"nephele.core.{name} is deprecated and ends in Nephele 0.2: "
                      f"use nephele.core.{_FORMER[name]}", DeprecationWarning, stacklevel=2)
        return importlib.import_module(f".{_FORMER[name]}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_ENTRY_POINTS))
