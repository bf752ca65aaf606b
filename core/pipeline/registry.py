"""The registry of per-frame tasks and planners, and the code stamps that key their cache entries.

A feature registers

* a **task**, ``@task("contour")`` on ``fn(params) -> dict[str, ndarray]``: the
  heavy work for one frame, fully determined by ``params`` (JSON-serialisable);
* optionally a **planner**, ``@planner("contour")`` on
  ``fn(obj_params, frame) -> list[(kind, task_params)]``: given the parameters
  a scene object stores (``obj["nephele"]``, see :mod:`nephele.addon.frame`)
  and a frame number, the tasks that frame needs.

Which module registers what is the table of object kinds, :data:`.kinds.KINDS`.

The cache (:mod:`.cache`) keys entries with :func:`code_stamp`; running tasks
(:mod:`.tasks`) uses both, so neither imports the other's user.  Nothing here
imports a task module (:func:`.tasks.load_all` does): the modules that register
import this one, never the other way round.
"""

import sys
from pathlib import Path

from .codehash import code_stamp as _file_stamp
from .kinds import KINDS

_CORE = Path(__file__).resolve().parent.parent

TASKS = {}
PLANNERS = {}


def task(kind):
    """Decorator registering ``fn(params) -> dict of arrays`` as the task ``kind``."""

    def deco(fn):
        TASKS[kind] = fn
        return fn

    return deco


def code_stamp(kind):
    """Hash of the code task ``kind`` depends on (its module and every core module it
    imports, transitively; :mod:`.codehash`), part of its cache key.

    The module is the one the table of kinds names for ``kind`` (read from disk,
    not imported), else the module of a task registered outside the table (e.g.
    a test's own); ``""`` for a kind nothing registers.
    """
    for row in KINDS.values():
        if kind in row.tasks:
            return _file_stamp(_CORE.joinpath(*row.module.split(".")).with_suffix(".py"))
    mod = sys.modules.get(getattr(TASKS.get(kind), "__module__", None) or "")
    path = getattr(mod, "__file__", None)
    return _file_stamp(path) if path else ""


def planner(kind):
    """Decorator registering ``fn(obj_params, frame) -> [(kind, task_params), ...]`` for objects of ``kind``."""

    def deco(fn):
        PLANNERS[kind] = fn
        return fn

    return deco

