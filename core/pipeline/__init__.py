"""Pipeline: the table of object kinds, the task registry, the on-disk cache and the code stamps that key it."""

from .cache import CACHE_VERSION, Cache, cache_key, canonical, default_cache_dir, source_stamp
from .codehash import dependencies
from .kinds import KINDS, TASK_MODULES, ObjectKind
from .registry import PLANNERS, TASKS, code_stamp, planner, task
from .sources import frame_hours, open_source, open_with_overrides, register_source
from .tasks import load_all, plan, run, run_cached

__all__ = ["CACHE_VERSION", "KINDS", "PLANNERS", "TASKS", "TASK_MODULES", "Cache", "ObjectKind", "cache_key",
           "canonical", "code_stamp", "default_cache_dir", "dependencies", "frame_hours", "load_all",
           "open_source", "open_with_overrides", "plan", "planner", "register_source", "run", "run_cached",
           "source_stamp", "task"]
