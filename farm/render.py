"""Render a frame sequence on Dask without ever losing a frame.

:func:`render_sequence` checks every input before any worker starts, skips
frames already valid on disk (see :mod:`.frames` for what "valid" means),
renders the rest on Dask workers that each keep one bpy (:mod:`.worker`),
retries failed frames up to a limit, and records everything in
``OUT/manifest.json`` (:mod:`.manifest`) and ``OUT/logs/``.
"""

import ast
import contextlib
import datetime
import json
import os
import shutil
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from ..addon.render_device import DEVICES
from ..core.errors import DataError, UsageError
from ..core.files import WriteError, check_space, lock_file, remove_temporaries
from .frames import FORMATS, TMP_DIR, InvalidFrame, check_image, chunks, format_frames, frame_name, parse_frames
from .manifest import Manifest, classify, entry_files, file_entry, views_entry

ENGINES = ("CYCLES", "BLENDER_EEVEE", "BLENDER_WORKBENCH")
_BLEND_MAGIC = (b"BLENDER", b"\x28\xb5\x2f\xfd", b"\x1f\x8b")  # plain, zstd, gzip


@dataclass
class RenderResult:
    """What a run left in ``out_dir``.

    Attributes
    ----------
    manifest : dict
        The content of ``OUT/manifest.json``.
    frames, rendered, skipped, failed : list of int
        All requested frames; those rendered by this run; those already valid; those that failed.
    """

    out_dir: Path
    fmt: str
    manifest: dict
    frames: list
    rendered: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    seconds: float = 0.0
    views: tuple = ("",)
    """File suffixes of each frame's views: ``("",)``, or ``("_L", "_R")`` for stereo."""

    @property
    def paths(self):
        """Paths of the valid frames, in frame order (every view of a frame, in view order)."""
        bad = set(self.failed)
        return [self.out_dir / frame_name(f, self.fmt, v) for f in self.frames if f not in bad for v in self.views]

    @property
    def ok(self):
        return not self.failed

    def failure_report(self):
        """Lines naming each failed frame, its error and its log file."""
        lines = []
        for f in self.failed:
            e = self.manifest["frames"].get(str(f), {})
            lines.append(f"frame {f}: {e.get('error', 'failed')} (log: {self.out_dir / e.get('log', '')})")
        return lines


def check_scene(scene):
    """The scene's absolute path and kind (``"blend"`` or ``"script"``); :class:`DataError` if unusable."""
    path = Path(scene).expanduser()
    if not path.is_file():
        raise DataError("no such scene file", path=path, field="SCENE")
    path = path.resolve()
    if path.suffix.lower() == ".blend":
        with open(path, "rb") as f:
            head = f.read(8)
        if not head.startswith(_BLEND_MAGIC):
            raise DataError("not a Blender file (bad header)", path=path, field="SCENE")
        return path, "blend"
    if path.suffix.lower() == ".py":
        try:
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))  # (Python source: UTF-8)
        except (SyntaxError, UnicodeDecodeError) as exc:
            raise DataError(f"the example script does not parse: {exc}", path=path, field="SCENE") from None
        if not any(isinstance(n, ast.FunctionDef) and n.name == "build" for n in tree.body):
            raise DataError("the example script defines no build(**options) function", path=path, field="SCENE")
        return path, "script"
    raise DataError("SCENE must be a .blend file or an example .py script with build(**options)", path=path,
                    field="SCENE")


def check_out_dir(out_dir):
    """Create ``out_dir`` if needed and prove it writable; :class:`DataError` otherwise."""
    out = Path(out_dir).expanduser().resolve()
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".nephele-probe-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DataError(f"output directory cannot be written: {exc.strerror or exc}", path=out, field="--out") from None
    return out


def _check_options(engine, samples, resolution, percentage, device, fmt, retries, timeout, chunk, workers,
                   scene_options):
    if engine is not None and engine not in ENGINES:
        raise UsageError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    if fmt not in FORMATS:
        raise UsageError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if device is not None and device not in DEVICES:
        raise UsageError(f"unknown device {device!r}; expected one of {', '.join(DEVICES)}")
    if device not in (None, "CPU") and engine not in (None, "CYCLES"):
        raise UsageError(f"--device {device} needs --engine CYCLES")
    for name, value, low in (("samples", samples, 1), ("percentage", percentage, 1), ("retries", retries, 0),
                             ("chunk", chunk, 1), ("workers", workers, 1)):
        if value is not None and (not isinstance(value, int) or value < low):
            raise UsageError(f"--{name} must be an integer >= {low}, got {value!r}")
    if timeout is not None and not timeout > 0:
        raise UsageError(f"--timeout must be > 0 seconds, got {timeout!r}")
    if resolution is not None:
        if len(resolution) != 2 or any(not isinstance(v, int) or v < 4 for v in resolution):
            raise UsageError(f"resolution must be two integers >= 4, got {resolution!r}")
    try:
        json.dumps(scene_options or {})
    except TypeError as exc:
        raise UsageError(f"scene options must be JSON values: {exc}") from None


class Progress:
    """A progress line on stderr: frames done/failed, per-frame time, ETA.

    On a terminal the line is redrawn in place; otherwise (logs, CI) one plain
    line is printed per finished frame, at most one per second, and always for
    failures and at the end.
    """

    def __init__(self, total, already, enabled=True, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = enabled and self.stream.isatty()
        self.total, self.already = total, already
        self.done = self.failed = 0
        self.render_s = 0.0
        self.t0 = time.perf_counter()
        self._last = 0.0

    def update(self, frame, entry, final=False):
        if entry is not None:
            if entry["status"] == "ok":
                self.done += 1
                self.render_s += entry.get("seconds") or 0.0
            else:
                self.failed += 1
        if not self.enabled:
            return
        now = time.perf_counter()
        failed_now = entry is not None and entry["status"] != "ok"
        if not (self.tty or final or failed_now or now - self._last >= 1.0):
            return
        self._last = now
        finished = self.already + self.done
        todo = self.total - self.already
        n = self.done + self.failed
        elapsed = now - self.t0
        eta = elapsed / n * (todo - n) if n else float("nan")
        per = self.render_s / self.done if self.done else float("nan")
        width = 24
        filled = int(width * (finished + self.failed) / max(self.total, 1))
        bar = "#" * filled + "-" * (width - filled)
        what = f" frame {frame} {'ok' if not failed_now else 'FAILED'}" if frame is not None else ""
        text = (f"nephele render [{bar}] {finished}/{self.total} done, {self.failed} failed, "
                f"{per:.2f} s/frame, ETA {_clock(eta)}{what}")
        if self.tty:
            self.stream.write("\r" + text.ljust(110) + ("\n" if final else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


def _clock(seconds):
    if seconds != seconds:
        return "--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def render_sequence(scene, frames, out_dir, *, workers=None, engine=None, samples=None, resolution=None,
                    percentage=None, device=None, persistent=False, fmt="PNG", chunk=1, retries=2, timeout=None,
                    scheduler=None, security=None, jobqueue=None, jobs=1, progress=True,
                    scene_options=None, precompute=False, cache_dir=None, overwrite=False, verify=False, force=False):
    """Render ``frames`` of ``scene`` into ``out_dir`` on Dask; valid frames already there are kept.

    Parameters
    ----------
    scene : str or Path
        A saved ``.blend`` or an example script defining ``build(**options)``.
    frames : str or iterable of int
        ``"1-240"``, ``"1-240x2"``, ``"1,5,9-12"`` or frame numbers.
    out_dir : str or Path
        Frames go to ``out_dir/frame_NNNN.png`` (or ``.exr``), logs to
        ``out_dir/logs/``, the manifest to ``out_dir/manifest.json``.
    workers : int, optional
        Local Dask workers (each one bpy process).  Ignored with ``scheduler``/``jobqueue``.
    engine, samples, resolution, percentage, device : optional
        Render overrides: ``"CYCLES"|"BLENDER_EEVEE"|"BLENDER_WORKBENCH"``,
        samples, ``(width, height)``, resolution percentage, Cycles device
        (``"CPU"``, ``"OPTIX"``, ``"CUDA"``, ``"HIP"``, ``"METAL"``, ``"ONEAPI"``;
        an absent GPU is a :class:`DataError`).
    persistent : bool
        Cycles keeps its scene data between the frames of a worker (``render.use_persistent_data``):
        faster for long sequences, more memory.
    fmt : {"PNG", "EXR"}
    chunk : int
        Frames per Dask task.
    retries : int
        Extra attempts for a frame that fails (raises, crashes its worker, times out).
    timeout : float, optional
        Seconds one frame may take; past it the worker is killed and the attempt fails.
    scheduler, security : optional
        Address of a running Dask scheduler and its TLS :class:`~distributed.security.Security`.
    jobqueue, jobs : optional
        ``dict(system="slurm"|"pbs", queue=..., account=..., walltime=..., job_cpus=..., job_mem=...)``
        and the number of jobs (see :func:`nephele.farm.cluster.jobqueue_cluster`).
    progress : bool
        Print the progress line on stderr.
    scene_options : dict, optional
        Keyword arguments of an example script's ``build()``.
    precompute : bool
        Run the scene's per-frame core tasks (:func:`nephele.core.pipeline.tasks.plan`) on Dask into the
        cache; each frame's render waits only for its own tasks.
    cache_dir : path, optional
        Cache of an example script's scene (default: beside the script, see
        :func:`nephele.core.pipeline.cache.default_cache_dir`).  A .blend's cache is always beside it,
        where the add-on's updaters look.
    overwrite : bool
        Re-render every frame, valid or not.
    verify : bool
        On resume, re-hash every frame against the manifest's sha256 instead of trusting size and mtime.
    force : bool
        Go on when the frames left will not fit on the disk.  The space they need is estimated from the
        frames already there, else from the first frame rendered (its files and log) times the count, and
        checked before the other frames are scheduled.

    A full disk, a read-only or otherwise unwritable output stops the run: no
    more frames are scheduled, the frames already moved into place stay
    (each is whole), and a :class:`~nephele.core.files.WriteError` names the
    path and the problem.  Run the same call again after freeing space: only
    the missing frames are rendered.  A second run into the same ``out_dir``
    while one is writing it is refused (``OUT/.nephele.lock`` names the pid
    and host holding it); a manifest that cannot be read is moved aside as
    ``manifest.json.bad-<time>`` with a warning on stderr.

    A stereo (multi-view) scene writes ``frame_0001_L.png`` and
    ``frame_0001_R.png`` (Blender's view suffixes); a frame counts as done only
    when every view is valid.  A scene with a dome rig and an engine without
    panoramic cameras (EEVEE, Workbench) renders each frame through the
    dome cube-map route (:func:`nephele.addon.dome_ops.render_dome_eevee`).
    Which views a scene has is known once a worker has loaded it; resume
    first assumes the views recorded by the previous run in ``OUT``.

    Returns
    -------
    RenderResult

    Raises
    ------
    DataError, UsageError
        Bad input, before any worker starts; another run writing ``out_dir``.
    WriteError
        The output cannot be written (full disk, read-only); raised after the run stops scheduling.
    """
    t_start = time.perf_counter()
    scene_path, kind = check_scene(scene)
    frame_list = parse_frames(frames)
    engine = engine.upper() if isinstance(engine, str) else engine
    fmt = fmt.upper()
    device = device.upper() if isinstance(device, str) else device
    resolution = tuple(resolution) if resolution is not None else None
    _check_options(engine, samples, resolution, percentage, device, fmt, retries, timeout, chunk, workers,
                   scene_options)
    out = check_out_dir(out_dir)

    with lock_file(out / ".nephele.lock", "nephele render"):
        manifest = Manifest.load(out)
        if manifest.warning:
            print(f"nephele render: warning: {manifest.warning}", file=sys.stderr)
        views = tuple(manifest.run.get("views") or ("",))  # the previous run's, until a worker says
        if overwrite:
            done, todo = [], list(frame_list)
        else:
            done, todo = classify(manifest, frame_list, fmt, verify=verify, views=views)
        # Leftovers of a killed run: its workers' unfinished frames, a manifest it was saving.
        shutil.rmtree(out / TMP_DIR, ignore_errors=True)
        remove_temporaries(manifest.path)
        settings = {
            "scene": str(scene_path), "frames": format_frames(frame_list), "engine": engine, "samples": samples,
            "resolution": resolution, "percentage": percentage, "device": device, "persistent": bool(persistent),
            "format": fmt,
            "scene_options": scene_options or {},
        }
        manifest.run = {**settings, "views": list(views), "started": _now(), "finished": None, "failed": []}
        result = RenderResult(out, fmt, {}, frame_list, skipped=done, views=views)
        if todo:
            def reclassify(views):
                if overwrite:
                    return [], list(frame_list)
                return classify(manifest, frame_list, fmt, verify=verify, views=views)

            _render(manifest, result, todo, reclassify, scene_path, kind, settings, out, workers=workers, chunk=chunk,
                    retries=retries, timeout=timeout, scheduler=scheduler, security=security,
                    jobqueue=jobqueue, jobs=jobs, progress=progress, precompute=precompute,
                    cache_dir=cache_dir, total=len(frame_list), already=len(done), force=force)
        manifest.run.update(finished=_now(), failed=result.failed, seconds=round(time.perf_counter() - t_start, 3))
        manifest.save()
        result.manifest = manifest.to_dict()
        result.seconds = time.perf_counter() - t_start
        return result


def _now():
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _render(manifest, result, todo, reclassify, scene_path, kind, settings, out, *, workers, chunk, retries, timeout,
            scheduler, security, jobqueue, jobs, progress, precompute, cache_dir, total, already, force=False):
    """Render ``todo`` on Dask into ``result``/``manifest``.

    ``reclassify(views)`` gives ``(done, todo)`` again when the loaded scene's
    views differ from those ``todo`` was planned with.
    """
    from distributed import as_completed

    from .cluster import open_client
    from .worker import render_frames

    (out / "logs").mkdir(exist_ok=True)
    (out / TMP_DIR).mkdir(exist_ok=True)
    if jobqueue and not jobqueue.get("log_dir"):
        jobqueue = {**jobqueue, "log_dir": str(out / "logs" / "jobs")}  # each job's own stdout/stderr
    spec = _spec(scene_path, kind, settings, cache_dir, out_dir=str(out), timeout=timeout)
    token = spec["token"]
    since_ns = time.time_ns() - 2_000_000_000  # frames this run moves into place are newer (2 s clock slack)
    futures = {}
    try:
        with open_client(workers=workers, scheduler=scheduler, security=security, jobqueue=jobqueue,
                         jobs=jobs) as client:
            name, info = _start(client, spec)
            manifest.run["worker_scene"] = {k: info[k] for k in ("engine", "size", "device", "threads", "dome_route")}
            views = tuple(info["views"])
            if views != result.views:
                result.views = views
                manifest.run["views"] = list(views)
                result.skipped, todo = reclassify(views)
                already = len(result.skipped)
            bar = Progress(total, already, enabled=progress)
            attempts = {f: 0 for f in todo}
            deps = {}
            if precompute:
                deps, pre = _precompute(client, info["objects"], todo, spec["cache_dir"])
                manifest.run["precompute"] = {"tasks": len(pre), "cache": spec["cache_dir"]}

            def submit(frames):
                for f in frames:
                    attempts[f] += 1
                first = frames[0]
                needs = [deps[f] for f in frames if f in deps]
                fut = client.submit(render_frames, name, frames, *needs, pure=False, priority=-first,
                                    key=f"nephele-frames-{token}-{first}-{len(frames)}-a{attempts[first]}")
                futures[fut] = frames
                return fut

            parts = chunks(todo, chunk) if todo else []
            # Without frames already there to size them, the first chunk renders alone: its files give the estimate.
            sized = _space_needed(out, manifest, result.skipped, views, len(todo), force)
            first, rest = (parts, []) if sized or len(parts) < 2 else (parts[:1], parts[1:])
            pending = as_completed([submit(c) for c in first], loop=client.loop)  # (not a default client)
            stop = None
            for fut in pending:
                frames = futures.pop(fut)
                try:
                    entries = fut.result()
                except Exception as exc:  # the worker died (crash, kill, timeout) or the task was lost
                    entries = {f: _after_lost_task(out, f, settings["format"], views, exc, since_ns) for f in frames}
                retry = []
                for f in frames:
                    e = entries.get(f)
                    if e is None:  # not tried: its worker stopped the chunk at a full disk
                        continue
                    e["attempts"] = attempts[f]
                    if e.get("disk"):  # the output cannot take more: stop scheduling, not fail frame after frame
                        stop = stop or WriteError(e["disk"]["errno"], e["disk"]["path"], e["disk"]["problem"])
                    elif e["status"] == "ok":
                        manifest.set(f, e)
                        result.rendered.append(f)
                        bar.update(f, e)
                    elif attempts[f] <= retries:
                        retry.append(f)
                    else:
                        manifest.set(f, e)
                        result.failed.append(f)
                        bar.update(f, e)
                if stop is None:
                    try:
                        if rest:
                            left = sum(len(c) for c in rest)
                            _space_needed(out, manifest, result.rendered, views, left, force)
                            for c in rest:
                                pending.add(submit(c))
                            rest = []
                        manifest.save(min_interval=0.5)
                    except WriteError as exc:
                        stop = exc
                if stop is not None:
                    client.cancel(list(futures))
                    raise stop
                for f in retry:
                    pending.add(submit([f]))
            if todo:
                bar.update(None, None, final=True)
            with contextlib.suppress(Exception):
                client.unregister_worker_plugin(name)
    except BaseException:
        with contextlib.suppress(OSError):  # a full disk may refuse this too: the frames on disk are adopted on resume
            manifest.save()
        raise
    else:
        manifest.save()
    finally:
        shutil.rmtree(out / TMP_DIR, ignore_errors=True)
        result.rendered.sort()
        result.failed.sort()


def _space_needed(out, manifest, frames, views, count, force):
    """Check that ``count`` more frames fit on the disk of ``out``, sized from ``frames`` already there.

    Returns False when none of ``frames`` can size them (none valid yet: they are then scheduled
    unchecked); raises :class:`~nephele.core.files.WriteError` when they will not fit (unless ``force``).
    """
    sizes = []
    for f in list(frames)[-8:]:
        records = entry_files(manifest.entry(f), views)
        if not records:
            continue
        log = (manifest.entry(f) or {}).get("log")
        log_size = (out / log).stat().st_size if log and (out / log).is_file() else 0
        sizes.append(sum(r.get("size") or 0 for _, r in records) + log_size + 400)  # + its manifest entry
    if not sizes:
        return False
    each = max(sizes)
    need = each * count
    from ..core.memory import format_bytes

    check_space(out, need, f"the {count} frame{'s' if count != 1 else ''} left ({format_bytes(each)} each, as "
                           f"the last {len(sizes)} rendered)", force=force)
    return True


def _after_lost_task(out, frame, fmt, views, exc, since_ns):
    """Entry for a frame whose task did not return: kept if this run moved all its views into place whole,
    else failed."""
    paths = [out / frame_name(frame, fmt, v) for v in views]
    log = f"logs/{Path(frame_name(frame, fmt)).stem}.log"
    try:
        for path in paths:
            check_image(path)
        if all(path.stat().st_mtime_ns >= since_ns for path in paths):
            extra = dict(seconds=None, worker=None, log=log, recovered=True)
            return file_entry(paths[0], **extra) if views == ("",) else views_entry(paths, views, **extra)
    except (InvalidFrame, OSError):
        pass
    from distributed import KilledWorker

    reason = (f"{type(exc).__name__}: {exc}".strip().splitlines() or ["?"])[0]
    if isinstance(exc, KilledWorker):
        what = f"worker lost ({reason}): it crashed, was killed or exceeded --timeout"
    else:  # e.g. a precompute task this frame needs failed
        what = f"task failed ({reason})"
    with contextlib.suppress(OSError), open(out / log, "a") as f:
        f.write(f"nephele: frame {frame}: {what}\n")
    return {"status": "failed", "error": what, "log": log}


def _spec(scene_path, kind, settings, cache_dir, **extra):
    """The JSON-able scene description a :class:`~nephele.farm.worker.BlenderScene` plugin carries."""
    from ..core.pipeline.cache import default_cache_dir

    if kind == "blend" or cache_dir is None:
        cache_dir = default_cache_dir(scene_path)
    return {
        "token": uuid.uuid4().hex[:12], "scene": str(scene_path), "kind": kind,
        "options": settings.get("scene_options") or {}, "engine": settings.get("engine"),
        "samples": settings.get("samples"), "resolution": settings.get("resolution"),
        "percentage": settings.get("percentage"), "device": settings.get("device"),
        "persistent": settings.get("persistent", False),
        "fmt": settings.get("format", "PNG"), "cache_dir": str(Path(cache_dir).resolve()), **extra,
    }


def _start(client, spec):
    """Register the scene plugin on every worker and load the scene on one; returns (plugin name, probe info)."""
    from .worker import BlenderScene, plugin_name, probe

    name = plugin_name(spec["token"])
    client.register_plugin(BlenderScene(spec), name=name)
    try:
        return name, client.submit(probe, name, pure=False, key=f"nephele-probe-{spec['token']}").result()
    except DataError:
        raise
    except Exception as exc:
        raise DataError(f"the scene did not load on a worker: {type(exc).__name__}: {exc}",
                        path=spec["scene"], field="SCENE") from None


def _precompute(client, objects, frames, cache_dir):
    """Submit every distinct core task the frames need.

    Returns ``frame -> future`` (what that frame's render waits on) and ``key -> future`` of all tasks.
    """
    from ..core.pipeline import tasks
    from ..core.pipeline.cache import cache_key
    from .worker import precompute

    by_key, per_frame = {}, {}
    for f in frames:
        needs = []
        for params in objects.values():
            for kind, task_params in tasks.plan(params, f):
                key = cache_key(kind, task_params)
                if key not in by_key:
                    by_key[key] = client.submit(precompute, kind, task_params, cache_dir, pure=False,
                                                priority=1_000_000 - f,
                                                key=f"nephele-pre-{key[:16]}-{uuid.uuid4().hex[:6]}")
                needs.append(by_key[key])
        if needs:
            per_frame[f] = client.submit(_count, needs, pure=False, key=f"nephele-need-{f}-{uuid.uuid4().hex[:6]}")
    return per_frame, by_key


def _count(results):
    return len(results)


def precompute_scene(scene, frames, *, workers=None, scheduler=None, security=None, jobqueue=None, jobs=1,
                     scene_options=None, cache_dir=None, progress=True):
    """Run the per-frame core tasks ``scene`` needs for ``frames`` on Dask into its cache.

    One worker opens the scene to read every Nephele object's parameters
    (``obj["nephele"]``); :func:`nephele.core.pipeline.tasks.plan` turns them into
    ``(kind, params)`` tasks per frame; distinct tasks run once each as Dask
    tasks through :func:`nephele.core.pipeline.tasks.run_cached` (a hit costs one file test).

    Returns
    -------
    dict
        ``tasks`` (distinct), ``computed`` (not in the cache before), ``cache`` (directory), ``seconds``.
    """
    from distributed import as_completed

    from .cluster import open_client

    t0 = time.perf_counter()
    scene_path, kind = check_scene(scene)
    frame_list = parse_frames(frames)
    _check_options(None, None, None, None, None, "PNG", 0, None, 1, workers, scene_options)
    spec = _spec(scene_path, kind, {"scene_options": scene_options}, cache_dir, out_dir=None, timeout=None)
    if jobqueue and not jobqueue.get("log_dir"):
        jobqueue = {**jobqueue, "log_dir": str(Path(spec["cache_dir"]) / "logs" / "jobs")}
    with open_client(workers=workers, scheduler=scheduler, security=security, jobqueue=jobqueue, jobs=jobs) as client:
        name, info = _start(client, spec)
        _, by_key = _precompute(client, info["objects"], frame_list, spec["cache_dir"])
        computed = done = 0
        for fut in as_completed(list(by_key.values()), loop=client.loop):
            _, new, _ = fut.result()
            computed += bool(new)
            done += 1
            if progress:
                print(f"nephele precompute: {done}/{len(by_key)} tasks ({computed} computed)", file=sys.stderr)
        with contextlib.suppress(Exception):
            client.unregister_worker_plugin(name)
    return {"tasks": len(by_key), "computed": computed, "cache": spec["cache_dir"],
            "objects": sorted(info["objects"]), "seconds": time.perf_counter() - t0}
