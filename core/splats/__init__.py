"""Splats with a flowing wind texture (Fig. 3): normalised kernels, footprints, streaks, a reference renderer."""

from .camera import Camera
from .cells import cell_jacobians, principal_axes
from .kernel import KINDS, SplatKernel, footprint_table, splat_kernel
from .render import (
    DEFAULT_PREFILTER,
    DEFAULT_STREAK_CONTRAST,
    ScreenSplats,
    default_tile,
    project_splats,
    ray_integral,
    reconstruct,
    render_splats,
    sphere_depth,
    streak_factor,
    streak_offsets,
)
from .samples import ALTITUDE, Splats, splat_samples
from .streaks import streak_maps, streak_orientation, structure_tensor

__all__ = [
    "ALTITUDE",
    "DEFAULT_PREFILTER",
    "DEFAULT_STREAK_CONTRAST",
    "KINDS",
    "Camera",
    "ScreenSplats",
    "SplatKernel",
    "Splats",
    "cell_jacobians",
    "default_tile",
    "footprint_table",
    "principal_axes",
    "project_splats",
    "ray_integral",
    "reconstruct",
    "render_splats",
    "splat_kernel",
    "sphere_depth",
    "splat_samples",
    "streak_factor",
    "streak_maps",
    "streak_offsets",
    "streak_orientation",
    "structure_tensor",
]
