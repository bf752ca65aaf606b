"""The Blender side of Nephele: the only package that imports ``bpy``.

Each feature module exports ``CLASSES`` (registered in order) and may export
``SCENE_PROPERTIES``, a dict ``{attribute name: PropertyGroup class}``
attached to ``bpy.types.Scene`` as pointer properties.  Panels are sub-panels
of the "Nephele" sidebar tab defined in :mod:`.panel`.
"""

import importlib

# Order matters: the main panel first, then the features' sub-panels.
MODULES = (
    "panel",
    "data_ops",
    "layers",
    "contour_ops",
    "globe_ops",
    "volume_ops",
    "volume_panel",
    "volume_bake",
    "advect_ops",
    "scatter_ops",
    "dome_ops",
    "muscle_ops",
    "flowvol_ops",
    "splat_ops",
    "presets",
    "annotate_ops",
)


def _modules():
    # The one list of features on the Blender side: a missing or broken module is an
    # error here, never a silently absent feature.  Importing a module also registers
    # its frame updater (``frame.register_updater``).
    return [importlib.import_module(f".{name}", __name__) for name in MODULES]


def register():
    import bpy

    from . import frame

    for mod in _modules():
        for cls in getattr(mod, "CLASSES", ()):
            bpy.utils.register_class(cls)
        for attr, group in getattr(mod, "SCENE_PROPERTIES", {}).items():
            setattr(bpy.types.Scene, attr, bpy.props.PointerProperty(type=group))
        if hasattr(mod, "install"):
            mod.install()
    frame.install()


def unregister():
    import bpy

    from . import frame

    frame.uninstall()
    for mod in reversed(_modules()):
        if hasattr(mod, "uninstall"):
            mod.uninstall()
        for attr in getattr(mod, "SCENE_PROPERTIES", {}):
            if hasattr(bpy.types.Scene, attr):
                delattr(bpy.types.Scene, attr)
        for cls in reversed(getattr(mod, "CLASSES", ())):
            bpy.utils.unregister_class(cls)
