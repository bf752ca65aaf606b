"""The one table of object kinds: what a scene object of each kind needs per frame, and who shows it.

A Nephele object in Blender stores its parameters with a ``kind``
(``obj["nephele"]``, see :mod:`nephele.addon.frame`).  For each kind the table
names the core module whose planner turns those parameters into per-frame
tasks (:func:`.tasks.plan`: the farm precomputes them, the add-on's updaters
load or compute them through the cache), the task kinds that planner returns,
and the add-on module whose frame updater shows the result.  Both sides read
this table: :func:`.tasks.plan` refuses a task kind the table does not list,
and :func:`nephele.addon.frame.register_updater` an updater the table does
not place.  A kind computed only inside Blender has no tasks; a kind with no
updater is shown from files or the cache by Blender itself.
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class ObjectKind:
    """One row of :data:`KINDS`."""

    tasks: tuple = ()
    """Task kinds its planner returns (registered with ``@task``)."""
    module: str = ""
    """Core module, under ``nephele.core``, registering its planner and tasks ("" without tasks)."""
    updater: str = ""
    """Add-on module, under ``nephele.addon``, registering its frame updater ("" for none)."""


KINDS = {
    "contour": ObjectKind(("contour",), "surface.contour_task", "contour_ops"),
    "advected_contour": ObjectKind(("advect_contour",), "flow.advect_task", "advect_ops"),
    "volume": ObjectKind(("volume",), "volume.volume_task", "volume_ops"),
    "scatter": ObjectKind(("scatter",), "light.scatter_task", "scatter_jobs"),
    "muscle": ObjectKind(("muscle_frame",), "muscle.film", "muscle_ops"),
    "flowvol": ObjectKind(updater="flowvol_ops"),
    "splats": ObjectKind(updater="splat_ops"),
    "dome": ObjectKind(),
    "annotations": ObjectKind(updater="annotate_ops"),
}
"""Object kind -> :class:`ObjectKind` (task kinds, core module, add-on updater)."""

TASK_MODULES = tuple(dict.fromkeys(k.module for k in KINDS.values() if k.module))
"""The core modules that register tasks and planners (imported by :func:`.tasks.load_all`)."""


__all__ = ["KINDS", "ObjectKind", "TASK_MODULES"]
