"""The per-frame contour-surface task: a dataset, a time and a level in, a mesh out.

A contour object in Blender stores its parameters (see
:func:`nephele.addon.frame.set_params`); for every frame :func:`task_params`
turns them into the exact inputs of one mesh (the model time interpolated
between hourly steps), and the task ``"contour"`` computes it — in Blender
through :func:`nephele.core.pipeline.tasks.run_cached`, or ahead of time on the farm.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (Fig. 1: contour surfaces of 15% cloudiness).
"""

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION
from ..errors import DataError
from ..pipeline.cache import source_stamp
from ..pipeline.registry import planner, task
from ..pipeline.sources import frame_hours, open_source

ALTITUDE = "altitude"
"""Name of the per-vertex height attribute (metres above sea level) every contour mesh carries."""

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
        :meth:`nephele.core.surface.mesh.Mesh.to_arrays` of the surface: vertices in
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
