"""The Dask worker side: one long-lived bpy per worker process.

:class:`BlenderScene` is a Dask ``WorkerPlugin`` carrying a run's scene
description.  The first task of a run on a worker opens the .blend (or builds
the example script) in that worker's bpy, installs the frame handler
(:func:`nephele.addon.frame.install`, no add-on needed) and applies the render
overrides; later frames only call ``scene.frame_set(f)`` and render.  Loading
happens in the task thread, the thread that then renders, so bpy is only ever
driven from one thread.

Each frame is rendered to ``OUT/.nephele-tmp/``, decoded with OpenImageIO
(every pixel, expected size) and by :func:`~nephele.farm.frames.check_image`,
fsync'ed, then moved into place with :func:`os.replace`.  A multi-view
(stereo) scene writes one file per view (``frame_0001_L.png``,
``frame_0001_R.png``); all are checked before any is moved.  A scene with a
dome rig (:mod:`nephele.addon.dome_ops`) and an engine without panoramic
cameras (EEVEE, Workbench) is rendered through the cube-map route, since
those engines would silently render the fisheye as a perspective view.  Blender's output
during the frame goes to ``OUT/logs/frame_NNNN.log``.  Python errors that
Blender swallows (a frame handler raising) are caught through
``sys.excepthook`` and fail the frame.  A per-frame timeout kills the worker
process (a Blender render cannot be interrupted from Python), leaving the
stacks of all threads in the frame's log; the nanny restarts the worker and
the client counts the attempt.
"""

import contextlib
import datetime
import faulthandler
import hashlib
import importlib.util
import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path

from distributed import get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from ..addon.render_device import use_device
from ..core.files import fsync_path, replace, write_error
from .frames import FORMATS, TMP_DIR, InvalidFrame, check_image, frame_name, sha256_file

ENGINES = ("CYCLES", "BLENDER_EEVEE", "BLENDER_WORKBENCH")
THREAD_VARS = ("NEPHELE_THREADS", "SLURM_CPUS_PER_TASK", "NCPUS", "PBS_NUM_PPN")
"""Render threads come from the first of these set: ours, Slurm's allocation, PBS Pro's, Torque's."""
_WORKBENCH_AA = ((1, "OFF"), (5, "5"), (8, "8"), (11, "11"), (16, "16"), (32, "32"))

# Which run's scene this process's bpy holds (one bpy per process).
_LOADED = {"token": None}
_LAST_BYTES = {"n": 0}  # the files of this process's last frame, to tell a full disk from a writer's failure


class FrameError(RuntimeError):
    """A frame that rendered wrongly or raised; the message says why."""


class BlenderScene(WorkerPlugin):
    """Worker plugin: the scene of one run, loaded once per worker process.

    Parameters
    ----------
    spec : dict
        JSON-able run description made by :func:`nephele.farm.render.render_sequence`
        (``token``, ``scene``, ``kind``, ``options``, overrides, ``out_dir``,
        ``fmt``, ``timeout``, ``cache_dir``).
    """

    def __init__(self, spec):
        self.spec = spec
        self.name = plugin_name(spec["token"])

    def setup(self, worker):
        self.address = worker.address
        # Ctrl-C reaches the whole process group: the client alone handles it
        # (cancels, closes the cluster, removes temp files); a worker would
        # only die noisily in the middle of a frame.
        with contextlib.suppress(ValueError):  # not the main thread
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    def ensure_loaded(self):
        if _LOADED["token"] != self.spec["token"]:
            load_scene(self.spec)
            _LOADED["token"] = self.spec["token"]
        import bpy

        return bpy.context.scene


def plugin_name(token):
    return f"nephele-scene-{token}"


def _plugin(name):
    return get_worker().plugins[name]


def render_threads():
    """Render threads from the environment (``NEPHELE_THREADS``, Slurm, PBS), or None for Blender's default."""
    for var in THREAD_VARS:
        value = os.environ.get(var, "").strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None


def batch_job():
    """The Slurm or PBS job id this worker runs in, or None."""
    return os.environ.get("SLURM_JOB_ID") or os.environ.get("PBS_JOBID") or None


def _import_script(path):
    name = "nephele_scene_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _import_bpy():
    """Import the bpy module, after dropping Blender script folders a parent process left on sys.path.

    A worker spawned from a process that had imported bpy inherits its
    ``sys.path``, which then starts with Blender's ``scripts/modules``: its
    ``bpy`` package there would shadow the real module.
    """
    if "bpy" not in sys.modules:
        sys.path[:] = [p for p in sys.path if not ("bpy" in Path(p).parts and "scripts" in Path(p).parts)]
    import bpy

    return bpy


def load_scene(spec):
    """Open or build the scene of ``spec`` in this process's bpy and apply the overrides."""
    bpy = _import_bpy()

    if spec.get("cache_dir"):
        # Updaters of a scene built from a script find the cache through this.
        os.environ["NEPHELE_CACHE"] = spec["cache_dir"]
    if spec["kind"] == "blend":
        bpy.ops.wm.open_mainfile(filepath=spec["scene"], load_ui=False)
    else:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        _import_script(spec["scene"]).build(**(spec.get("options") or {}))
    from ..addon import frame

    frame.install()
    scene = bpy.context.scene
    r = scene.render
    if spec.get("engine"):
        r.engine = spec["engine"]
    if spec.get("resolution"):
        r.resolution_x, r.resolution_y = spec["resolution"]
    if spec.get("percentage"):
        r.resolution_percentage = spec["percentage"]
    if spec.get("samples"):
        n = spec["samples"]
        if r.engine == "CYCLES":
            scene.cycles.samples = n
        elif r.engine == "BLENDER_EEVEE":
            scene.eevee.taa_render_samples = n
        else:  # Workbench: the largest anti-aliasing level not above n samples
            scene.display.render_aa = [name for k, name in _WORKBENCH_AA if k <= n][-1]
    if r.engine == "CYCLES":
        use_device(scene, spec.get("device") or "CPU")
        if spec.get("persistent"):
            r.use_persistent_data = True
    elif spec.get("device") not in (None, "CPU"):
        raise FrameError(f"--device {spec['device']} needs the CYCLES engine, the scene uses {r.engine}")
    threads = spec.get("threads") or render_threads()
    if threads:
        r.threads_mode, r.threads = "FIXED", threads
    im = r.image_settings
    if spec["fmt"] == "EXR":
        im.file_format = "OPEN_EXR"
        im.exr_codec = "ZIP"
    else:
        im.file_format = "PNG"
    r.use_file_extension = True
    r.use_overwrite = True
    r.use_placeholder = False
    fit_dome(scene)
    return scene


def expected_size(scene):
    """``(width, height)`` of the rendered frame, or None when a crop border makes it vary."""
    r = scene.render
    if r.use_border and r.use_crop_to_border:
        return None
    return r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100


def decode(path, size=None):
    """Decode every pixel of ``path`` with OpenImageIO; raises :class:`InvalidFrame` unless whole."""
    from ..fileio import oiio as _oiio

    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InvalidFrame(f"OpenImageIO cannot open it: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
        err = inp.geterror()
    finally:
        inp.close()
    if pixels is None or err:
        raise InvalidFrame(f"OpenImageIO cannot decode it: {err}")
    if size is not None and (spec.width, spec.height) != tuple(size):
        raise InvalidFrame(f"size {spec.width}x{spec.height}, expected {size[0]}x{size[1]}")
    check_image(path)
    return spec.width, spec.height


@contextlib.contextmanager
def _logged(log_path):
    """Send this process's stdout/stderr (Blender's C output too) to ``log_path``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (fd, *saved):
            os.close(f)


@contextlib.contextmanager
def _swallowed_errors():
    """Collect Python errors that Blender prints instead of raising (frame handlers)."""
    caught = []
    old = sys.excepthook

    def hook(kind, value, tb):
        caught.append("".join(traceback.format_exception(kind, value, tb)))
        old(kind, value, tb)

    sys.excepthook = hook
    try:
        yield caught
    finally:
        sys.excepthook = old


@contextlib.contextmanager
def _watchdog(seconds, log_path):
    """End this worker process if the frame takes longer than ``seconds``.

    :func:`faulthandler.dump_traceback_later` runs in a C thread that needs
    no GIL, so it fires even when Blender hangs in C code holding it; it
    writes every thread's stack to the frame's log ("Timeout (h:mm:ss)!") and
    exits the process.  The nanny starts a fresh worker.
    """
    if not seconds:
        yield
        return
    with open(log_path, "a") as f:
        faulthandler.dump_traceback_later(seconds, repeat=False, file=f, exit=True)
        try:
            yield
        finally:
            faulthandler.cancel_dump_traceback_later()


def output_views(scene, cube=None):
    """The file suffixes Blender writes each frame under: ``[""]``, or one per view (``["_L", "_R"]``).

    Multi-view scenes saved as individual files (stereo 3D or multi-view
    mode) write one file per view, the view's ``file_suffix`` inserted before
    the extension; a stereo 3D image format (one packed file) is one view.
    A dome rig rendered through the cube-map route writes ``_L`` / ``_R``
    when the rig is stereo (``cube``: whether that route is taken, if already known).
    """
    if cube is None:
        cube = _dome_cube_route(scene)
    if cube:
        from ..addon import frame as nframe

        return ["_L", "_R"] if nframe.params(_dome_rig(scene)).get("stereo") else [""]
    r = scene.render
    if not r.use_multiview or r.image_settings.views_format != "INDIVIDUAL":
        return [""]
    if r.views_format == "STEREO_3D":
        return [r.views["left"].file_suffix, r.views["right"].file_suffix]
    return [v.file_suffix for v in r.views if v.use]


def _dome_rig(scene):
    from ..addon import dome_ops

    return dome_ops.dome_rig(scene)


def _dome_cube_route(scene):
    """True when the scene has a dome rig and an engine without panoramic cameras (EEVEE, Workbench).

    Those engines would render the fisheye camera as a plain perspective
    view; the frame is made from six cube faces per eye instead
    (:func:`nephele.addon.dome_ops.render_dome_eevee`).
    """
    return scene.render.engine != "CYCLES" and _dome_rig(scene) is not None


def fit_dome(scene):
    """Make a dome rig's frame size the scene's output size (after ``--resolution``/``--percentage``).

    The rig's cameras are re-set for the new aspect (Cycles) and its stored
    size is what the cube-map route writes, so both routes give frames of the
    size the worker checks.
    """
    rig = _dome_rig(scene)
    if rig is None:
        return
    from ..addon import dome_ops
    from ..addon import frame as nframe

    r = scene.render
    size = (r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100)
    r.resolution_x, r.resolution_y, r.resolution_percentage = *size, 100
    p = nframe.params(rig)
    if (p["width"], p["height"]) == size:
        return
    p["width"], p["height"] = size
    camera = dome_ops.dome_from_params(p)
    for ob in rig.children:
        if ob.type == "CAMERA":
            dome_ops.configure_fisheye(ob.data, camera)
    nframe.set_params(rig, p)


def _render_to(scene, tmp, cube):
    """Render the current frame to ``tmp`` (Blender adds view suffixes); ``cube``: the dome cube-map route."""
    import bpy

    if cube:
        from ..addon import dome_ops

        dome_ops.render_dome_eevee(tmp, scene=scene)
        return
    scene.render.filepath = str(tmp)
    result = bpy.ops.render.render(write_still=True)
    if "FINISHED" not in result:
        raise FrameError(f"render operator returned {sorted(result)}")


def render_one(scene, spec, frame, address):
    """Render ``frame`` of the loaded ``scene`` into place; returns its manifest entry.

    Every view's file (both eyes of a stereo frame) is decoded and checked
    before any is moved into place; each move is an :func:`os.replace`.  A
    crash between the moves leaves a frame with one eye new and the other old
    or missing, which the client's resume check (every view valid) re-renders.
    """
    out = Path(spec["out_dir"])
    cube = _dome_cube_route(scene)
    views = output_views(scene, cube)
    fmt = spec["fmt"]
    stem = Path(frame_name(frame, fmt)).stem
    log = out / "logs" / f"{stem}.log"
    tmp = out / TMP_DIR / f"{stem}.{os.getpid()}.{time.monotonic_ns()}{FORMATS[fmt]}"
    tmps = [tmp.with_name(f"{tmp.stem}{v}{tmp.suffix}") for v in views]
    names = [frame_name(frame, fmt, v) for v in views]
    t0 = time.perf_counter()
    with open(log, "a") as f:
        job = f", job {batch_job()}" if batch_job() else ""
        f.write(f"=== frame {frame} on {address} (pid {os.getpid()}{job}) {datetime.datetime.now().isoformat()} ===\n")
    try:
        with _logged(log), _watchdog(spec.get("timeout"), log), _swallowed_errors() as caught:
            scene.frame_set(frame)
            _render_to(scene, tmp, cube)
        if caught:  # the traceback itself is already in the log
            raise FrameError(f"a Python error during frame {frame}: {caught[0].strip().splitlines()[-1]}")
        size = expected_size(scene)
        records = []
        with _logged(log):  # a decoder's own complaints (libpng on a cut file) go to the frame's log too
            for t, v in zip(tmps, views):
                if not t.is_file():
                    raise FrameError(f"Blender wrote no file for frame {frame}" + (f" view {v}" if v else ""))
                decode(t, size)
                fsync_path(t)
                records.append(sha256_file(t))
        stats = []
        for t, name in zip(tmps, names):
            replace(t, out / name)  # (Windows: retried while a viewer holds the old frame)
            stats.append((out / name).stat())
    except BaseException as exc:
        with open(log, "a") as f:
            f.write("".join(traceback.format_exception(exc)))
        for t in tmps:
            with contextlib.suppress(OSError):
                t.unlink()
        raise
    seconds = time.perf_counter() - t0
    _LAST_BYTES["n"] = sum(st.st_size for st in stats)
    with open(log, "a") as f:
        f.write(f"nephele: frame {frame} ok in {seconds:.3f} s -> {', '.join(names)}\n")
    files = [{"file": n, "size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": d}
             for n, st, d in zip(names, stats, records)]
    common = {"seconds": round(seconds, 4), "worker": address, "log": str(log.relative_to(out))}
    job = batch_job()
    if job:
        common["job"] = job
    if views == [""]:
        return {"status": "ok", **files[0], **common}
    return {"status": "ok", "views": dict(zip(views, files)), **common}


def render_frames(name, frames, *needs):
    """Dask task: render ``frames`` with the scene of plugin ``name``; one entry per frame.

    ``needs`` are the results of the precompute tasks these frames wait for (unused).

    A frame that fails gets ``{"status": "failed", "error": ...}``; the others
    of the chunk still render.
    """
    plugin = _plugin(name)
    scene = plugin.ensure_loaded()
    results = {}
    for f in frames:
        try:
            results[f] = render_one(scene, plugin.spec, f, plugin.address)
        except Exception as exc:
            out = Path(plugin.spec["out_dir"])
            log = out / "logs" / f"{Path(frame_name(f, plugin.spec['fmt'])).stem}.log"
            results[f] = {
                "status": "failed",
                "error": f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}",
                "worker": plugin.address,
                "log": str(log.relative_to(plugin.spec["out_dir"])),
            }
            # Full or read-only: the client stops scheduling.  A writer failing without an errno (Blender) counts
            # as a full disk when less than twice this worker's last frame is free.
            disk = write_error(exc, getattr(exc, "filename", None) or out, low=2 * _LAST_BYTES["n"])
            if disk is not None:
                results[f]["disk"] = {"errno": disk.errno, "path": disk.path, "problem": disk.problem}
                results[f]["error"] = str(disk)
                break  # the rest of the chunk would fail the same way
    return results


def probe(name):
    """Dask task: load the scene and report what the client needs before rendering.

    Returns the engine, the frame size, the device, the output views (file
    suffixes), the dome route (``"cube"``, ``"fisheye"`` or None), and the
    ``obj["nephele"]`` parameters of every Nephele object (for precompute).
    Raises on a scene that does not load, a device that is absent, or EXR
    output of the dome cube-map route.
    """
    plugin = _plugin(name)
    scene = plugin.ensure_loaded()
    objects = {}
    for obj in scene.objects:
        raw = obj.get("nephele")
        if raw:
            objects[obj.name] = json.loads(raw)
    views = output_views(scene)
    if plugin.spec["fmt"] == "EXR" and _dome_cube_route(scene):
        from ..core.errors import DataError

        raise DataError("the dome cube-map route (EEVEE, Workbench) writes 8-bit frames: use --format PNG, "
                        "or --engine CYCLES for EXR dome frames", field="--format")
    return {
        "engine": scene.render.engine,
        "size": expected_size(scene),
        "views": views,
        "dome_route": "cube" if _dome_cube_route(scene) else ("fisheye" if _dome_rig(scene) is not None else None),
        "device": scene.cycles.device if scene.render.engine == "CYCLES" else None,
        "objects": objects,
        "threads": scene.render.threads,
    }


def precompute(kind, params, cache_dir):
    """Dask task: make sure the cache holds task ``kind`` for ``params``; returns (key, computed?, seconds)."""
    from ..core.pipeline import tasks
    from ..core.pipeline.cache import Cache, cache_key

    cache = Cache(cache_dir)
    t0 = time.perf_counter()
    hit = (kind, params) in cache
    if not hit:
        tasks.run_cached(kind, params, cache)
    return cache_key(kind, params), not hit, time.perf_counter() - t0
