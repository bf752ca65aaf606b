"""Blender tests: bpy imported once per process, the scene reset before each test."""

import pytest

bpy = pytest.importorskip("bpy")


@pytest.fixture(autouse=True)
def empty_scene():
    """A factory-fresh empty scene with the Nephele add-on's classes registered."""
    import nephele

    bpy.ops.wm.read_factory_settings(use_empty=True)
    nephele.register()
    yield bpy.context.scene
    nephele.unregister()
