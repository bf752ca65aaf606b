"""The scattering task: one cloud solved once, for the farm and Blender's cache alike."""

import json
from dataclasses import asdict

import numpy as np

from ..errors import DataError
from ..memory import check_memory
from ..pipeline.registry import planner, task
from ..volume import cloud_density as cd
from .phase import N_PER_FACE
from .scatter import json_plain, solution_arrays, solve

_SOLVE_KEYS = ("albedo", "g", "sun_dir", "sun_irradiance", "sky_radiance", "tol", "max_passes", "bins_per_face")


def task_params(cloud, extinction=40.0, **solve):
    """JSON parameters of the ``"scatter"`` task: a cloud (:class:`.cloud_density.CloudParams`),
    its extinction per unit density and :func:`solve` keywords (``_SOLVE_KEYS``; a per-bin
    ``sky_radiance`` array becomes a list of its ``6 n^2`` values, so the cache key holds them
    all; the default ``bins_per_face`` and ``noise_offset`` are left out, so default solves keep
    their earlier keys)."""
    bad = sorted(set(solve) - set(_SOLVE_KEYS))
    if bad:
        raise DataError(f"unknown scattering parameters {bad}", field="scatter")
    if solve.get("bins_per_face", N_PER_FACE) == N_PER_FACE:
        solve = {k: v for k, v in solve.items() if k != "bins_per_face"}
    c = asdict(cloud)
    if not any(c.get("noise_offset", ())):  # (the default: earlier solves keep their keys)
        c.pop("noise_offset", None)
    return json.loads(json.dumps({"cloud": c, "extinction": float(extinction), "solve": solve}, default=json_plain))


def task_grid(params):
    """The extinction grid and box size of :func:`task_params`' cloud."""
    c = dict(params["cloud"])
    c["ellipsoids"] = tuple(cd.Ellipsoid(tuple(e["center"]), tuple(e["radii"]), float(e["weight"]))
                            for e in c.get("ellipsoids", ()))
    for k in ("shape", "size", "noise_offset"):
        if k in c:
            c[k] = tuple(c[k])
    return float(params["extinction"]) * cd.cloud_density(cd.CloudParams(**c)), c["size"]


SOLVE_BYTES_PER_CELL = 8000.0
"""Peak memory of the scattering solve per grid cell at 4x4 bins per cube face (tracemalloc: 7.6 kB; the
add-on's :data:`~nephele.addon.scatter_ops.BYTES_PER_CELL`); it grows with the bins, as (bins_per_face/4)^2."""


def check_solve_memory(shape, bins_per_face=N_PER_FACE):
    """Refuse (:class:`DataError`) a solve on grid ``shape`` that would not fit in memory.

    The solver itself (:mod:`.scatter`) stays free of this check: its callers (this task, ``nephele
    scatter``, the add-on's operator) make it before anything is allocated.
    """
    cells = int(np.prod(shape))
    check_memory(SOLVE_BYTES_PER_CELL * (bins_per_face / 4) ** 2 * cells,
                 f"the scattering solve on a {'x'.join(str(n) for n in shape[::-1])} grid",
                 hint="lower the grid or the bins per face", field="grid")


@task("scatter")
def solve_task(params):
    """The ``"scatter"`` task: build the cloud of :func:`task_params` and solve it;
    returns :func:`solution_arrays` (:func:`solution_from_arrays` reads them back)."""
    sigma, size = task_grid(params)
    check_solve_memory(params["cloud"]["shape"], params["solve"].get("bins_per_face", N_PER_FACE))
    return solution_arrays(solve(sigma, size, **params["solve"]))


@planner("scatter")
def plan_solve(obj_params, frame):
    """A scattering cloud object needs its one solve (the same task for every frame)."""
    return [("scatter", obj_params["solve_task"])] if "solve_task" in obj_params else []


__all__ = ["plan_solve", "solve_task", "task_grid", "task_params"]
