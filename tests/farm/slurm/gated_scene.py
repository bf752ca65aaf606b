"""The farm's cube test scene, slow only while a gate file exists.

A test holds a job's frames slow (``slow`` seconds in each frame-change
handler call) until the fault it is waiting for has happened, removes the
file, and the rest of the sequence renders at full speed: the test does not
pay for the worst case of an event whose time it cannot choose.
"""

import importlib.util
import os
import time
from pathlib import Path

import bpy

_CUBE = Path(__file__).resolve().parents[1] / "cube_scene.py"


def build(gate, slow=0.3, **cube_options):
    spec = importlib.util.spec_from_file_location("nephele_test_cube_scene", _CUBE)
    cube = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cube)
    cube.build(**cube_options)

    def hold(scene, depsgraph=None):
        if os.path.exists(gate):
            time.sleep(slow)

    bpy.app.handlers.frame_change_pre.append(hold)
