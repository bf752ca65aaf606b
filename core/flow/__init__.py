"""Flow: analytic and gridded winds, trajectories and the advection strategies."""

from .advect import (  # noqa: F401
    ADVECT_DEFAULTS,
    AnalyticWind,
    ComposedTrace,
    Copy,
    FullTrace,
    RestartTrace,
    STRATEGIES,
    WindField,
    active_vertices,
    advect_task_params,
    dilate,
    great_circle_km,
    grid_vertices,
    start_coordinates,
    steps_to_keep,
    trace,
    vertex_levels,
)
from .flows import (  # noqa: F401
    DeformationalFlow,
    FlowDataset,
    SolidBodyRotation,
    rotate,
    sample_grid,
    tangent_velocity,
)
