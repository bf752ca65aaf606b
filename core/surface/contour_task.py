"""The per-frame contour-surface task: a dataset, a time and a level in, a mesh out.

A contour object in Blender stores its parameters (see
:func:`nephele.addon.frame.set_params`); for every frame :func:`task_params`
turns them into the exact inputs of one mesh (the model time interpolated
between hourly steps), and the task ``"contour"`` computes it — in Blender
through :func:`nephele.core.tasks.run_cached`, or ahead of time on the farm.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (Fig. 1: contour surfaces of 15% cloudiness).
"""

import hashlib
from collections import OrderedDict
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..pipeline.cache import source_stamp
from ..errors import DataError
from ..climate.grid import DEFAULT_EXAGGERATION
from ..pipeline.tasks import planner, task

ALTITUDE = "altitude"
"""Name of the per-vertex height attribute (metres above sea level) every contour mesh carries."""

_OPEN = OrderedDict()
_OPEN_MAX = 3
_MEMORY = {}


def register_source(name, dataset):
    """Make an in-memory :class:`~nephele.core.dataset.Dataset` available as source ``name``.

    For data built in a session (and tests); such a source exists only in
    this process, so the farm cannot precompute it.
    """
    _MEMORY[str(name)] = dataset
    return str(name)


def open_source(source):
    """Open the dataset ``source`` ("demo", "demo:small", a .nc or .ctl path), once per process.

    Datasets read lazily and keep only a few steps, so holding the last few
    open is cheap; a file changed on disk is opened again.
    """
    source = str(source)
    if source in _MEMORY:
        return _MEMORY[source]
    from ..climate.readers import open_dataset

    stamp = source_stamp(source)
    hit = _OPEN.get(source)
    if hit is not None and hit[0] == stamp:
        _OPEN.move_to_end(source)
        return hit[1]
    ds = open_dataset(source)
    _OPEN[source] = (stamp, ds)
    while len(_OPEN) > _OPEN_MAX:
        _OPEN.popitem(last=False)
    return ds


@lru_cache(maxsize=1)
def code_stamp():
    """Short hash of the contouring code, part of every cache key: a changed
    algorithm never serves meshes cached by the old one."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in ("contour.py", "_mc_tables.py", "mesh.py", "contour_task.py"):
        p = here / name
        h.update(p.read_bytes() if p.is_file() else name.encode())
    return h.hexdigest()[:16]


def frame_hours(frame, frame_start=1, hours_per_frame=1.0, last_hour=None):
    """Model time (hours since the first step) shown at ``frame``, clamped to ``[0, last_hour]``."""
    if not hours_per_frame > 0:
        raise ValueError(f"hours_per_frame must be > 0, got {hours_per_frame}")
    hours = (float(frame) - float(frame_start)) * float(hours_per_frame)
    hours = max(hours, 0.0)
    if last_hour is not None:
        hours = min(hours, float(last_hour))
    return hours


def task_params(obj_params, frame):
    """The inputs of the contour mesh that an object with ``obj_params`` shows at ``frame``.

    ``obj_params`` keys: ``source``, ``var``, ``level``, and optionally
    ``exaggeration``, ``radius``, ``color_var``, ``method``,
    ``hours_per_frame``, ``frame_start``.  Times are rounded to 1e-6 h so
    equal frames share a cache entry.
    """
    missing = [k for k in ("source", "var", "level") if k not in obj_params]
    if missing:
        raise DataError(f"contour parameters lack {missing}", field="contour")
    source = str(obj_params["source"])
    ds = open_source(source)
    hours = frame_hours(frame, obj_params.get("frame_start", 1), obj_params.get("hours_per_frame", 1.0),
                        last_hour=float(ds.hours[-1]))
    color_var = obj_params.get("color_var") or ALTITUDE
    return {
        "source": source,
        "stamp": source_stamp(source),
        "var": str(obj_params["var"]),
        "level": float(obj_params["level"]),
        "hours": round(hours, 6),
        "exaggeration": float(obj_params.get("exaggeration", DEFAULT_EXAGGERATION)),
        "radius": float(obj_params.get("radius", 1.0)),
        "color_var": str(color_var),
        "method": str(obj_params.get("method", "cubes")),
        "code": code_stamp(),
    }


@planner("contour")
def plan_contour(obj_params, frame):
    """The one ``("contour", params)`` task a contour object needs at ``frame``."""
    return [("contour", task_params(obj_params, frame))]


@task("contour")
def contour_mesh(params):
    """Contour surface of ``params["var"]`` at ``params["level"]`` and model time ``params["hours"]``.

    Parameters
    ----------
    params : dict
        As made by :func:`task_params`.

    Returns
    -------
    dict of ndarray
        :meth:`nephele.core.mesh.Mesh.to_arrays` of the surface: vertices in
        scene units, attributes ``altitude`` (metres) and, when ``color_var``
        names a field, that field.
    """
    from .contour import isosurface

    ds = open_source(params["source"])
    var = params["var"]
    if var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", path=ds.source, field=var)
    level = float(params["level"])
    if not np.isfinite(level):
        raise DataError(f"contour level {level} is not finite", path=ds.source, field=var)
    values = ds.read_at(var, params["hours"])
    points = ds.grid.points(radius=params["radius"], exaggeration=params["exaggeration"])
    attributes = {ALTITUDE: ds.grid.height.astype(np.float32)}
    color_var = params.get("color_var") or ALTITUDE
    if color_var != ALTITUDE:
        if color_var not in ds:
            raise DataError("colour variable not in the dataset", path=ds.source, field=color_var)
        attributes[color_var] = ds.read_at(color_var, params["hours"])
    # Global grids with cell-centred latitudes get the poles added, so clouds
    # over a pole are closed instead of keeping a hole the size of the polar cap.
    periodic = ds.grid.periodic_lon
    mesh = isosurface(points, values, level, periodic_lon=periodic, method=params.get("method", "cubes"),
                      attributes=attributes, close_poles=periodic)
    return mesh.to_arrays()
