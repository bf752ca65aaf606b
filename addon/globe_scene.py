"""What the globe figures (Figs. 1-5) share: options, the globe scene,
render settings and the command line that saves or renders it headless.

The figures' recipes and their ``*_DEFAULTS`` are in :mod:`.presets` (the
panels' "Make the paper's figure" and the examples both call them); this
module holds the parts that are the same in all of them.
"""

import argparse
from pathlib import Path

import bpy

from ..core.parse import parse_range, parse_size


def merge_options(defaults, options):
    """``defaults`` updated by ``options``; an unknown option is a TypeError naming the known ones."""
    unknown = set(options) - set(defaults)
    if unknown:
        raise TypeError(f"unknown options {sorted(unknown)}; known: {sorted(defaults)}")
    return dict(defaults, **options)


def globe_scene(scene, o, *, sun_direction, haze=True, haze_mode="volume"):
    """Dataset settings, frame range, relief globe, sky/sun/haze; returns ``(globe, sky_dict)``.

    ``o`` holds ``source``, ``hours_per_frame``, ``frames`` and ``exaggeration``
    (None: :data:`nephele.core.climate.grid.DEFAULT_EXAGGERATION`).
    """
    from ..core.climate.grid import DEFAULT_EXAGGERATION
    from . import data_ops, globe_ops

    exaggeration = DEFAULT_EXAGGERATION if o["exaggeration"] is None else float(o["exaggeration"])
    first, last = (int(f) for f in o["frames"])
    data_ops.set_settings(scene, source=o["source"], hours_per_frame=o["hours_per_frame"],
                          frame_start=first, exaggeration=exaggeration, radius=1.0)
    scene.frame_start, scene.frame_end = first, last
    scene.frame_current = first
    globe = globe_ops.add_globe(scene=scene)
    sky = globe_ops.add_sky_and_haze(scene, haze=haze, haze_mode=haze_mode, sun_direction=sun_direction,
                                     sun_strength=4.5)
    return globe, sky


def render_settings(scene, size, samples, engine="CYCLES"):
    """Headless defaults: CPU Cycles with denoising (or ``engine``), ``size`` pixels, PNG, opaque film."""
    render = scene.render
    render.engine = engine
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(samples)
    scene.cycles.use_denoising = True
    render.resolution_x, render.resolution_y = (int(v) for v in size)
    render.resolution_percentage = 100
    render.image_settings.file_format = "PNG"
    render.film_transparent = False


def argument_parser(description, defaults):
    """An ArgumentParser with the options every globe example takes:
    ``--out --save --frames --size --samples --source``."""
    f0, f1 = defaults["frames"]
    w, h = defaults["size"]
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--out", help="render the frames into this directory (frame_####.png)")
    ap.add_argument("--save", help="save the scene to this .blend")
    ap.add_argument("--frames", type=parse_range, default=defaults["frames"], help=f"A-B (default {f0}-{f1})")
    ap.add_argument("--size", type=parse_size, default=defaults["size"], help=f"WxH (default {w}x{h})")
    ap.add_argument("--samples", type=int, default=defaults["samples"])
    ap.add_argument("--source", default=defaults["source"], help='"demo", "demo:small", a .nc or a .ctl')
    ap.add_argument("--annotations", action="store_true",
                    help="lay the caption, the model date and time and a legend over every render")
    return ap


def save(path):
    """Save the current file as ``path`` (folders created)."""
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def render_frames(scene, frames, out):
    """Render frames ``(first, last)`` of ``scene`` to ``out/frame_####.png``; returns the paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for f in range(frames[0], frames[1] + 1):
        scene.frame_set(f)
        scene.render.filepath = str((out / f"frame_{f:04d}.png").resolve())
        bpy.ops.render.render(write_still=True)
        paths.append(scene.render.filepath)
    return paths
