"""Nephele: scientific fields (clouds, winds, smoke, molecules) into films.

This file is both the Python package ``nephele`` and the Blender extension's
entry point.  It must stay importable without Blender: ``bpy`` is imported
only inside :func:`register`, so ``import nephele.core`` works in plain Python.
"""

__version__ = "0.1.0"


def register():
    from .addon import register as _register

    _register()


def unregister():
    from .addon import unregister as _unregister

    _unregister()
