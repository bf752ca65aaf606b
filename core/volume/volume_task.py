"""The per-frame volume task: a dataset, a time and a transfer function in, a sparse volume out.

A volume object in Blender stores its parameters; :func:`frame_params` turns
them into the exact inputs of one frame's volume, and the task ``"volume"``
computes it (:func:`~.sparse.resample`, or :func:`~.volume_atlas.exact_volume`
in exact mode), in Blender through :func:`nephele.core.pipeline.tasks.run_cached`
or ahead of time on the farm.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION
from ..errors import DataError
from ..pipeline.cache import source_stamp
from ..pipeline.registry import planner, task
from ..pipeline.sources import frame_hours, open_source
from .sparse import ALTITUDE, DEFAULT_VOXEL_SIZE, EXACT, VOXELS, resample
from .transfer import TransferFunction
from .volume_atlas import DEFAULT_BELOW, DEFAULT_SUPPORT_SIZE, exact_volume


def frame_params(obj_params, frame):
    """The inputs of the volume an object with ``obj_params`` shows at ``frame``.

    ``obj_params`` keys: ``source``, ``var``, ``tf`` (a
    :meth:`TransferFunction.to_dict`), optionally ``color_var`` (a field
    name, ``"altitude"`` or ``""`` for none), ``mode`` (:data:`VOXELS`, the
    default, with ``voxel_size``; or :data:`EXACT`, with ``support_size`` and
    ``below``, see :mod:`nephele.core.volume.volume_atlas`), ``exaggeration``,
    ``radius``, ``frame_start``, ``hours_per_frame``.
    The model time is interpolated linearly between steps and clamped to the
    data; it is rounded to 1e-6 h so equal frames share a cache entry.
    """
    missing = [k for k in ("source", "var", "tf") if k not in obj_params]
    if missing:
        raise DataError(f"volume parameters lack {missing}", field="volume")
    source = str(obj_params["source"])
    ds = open_source(source)
    hours = frame_hours(frame, obj_params.get("frame_start", 1), obj_params.get("hours_per_frame", 1.0),
                        last_hour=float(ds.hours[-1]))
    out = {
        "source": source,
        "stamp": source_stamp(source),
        "var": str(obj_params["var"]),
        "hours": round(hours, 6),
        "tf": TransferFunction.from_dict(obj_params["tf"]).to_dict(),
        "color_var": str(obj_params.get("color_var", ALTITUDE) or ""),
        "exaggeration": float(obj_params.get("exaggeration", DEFAULT_EXAGGERATION)),
        "radius": float(obj_params.get("radius", 1.0)),
    }
    mode = str(obj_params.get("mode", VOXELS))
    if mode == EXACT:
        out["mode"] = EXACT
        out["support_size"] = float(obj_params.get("support_size", DEFAULT_SUPPORT_SIZE))
        out["below"] = float(obj_params.get("below", DEFAULT_BELOW))
    elif mode == VOXELS:
        out["voxel_size"] = float(obj_params.get("voxel_size", DEFAULT_VOXEL_SIZE))
    else:
        raise DataError(f'must be "{EXACT}" or "{VOXELS}", got {mode!r}', field="mode")
    return out


@task("volume")
def _volume_task(params):
    """Task ``"volume"``: :func:`resample` of one model time (params from
    :func:`frame_params`).  Arrays of :meth:`SparseVolume.arrays` plus
    ``value_max``, the largest finite value of the field at that time."""
    ds = open_source(params["source"])
    values = ds.read_at(params["var"], params["hours"])
    color_var = params.get("color_var") or None
    color_values = None if color_var in (None, ALTITUDE) else ds.read_at(color_var, params["hours"])
    finite = values[np.isfinite(values)]
    value_max = np.float64(finite.max() if finite.size else np.nan)
    if params.get("mode") == EXACT:
        ev = exact_volume(
            ds.grid, values, TransferFunction.from_dict(params["tf"]), support_size=params["support_size"],
            color_values=color_values, color_name=color_var, radius=params["radius"],
            exaggeration=params["exaggeration"], below=params["below"],
        )
        return dict(ev.arrays(), value_max=value_max)
    vol = resample(
        ds.grid, values, TransferFunction.from_dict(params["tf"]), voxel_size=params["voxel_size"],
        color_values=color_values, color_name=color_var, radius=params["radius"],
        exaggeration=params["exaggeration"],
    )
    return dict(vol.arrays(), value_max=value_max)


@planner("volume")
def plan_volume(obj_params, frame):
    """Planner ``"volume"``: the one ``("volume", params)`` task a volume object
    needs at ``frame`` (none outside its baked frame range ``frames``, where
    the sequence holds its end files)."""
    frames = obj_params.get("frames")
    if frames and not int(frames[0]) <= int(frame) <= int(frames[1]):
        return []
    return [("volume", frame_params(obj_params, frame))]


__all__ = ["frame_params", "plan_volume"]
