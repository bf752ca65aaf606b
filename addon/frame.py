"""Objects that follow the frame, with or without the add-on installed, without freezing the interface.

An animated Nephele object stores what it needs in its ID properties under
``obj["nephele"]`` (a JSON string: ``{"kind": ..., ...}``), so a saved .blend
carries everything.  A ``frame_change_pre`` handler calls the updater
registered for each kind.  The add-on installs the handler on register; the
farm (and any headless script) calls :func:`install` after opening a .blend,
so renders need only the ``nephele`` package on ``sys.path``.

Kinds whose work can take seconds (contours, advected textures) register in
three parts with :func:`register_job`: ``plan`` (main thread, cheap: what the
frame needs), ``compute`` (a worker thread, NumPy only, no ``bpy``) and
``apply`` (main thread: fill the object).  In the interface a frame change
then only plans: the object keeps its last good result, one worker thread
computes the newest request per object, and a ``bpy.app.timers`` poll applies
finished results on the main thread, with progress in the status bar and Esc
to cancel (:class:`NEPHELE_OT_watch_jobs`).  Headless (``bpy.app.background``)
and while rendering every update stays synchronous, so renders are exact.

Which module registers the updater of each kind, and which core tasks a kind
needs, is the table of kinds :data:`nephele.core.pipeline.kinds.KINDS`; a kind
whose frame is core tasks plans them with :func:`plan_task`, through
:func:`nephele.core.pipeline.tasks.plan` as the farm does.
"""

import json
import threading
import time
from contextlib import contextmanager

import bpy
from bpy.app.handlers import persistent

from ..core.pipeline import tasks
from ..core.pipeline.cache import Cache, default_cache_dir
from ..core.pipeline.kinds import KINDS
from ..core.pipeline.registry import code_stamp

UPDATERS = {}
"""``kind -> fn(obj, params: dict, scene, frame: float)``."""

JOBS = {}
"""``kind -> JobKind``: the kinds computed off the main thread in the interface."""

POLL_S = 0.05
"""How often the timer looks for finished work (seconds)."""


def _check_kind(kind):
    row = KINDS.get(kind)
    if row is None or not row.updater:
        raise KeyError(f"no frame updater for object kind {kind!r} in the table of kinds "
                       f"(nephele.core.pipeline.kinds.KINDS): add its row first")


def register_updater(kind):
    """Decorator: ``@register_updater("volume")`` on ``fn(obj, params, scene, frame)``."""
    _check_kind(kind)

    def deco(fn):
        UPDATERS[kind] = fn
        return fn

    return deco


class JobKind:
    """The three parts of a kind computed in the background (see the module docstring).

    ``plan(obj, params, scene, frame) -> (key, args, cached)`` or None when the
    object already shows ``frame``; ``key`` (str) names the result (it is stored
    as ``obj["nephele_shown"]``), ``args`` is what ``compute(args, job)`` needs
    (plain data: it runs on a worker thread), ``cached`` says the result can be
    loaded at once (then it is, synchronously).  ``apply(obj, args, result)``
    fills the object on the main thread.
    """

    def __init__(self, plan, compute, apply, progress=None):
        self.plan, self.compute, self.apply, self.progress = plan, compute, apply, progress


def register_job(kind, plan, compute, apply, progress=None):
    """Register ``kind`` as a background kind; also registers its synchronous updater."""
    _check_kind(kind)
    JOBS[kind] = JobKind(plan, compute, apply, progress)

    def updater(obj, params, scene, frame_number):
        planned = plan(obj, params, scene, frame_number)
        if planned is not None:
            key, args, _cached = planned
            with _COMPUTE:  # never beside a worker using the same streamed state
                result = compute(args, None)
            apply(obj, args, result)
            obj["nephele_shown"] = key

    UPDATERS[kind] = updater
    return updater


def params(obj):
    """The Nephele parameters stored on ``obj`` (empty dict if none)."""
    raw = obj.get("nephele")
    return json.loads(raw) if raw else {}


def set_params(obj, value):
    obj["nephele"] = json.dumps(value, sort_keys=True)


def _load_updaters():
    # Importing the feature modules (the one list, addon.MODULES) registers their updaters;
    # each row of the table of kinds with an updater must then have one.
    from . import _modules

    _modules()
    missing = sorted(k for k, row in KINDS.items() if row.updater and k not in UPDATERS)
    if missing:
        raise KeyError(f"no frame updater registered for object kinds {missing} (see KINDS)")


def results_dir():
    """Where task results are cached: beside the saved .blend, else ``$NEPHELE_CACHE`` or ``~/.cache/nephele``.

    Entries are content-addressed (an entry's name is the key of its code,
    data and parameters), so sharing the user folder between sessions is safe;
    it is also where the farm's workers precompute a scene built by a script.
    Files a layer links by name go in :func:`.data_ops.cache_dir` instead.
    """
    return default_cache_dir(bpy.data.filepath or None)


def shown_task(kind, task_params):
    """The ``nephele_shown`` key of a task result: its parameters and the stamp of its code
    (:func:`nephele.core.pipeline.registry.code_stamp`, as in its cache key), so a .blend
    saved by other code shows no mesh that code made."""
    return json.dumps(dict(task_params, code=code_stamp(kind)), sort_keys=True)


def plan_task(obj, params, scene, frame_number, shown_key=shown_task):
    """The plan (see :class:`JobKind`) of a layer whose frame is one core task.

    The task comes from :func:`nephele.core.pipeline.tasks.plan`, as on the
    farm; ``args`` are ``kind``, ``tp`` (its parameters) and ``cache``
    (:func:`results_dir`).  ``shown_key(kind, tp)`` names the result.  None
    when ``obj`` already shows it.
    """
    (kind, tp), = tasks.plan(params, frame_number)
    key = shown_key(kind, tp)
    if obj.get("nephele_shown") == key and len(obj.data.vertices):
        return None
    cache = results_dir()
    return key, {"kind": kind, "tp": tp, "cache": str(cache)}, Cache(cache).file(kind, tp).is_file()


# ---------------------------------------------------------------- when to be synchronous

_FORCE_ASYNC = False
_RENDERING = [0]
_SUSPENDED = [0]


def force_background_jobs(value=True):
    """Use the background path even headless (tests of the interface's behaviour)."""
    global _FORCE_ASYNC
    _FORCE_ASYNC = bool(value)


def synchronous():
    """True where every update must finish before returning: headless, or while rendering."""
    if _RENDERING[0] or bpy.app.is_job_running("RENDER"):
        return True
    return bool(bpy.app.background) and not _FORCE_ASYNC


@contextmanager
def suspended():
    """Frame changes inside skip every Nephele updater (e.g. stepping frames only to move a camera).

    Used by operators that call ``scene.frame_set`` through a whole film for
    something other than the layers, so an advected contour is not recomputed
    for every frame.
    """
    _SUSPENDED[0] += 1
    try:
        yield
    finally:
        _SUSPENDED[0] -= 1


# ---------------------------------------------------------------- the worker

class Job:
    """One object's request: what it needs, progress, result or error."""

    def __init__(self, uid, kind, key, args, params_json, label):
        self.uid, self.kind, self.key, self.args = uid, kind, key, args
        self.params_json, self.label = params_json, label
        self.cancelled = False
        self.result = self.error = None
        self.started = self.finished = None
        self.submitted = time.perf_counter()

    def check(self):
        """Raise :class:`Cancelled` if the job was cancelled (called by compute between steps)."""
        if self.cancelled:
            raise Cancelled(self.label)


class Cancelled(Exception):
    """A background job stopped at the user's request."""


_COMPUTE = threading.RLock()  # held by whoever computes (worker or synchronous path)
_LOCK = threading.Condition()
_PENDING = {}  # uid -> Job (the newest request per object)
_RUNNING = [None]
_DONE = []
_WANTED = {}  # uid -> key the object should show
_THREAD = [None]
ERRORS = {}  # uid -> the last background error of that object
STATUS = {"text": "", "errors": []}
"""What the panel shows about background work (``text``; ``errors``: recent messages)."""


def _worker():
    while True:
        with _LOCK:
            while not _PENDING:
                _LOCK.wait(timeout=1.0)
                if not _PENDING and _THREAD[0] is not threading.current_thread():
                    return
            uid = next(iter(_PENDING))
            job = _PENDING.pop(uid)
            _RUNNING[0] = job
        job.started = time.perf_counter()
        try:
            with _COMPUTE:
                job.check()
                job.result = JOBS[job.kind].compute(job.args, job)
        except Cancelled:
            job.cancelled = True
        except Exception as exc:  # noqa: BLE001 - reported on the main thread, the worker lives on
            job.error = exc
        job.finished = time.perf_counter()
        with _LOCK:
            _RUNNING[0] = None
            _DONE.append(job)
            _LOCK.notify_all()


def _ensure_worker():
    t = _THREAD[0]
    if t is None or not t.is_alive():
        t = threading.Thread(target=_worker, name="nephele-frame-jobs", daemon=True)
        _THREAD[0] = t
        t.start()


def _uid(obj):
    return obj.session_uid


def _object(uid):
    for obj in bpy.data.objects:
        if obj.session_uid == uid:
            return obj
    return None


def submit(obj, scene, frame_number=None, *, force=False):
    """Bring one object to ``frame_number`` (default: the scene's): synchronously, or queue it.

    Returns the :class:`Job` queued, or None when the object was brought up
    to date at once (synchronous mode, a cached result, or nothing to do).
    ``force`` recomputes even if the object shows the same key (its mesh was
    changed by hand or lost).
    """
    p = params(obj)
    kind = p.get("kind")
    if force:
        obj.pop("nephele_shown", None)
    if _SUSPENDED[0]:
        return None
    jk = JOBS.get(kind)
    frame_number = scene.frame_current + scene.frame_subframe if frame_number is None else frame_number
    if jk is None or synchronous():
        fn = UPDATERS.get(kind)
        if fn is not None:
            if jk is not None:
                _drop(_uid(obj))
            fn(obj, p, scene, frame_number)
        return None
    planned = jk.plan(obj, p, scene, frame_number)
    uid = _uid(obj)
    if planned is None:  # already shown: forget any older request still queued
        _drop(uid)
        return None
    key, args, cached = planned
    _WANTED[uid] = key
    if cached:  # a load: no streamed state involved, so no waiting for the worker either
        _drop(uid)
        result = jk.compute(args, None)
        jk.apply(obj, args, result)
        obj["nephele_shown"] = key
        return None
    with _LOCK:
        running = _RUNNING[0]
        if running is not None and running.uid == uid and running.key == key:
            return running
        old = _PENDING.get(uid)
        if old is not None and old.key == key:
            return old
        job = Job(uid, kind, key, args, obj.get("nephele"), f"{obj.name} at frame {frame_number:g}")
        _PENDING[uid] = job
        if running is not None and running.uid == uid:
            running.cancelled = True  # superseded: stop at its next check, keep what it streamed
        _LOCK.notify_all()
    _ensure_worker()
    _start_polling()
    return job


def _drop(uid):
    with _LOCK:
        _PENDING.pop(uid, None)
        _WANTED.pop(uid, None)


def pending(obj):
    """True while ``obj`` waits for a background result (queued, running or not yet applied)."""
    return _uid(obj) in _WANTED


def last_error(obj):
    """The message of ``obj``'s last failed background job (None if none)."""
    return ERRORS.get(_uid(obj))


class BackgroundAdd:
    """Mixin for an operator that adds or changes a layer: waits for its background result modally.

    ``execute`` calls :meth:`wait_for` with the object; in the interface the
    operator then runs modally (the interface stays live, Esc cancels) and
    calls ``self.done(context, obj)`` when the result is applied; headless
    ``done`` runs at once.  ``done`` reports and returns the operator's result.
    """

    def wait_for(self, context, obj):
        if bpy.app.background or context.window is None:  # no event loop to come back to: wait here
            wait()
        if not pending(obj):
            return self.done(context, obj)
        self._obj_name = obj.name
        self._obj_uid = _uid(obj)
        self._timer = context.window_manager.event_timer_add(POLL_S * 2, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        obj = _object(self._obj_uid)
        if event.type == "ESC" and event.value == "PRESS":
            context.window_manager.event_timer_remove(self._timer)
            cancel_all()
            self.report({"WARNING"}, f"{self._obj_name}: cancelled; it shows its last result")
            return {"FINISHED"}
        if event.type == "TIMER" and (obj is None or not pending(obj)):
            context.window_manager.event_timer_remove(self._timer)
            if obj is None:
                return {"CANCELLED"}
            return self.done(context, obj)
        return {"PASS_THROUGH"}


def busy():
    """True while background work is queued, running or waiting to be applied."""
    with _LOCK:
        return bool(_PENDING or _RUNNING[0] is not None or _DONE)


def cancel_all():
    """Stop background work: queued requests are dropped, the running one stops at its next step.

    Objects keep the result they show.
    """
    with _LOCK:
        n = len(_PENDING) + (_RUNNING[0] is not None)
        _PENDING.clear()
        _WANTED.clear()
        if _RUNNING[0] is not None:
            _RUNNING[0].cancelled = True
    STATUS["text"] = "Cancelled" if n else ""
    return n


def progress_text():
    """One line on the running job, e.g. ``"Contour cloud [0.15] at frame 240: 12/24, 3.1 s"``."""
    with _LOCK:
        job, queued = _RUNNING[0], len(_PENDING)
    if job is None:
        return f"{queued} queued" if queued else ""
    jk = JOBS.get(job.kind)
    extra = ""
    if jk is not None and jk.progress is not None:
        try:
            extra = jk.progress(job.args) or ""
        except Exception:  # noqa: BLE001 - progress is a hint, never an error
            extra = ""
    t = time.perf_counter() - (job.started or job.submitted)
    more = f", {queued} queued" if queued else ""
    return f"{job.label}: {extra + ', ' if extra else ''}{t:.1f} s{more}"


def apply_finished():
    """Apply finished results on the main thread; returns how many objects changed."""
    with _LOCK:
        done = list(_DONE)
        _DONE.clear()
    changed = 0
    for job in done:
        if job.cancelled or job.error is not None:
            if _WANTED.get(job.uid) == job.key:  # nothing newer is coming for this object
                _WANTED.pop(job.uid)
            if job.error is not None:
                msg = f"{job.label}: {job.error}"
                ERRORS[job.uid] = msg
                STATUS["errors"] = (STATUS["errors"] + [msg])[-5:]
                print(f"Nephele: {msg}")
            continue
        obj = _object(job.uid)
        # Only what the object still wants: an edited layer or a newer frame make this one stale.
        if obj is None or obj.get("nephele") != job.params_json or _WANTED.get(job.uid) != job.key:
            continue
        JOBS[job.kind].apply(obj, job.args, job.result)
        obj["nephele_shown"] = job.key
        _WANTED.pop(job.uid, None)
        ERRORS.pop(job.uid, None)
        changed += 1
    if changed:
        _redraw()
    return changed


def _redraw():
    wm = getattr(bpy.context, "window_manager", None)
    for win in getattr(wm, "windows", ()):
        for area in win.screen.areas:
            area.tag_redraw()


def _poll():
    """The timer: apply finished work, show progress; stops itself when idle."""
    apply_finished()
    STATUS["text"] = progress_text()
    _redraw()
    if busy():
        _start_watcher()
        return POLL_S
    STATUS["text"] = ""
    return None


def _start_polling():
    if not bpy.app.timers.is_registered(_poll):
        bpy.app.timers.register(_poll, first_interval=POLL_S)


def wait(timeout=None):
    """Drive the poll on this thread until background work is done (headless scripts, tests).

    Returns True when everything finished, False at ``timeout`` seconds.
    """
    t_end = None if timeout is None else time.perf_counter() + timeout
    while busy():
        if t_end is not None and time.perf_counter() > t_end:
            return False
        with _LOCK:
            if not _DONE:
                _LOCK.wait(timeout=POLL_S)
        apply_finished()
    return True


# ---------------------------------------------------------------- Esc and the status bar

_WATCHING = [False]


def _start_watcher():
    """Start the modal watcher (Esc, status bar) in the first window, if there is one."""
    if _WATCHING[0] or bpy.app.background:
        return
    wm = bpy.context.window_manager
    win = wm.windows[0] if wm is not None and len(wm.windows) else None
    if win is None:
        return
    try:
        with bpy.context.temp_override(window=win):
            bpy.ops.nephele.watch_jobs("INVOKE_DEFAULT")
    except (RuntimeError, AttributeError):  # operator not registered (add-on off) or no usable context
        pass


class NEPHELE_OT_watch_jobs(bpy.types.Operator):
    """Show the progress of Nephele's background work in the status bar; Esc cancels it"""

    bl_idname = "nephele.watch_jobs"
    bl_label = "Nephele background work"

    def invoke(self, context, event):
        if _WATCHING[0]:
            return {"CANCELLED"}
        _WATCHING[0] = True
        self._timer = context.window_manager.event_timer_add(0.2, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context):
        _WATCHING[0] = False
        context.window_manager.event_timer_remove(self._timer)
        if context.workspace is not None:
            context.workspace.status_text_set(None)

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS" and busy():
            n = cancel_all()
            self.report({"WARNING"}, f"Nephele: cancelled {n} background job(s); layers keep their last result")
            self._end(context)
            return {"FINISHED"}
        if event.type == "TIMER":
            if not busy():
                self._end(context)
                return {"FINISHED"}
            if context.workspace is not None:
                context.workspace.status_text_set(f"Nephele: {STATUS['text']}  (Esc cancels)")
        return {"PASS_THROUGH"}


class NEPHELE_OT_cancel_jobs(bpy.types.Operator):
    """Stop Nephele's background work; layers keep the result they show"""

    bl_idname = "nephele.cancel_jobs"
    bl_label = "Cancel background work"

    def execute(self, context):
        n = cancel_all()
        self.report({"INFO"}, f"cancelled {n} job(s)")
        return {"FINISHED"}


CLASSES = (NEPHELE_OT_watch_jobs, NEPHELE_OT_cancel_jobs)


# ---------------------------------------------------------------- the frame handler

def update_scene(scene, frame=None):
    """Bring every Nephele object of ``scene`` to ``frame`` (default: the current frame).

    Synchronous headless and while rendering; in the interface, background
    kinds are queued (see :func:`submit`) and keep showing their last result.
    """
    frame = scene.frame_current + scene.frame_subframe if frame is None else frame
    if _SUSPENDED[0]:
        return
    for obj in scene.objects:
        p = params(obj)
        if p.get("kind") in UPDATERS:
            submit(obj, scene, frame)


@persistent
def _on_frame_change(scene, depsgraph=None):
    update_scene(scene)


def flush(scene):
    """Bring the background kinds of ``scene`` to its frame now.

    A running job is asked to stop at its next step (what it streamed is kept
    for later), so the render waits for at most one step of it.
    """
    with _LOCK:
        if _RUNNING[0] is not None:
            _RUNNING[0].cancelled = True
    for obj in scene.objects:
        kind = params(obj).get("kind")
        if kind in JOBS:
            _drop(_uid(obj))
            UPDATERS[kind](obj, params(obj), scene, scene.frame_current + scene.frame_subframe)


@persistent
def _on_render_init(scene=None, *_args):
    # A render shows exactly the frame: finish what the interface left in the background.
    _RENDERING[0] += 1
    if isinstance(scene, bpy.types.Scene):
        flush(scene)


@persistent
def _on_render_end(*_args):
    _RENDERING[0] = max(0, _RENDERING[0] - 1)


_HANDLERS = (("frame_change_pre", _on_frame_change), ("render_init", _on_render_init),
             ("render_complete", _on_render_end), ("render_cancel", _on_render_end))


def install():
    """Add the frame and render handlers once (idempotent) and load the updaters."""
    _load_updaters()
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if not any(getattr(h, "__name__", "") == fn.__name__ for h in handlers):
            handlers.append(fn)


def uninstall():
    """Remove the handlers and the timer; queued work is dropped."""
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        for h in [h for h in handlers if getattr(h, "__name__", "") == fn.__name__]:
            handlers.remove(h)
    cancel_all()
    _WATCHING[0] = False  # a watcher cut off by the disable must not block the next one
    if bpy.app.timers.is_registered(_poll):
        bpy.app.timers.unregister(_poll)
    with _LOCK:
        _THREAD[0] = None  # the idle worker notices and exits
        _LOCK.notify_all()
