"""Pipeline: the task registry, the on-disk cache and the code stamps that key it."""

from .cache import (  # noqa: F401
    CACHE_VERSION,
    Cache,
    cache_key,
    canonical,
    default_cache_dir,
    source_stamp,
)
from .codehash import (  # noqa: F401
    dependencies,
)
from .sources import (  # noqa: F401
    frame_hours,
    open_source,
    register_source,
)
from .tasks import (  # noqa: F401
    PLANNERS,
    TASKS,
    TASK_MODULES,
    load_all,
    plan,
    planner,
    run,
    run_cached,
    task,
)
