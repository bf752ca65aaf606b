"""Flow: analytic and gridded winds, trajectories and the advection strategies."""

from .advect import (  # noqa: F401
    COPIES,
    START,
    START_ALT,
    STRATEGIES,
    WEIGHT,
    AnalyticWind,
    ComposedTrace,
    Copy,
    FullTrace,
    RestartTrace,
    WindField,
    active_vertices,
    dilate,
    great_circle_km,
    grid_vertices,
    start_coordinates,
    steps_to_keep,
    trace,
    vertex_levels,
)
from .advect_task import (  # noqa: F401
    ADVECT_DEFAULTS,
    advect_task_params,
)
from .flows import (  # noqa: F401
    DeformationalFlow,
    FlowDataset,
    SolidBodyRotation,
    rotate,
    sample_grid,
    tangent_velocity,
)
