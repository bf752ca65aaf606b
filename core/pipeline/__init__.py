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
    open_with_overrides,
    register_source,
)
from .registry import (  # noqa: F401
    PLANNERS,
    TASKS,
    TASK_MODULES,
    code_stamp,
    load_all,
    planner,
    task,
)
from .tasks import (  # noqa: F401
    plan,
    run,
    run_cached,
)
