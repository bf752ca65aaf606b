"""The per-frame advected-contour task: a contour mesh carrying the texture's start coordinates.

An advected contour object stores its contour's parameters plus the strategy
settings (:data:`ADVECT_DEFAULTS`); :func:`advect_task_params` makes one
frame's inputs and the task ``"advect_contour"`` traces the contour's grid
vertices back with the strategy (:mod:`.advect`), kept per process so that
frames rendered in order stream.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 4.
"""

from collections import OrderedDict

import numpy as np

from ..errors import DataError
from ..pipeline.registry import planner, task
from ..pipeline.sources import open_source
from ..surface.contour import isosurface
from ..surface.contour_task import ALTITUDE, task_params
from .advect import (
    COPIES,
    DEFAULT_BAND,
    START,
    START_ALT,
    STRATEGIES,
    WEIGHT,
    ComposedTrace,
    Copy,
    FullTrace,
    RestartTrace,
    WindField,
    active_vertices,
    steps_to_keep,
)

ADVECT_DEFAULTS = {"strategy": "restart", "period": 24, "integrator": "rk4", "order": 3, "band": DEFAULT_BAND,
                   "nan": "error", "vertical": "auto", "cfl": 2.0}
"""Texture-advection settings an advected contour object stores (besides its contour's).

``cfl`` 2 (RK4 steps up to two grid spacings) halves the tracing of
:func:`trace`'s default 1 at no measured cost on the demo (restart copies over
24 frames, levels kept: 0.045 vs 0.044 km rms, 3.94 km max either way; see
benchmarks/bench_advect.py).  Each process keeps at most two winds, each with
:func:`steps_to_keep` steps (about 420 MB on the demo for 24 hourly frames).
"""

_WINDS = OrderedDict()
_STRATEGIES = OrderedDict()


def advect_task_params(obj_params, frame):
    """The inputs of the advected contour an object with ``obj_params`` shows at ``frame``.

    The contour's own parameters (see :func:`nephele.core.surface.contour_task.task_params`)
    plus the strategy settings (:data:`ADVECT_DEFAULTS`) and the frame index ``n``
    counted from the texture's start (the first frame, model time 0).
    """
    tp = task_params(obj_params, frame)
    hpf = float(obj_params.get("hours_per_frame", 1.0))
    tp.update({k: obj_params.get(k, v) for k, v in ADVECT_DEFAULTS.items()})
    tp["hours_per_frame"] = hpf
    tp["frame"] = int(round(tp["hours"] / hpf))
    if tp["strategy"] not in STRATEGIES:
        raise DataError(f"unknown strategy {tp['strategy']!r} (known: {', '.join(STRATEGIES)})", field="strategy")
    return tp


def _strategy(params, ds):
    key = (params["stamp"], params["strategy"], params["period"], params["integrator"], params["order"], params["band"],
           params["hours_per_frame"], params["nan"], params["vertical"], params["cfl"])
    hit = _STRATEGIES.get(key)
    if hit is not None:  # kept per process, so frames rendered in order stream
        _STRATEGIES.move_to_end(key)
        return hit
    wkey = (params["stamp"], params["nan"], params["vertical"])
    wind = _WINDS.get(wkey)
    keep = steps_to_keep(ds.grid, float(params["period"]) * params["hours_per_frame"])
    if wind is None:
        wind = _WINDS[wkey] = WindField(ds, nan=params["nan"], vertical=params["vertical"], cache_steps=keep)
        while len(_WINDS) > 2:
            _WINDS.popitem(last=False)
    wind._cache_steps = max(wind._cache_steps, keep)  # a longer period sharing this wind
    last = float(ds.hours[-1])
    fh = np.arange(int(np.floor(last / params["hours_per_frame"] + 1e-9)) + 1) * params["hours_per_frame"]
    opts = dict(method=params["integrator"], cfl=float(params["cfl"]))
    name = params["strategy"]
    if name == "restart":
        st = RestartTrace(wind, fh, ds.grid, period=int(params["period"]), order=int(params["order"]),
                          band=params["band"], **opts)
    elif name == "compose":
        st = ComposedTrace(wind, fh, ds.grid, order=int(params["order"]), band=params["band"], **opts)
    else:
        st = FullTrace(wind, fh, ds.grid, **opts)
    _STRATEGIES[key] = st
    while len(_STRATEGIES) > 2:
        _STRATEGIES.popitem(last=False)
    return st


@planner("advected_contour")
def plan_advected(obj_params, frame):
    """The one ``("advect_contour", params)`` task an advected contour needs at ``frame``."""
    return [("advect_contour", advect_task_params(obj_params, frame))]

@task("advect_contour")
def advect_contour(params):
    """Contour mesh of one frame with the texture start coordinates of its vertices.

    The strategy traces the vertices of the cells holding the contour; their
    start coordinates are passed to the contour as grid attributes, so every
    mesh vertex gets them interpolated with the contour's own edge weights [1]_.

    Returns
    -------
    dict of ndarray
        :meth:`nephele.core.surface.mesh.Mesh.to_arrays` with attributes ``altitude``,
        the colour variable, and per copy ``a``/``b``: :data:`START`,
        :data:`START_ALT` and :data:`WEIGHT`.
    """
    ds = open_source(params["source"])
    var, level = params["var"], float(params["level"])
    if var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", path=ds.source, field=var)
    values = ds.read_at(var, params["hours"])
    st = _strategy(params, ds)
    n = min(int(params["frame"]), st.frame_hours.size - 1)
    index = active_vertices(values, level, ds.grid.periodic_lon)
    copies = st.copies(n, index) if index.size else [Copy(np.zeros((0, 3)), np.zeros(0), 1.0, 0.0)]
    if len(copies) == 1:
        copies = copies + [Copy(copies[0].xyz, copies[0].s, 0.0, copies[0].start_hours)]
    attrs = {ALTITUDE: ds.grid.height.astype(np.float32)}
    color_var = params.get("color_var") or ALTITUDE
    if color_var != ALTITUDE:
        attrs[color_var] = ds.read_at(color_var, params["hours"])
    wind = st.wind
    rot = ds.grid.rotation
    for name, cp in zip(COPIES, copies):
        alt = wind.start_height(cp.xyz, cp.s) if len(cp.s) else np.zeros(0)
        # traced in a rotated grid's frame; the mesh is on the true globe
        xyz = cp.xyz if rot is None else cp.xyz @ rot.T
        for c, vals in enumerate((xyz[:, 0], xyz[:, 1], xyz[:, 2], alt)):
            f = np.zeros(ds.grid.shape, dtype=np.float32)
            f.reshape(-1)[index] = vals
            attrs[f"_{name}{c}"] = f
    points = ds.grid.points(radius=params["radius"], exaggeration=params["exaggeration"])
    mesh = isosurface(points, values, level, periodic_lon=ds.grid.periodic_lon, method=params.get("method", "cubes"),
                      attributes=attrs)
    nv = len(mesh.vertices)
    for name, cp in zip(COPIES, copies):
        a = [mesh.attributes.pop(f"_{name}{c}", np.zeros(nv, np.float32)) for c in range(4)]
        mesh.attributes[START.format(name)] = np.stack(a[:3], axis=1).astype(np.float32)
        mesh.attributes[START_ALT.format(name)] = np.asarray(a[3], dtype=np.float32)
        mesh.attributes[WEIGHT.format(name)] = np.full(nv, cp.weight, dtype=np.float32)
    return mesh.to_arrays()


__all__ = ["ADVECT_DEFAULTS", "advect_task_params"]
