"""Objects that follow the frame, with or without the add-on installed.

An animated Nephele object stores what it needs in its ID properties under
``obj["nephele"]`` (a JSON string: ``{"kind": ..., ...}``), so a saved .blend
carries everything.  A ``frame_change_pre`` handler calls the updater
registered for each kind.  The add-on installs the handler on register; the
farm (and any headless script) calls :func:`install` after opening a .blend,
so renders need only the ``nephele`` package on ``sys.path``.
"""

import json

import bpy
from bpy.app.handlers import persistent

UPDATERS = {}
"""``kind -> fn(obj, params: dict, scene, frame: float)``."""


def register_updater(kind):
    """Decorator: ``@register_updater("contour")`` on ``fn(obj, params, scene, frame)``."""

    def deco(fn):
        UPDATERS[kind] = fn
        return fn

    return deco


def params(obj):
    """The Nephele parameters stored on ``obj`` (empty dict if none)."""
    raw = obj.get("nephele")
    return json.loads(raw) if raw else {}


def set_params(obj, value):
    obj["nephele"] = json.dumps(value, sort_keys=True)


def _load_updaters():
    # Importing the feature modules (the one list, addon.MODULES) registers their updaters.
    from . import _modules

    _modules()


def update_scene(scene, frame=None):
    """Bring every Nephele object of ``scene`` to ``frame`` (default: the current frame)."""
    frame = scene.frame_current + scene.frame_subframe if frame is None else frame
    for obj in scene.objects:
        p = params(obj)
        fn = UPDATERS.get(p.get("kind"))
        if fn is not None:
            fn(obj, p, scene, frame)


@persistent
def _on_frame_change(scene, depsgraph=None):
    update_scene(scene)


def install():
    """Add the frame handler once (idempotent) and load the updaters."""
    _load_updaters()
    handlers = bpy.app.handlers.frame_change_pre
    if not any(getattr(h, "__name__", "") == _on_frame_change.__name__ for h in handlers):
        handlers.append(_on_frame_change)


def uninstall():
    handlers = bpy.app.handlers.frame_change_pre
    for h in [h for h in handlers if getattr(h, "__name__", "") == _on_frame_change.__name__]:
        handlers.remove(h)
