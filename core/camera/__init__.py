"""Cameras: the dome (fisheye, cube-map) projections and red-cyan anaglyphs of stereo pairs."""

from .anaglyph import red_cyan  # noqa: F401
from .dome import (  # noqa: F401
    CUBE_AXES,
    CUBE_FACES,
    LENSES,
    OMNIMAX_FILM_MM,
    PRESET_DEFAULTS,
    PRESETS,
    SOURCES,
    DomeCamera,
    RemapTable,
    cube_to_direction,
    direction_to_cube,
    direction_to_equirect,
    dome_camera,
    remap,
    remap_table,
    stereo_eyes,
    stored_remap_table,
)
