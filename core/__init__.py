"""NumPy-only algorithms of Nephele.  Nothing here imports Blender."""

from .splats import Camera, Splats, footprint_table, render_splats, splat_kernel, splat_samples, streak_maps
