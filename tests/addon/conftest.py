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


def render_small(path, scene=None, engine="CYCLES", size=(64, 48), samples=4):
    """Render ``scene`` (default: current) to ``path`` at a tiny size; returns the path."""
    scene = scene or bpy.context.scene
    scene.render.engine = engine
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    if engine == "CYCLES":
        scene.cycles.samples = samples
        scene.cycles.device = "CPU"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return path
