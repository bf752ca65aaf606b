"""Surfaces: isosurfaces by marching cubes, triangle meshes and the contour task."""

from .contour import (  # noqa: F401
    EDGE_MARGIN,
    METHODS,
    POLE_RING,
    isosurface,
    regular_points,
)
from .contour_task import (  # noqa: F401
    ALTITUDE,
    contour_mesh,
    plan_contour,
    task_params,
)
from .mesh import (  # noqa: F401
    EXPORT_FORMATS,
    Mesh,
    triangle_areas,
    vertex_normals,
)
