"""Textures: solid noise and the poor-man's fractal."""

from .fractal import (  # noqa: F401
    Fractal,
    blend,
    terms,
    texture,
    texture_xyz,
)
from .noise import (  # noqa: F401
    improved_noise,
    turbulence,
)
