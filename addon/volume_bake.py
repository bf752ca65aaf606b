"""Baking a volume layer's frames without freezing the interface.

A bake of many frames takes seconds per frame.  In the interface "Add volume
clouds" therefore adds the layer lazily (each frame's file written when shown)
and hands the frames to :class:`NEPHELE_OT_bake_volume`: a worker thread writes
them (the shown frame first), the operator shows progress in the status bar and
Esc stops it between frames; frames left unbaked are still written when shown,
and every file is written atomically, so a stop leaves nothing half-written.
Headless the operator bakes synchronously.
"""

import threading

import bpy

from ..volume_files import bake_frame
from . import data_ops, frame


class BakeJob:
    """The frames of one volume layer, baked on a worker thread (:meth:`start`) or here (:meth:`run`)."""

    def __init__(self, obj, scene):
        from .volume_ops import PREFIX

        self.name = obj.name
        self.params = dict(frame.params(obj))
        f0, f1 = (int(f) for f in self.params["frames"])
        cur = min(max(scene.frame_current, f0), f1)
        self.frames = [cur] + [f for f in range(f0, f1 + 1) if f != cur]
        self.f0, self.prefix = f0, PREFIX
        self.directory = data_ops.layer_dir(self.params)
        self.cache = frame.results_dir()
        self.infos, self.error = [], None
        self.cancelled = False
        self._thread = None

    @property
    def fraction(self):
        return len(self.infos) / len(self.frames)

    @property
    def status(self):
        return f"Baking {self.name}: frame {len(self.infos)} of {len(self.frames)}"

    @property
    def done(self):
        return self._thread is not None and not self._thread.is_alive()

    def run(self):
        """Bake the frames in order; stops between frames when cancelled; an error is kept in ``error``."""
        try:
            for f in self.frames:
                if self.cancelled:
                    return
                self.infos.append(bake_frame(self.params, f, f - self.f0 + 1, self.directory, self.prefix,
                                             cache=self.cache))
        except (ValueError, OSError, RuntimeError, ImportError) as exc:
            self.error = exc

    def start(self):
        self._thread = threading.Thread(target=self.run, name=f"nephele bake {self.name}", daemon=True)
        self._thread.start()

    def cancel(self):
        """Stop after the frame being written (it is finished, never left half-written)."""
        self.cancelled = True
        if self._thread is not None:
            self._thread.join()

    def finish(self, obj):
        """Main thread: record what the bake found on the layer and make Blender re-read its files."""
        from .volume_ops import data_range, refresh_material

        p = frame.params(obj)
        if self.infos:
            p["value_max"] = max(i["value_max"] for i in self.infos)
        if len(self.infos) == len(self.frames):
            p["empty"] = all(i["active_voxels"] == 0 for i in self.infos)
            if p["empty"]:
                ds = data_ops.dataset(p["source"])
                p["value_range"] = list(data_range(ds, p["var"], p, *p["frames"]))
        frame.set_params(obj, p)
        obj.data.filepath = obj.data.filepath  # unloads the grids: the shown frame is read again
        refresh_material(obj)


def _target(context, name):
    from .volume_ops import KIND

    obj = context.scene.objects.get(name) if name else context.active_object
    if obj is None or frame.params(obj).get("kind") != KIND:
        obj = next((o for o in context.scene.objects if frame.params(o).get("kind") == KIND), None)
    return obj


class NEPHELE_OT_bake_volume(bpy.types.Operator):
    """Write a volume layer's frame files now, in the background (Esc stops; the rest are written when shown)"""

    bl_idname = "nephele.bake_volume"
    bl_label = "Bake volume frames"

    name: bpy.props.StringProperty(name="Layer", default="", description="Volume layer (empty: the active one)")

    def _job(self, context):
        obj = _target(context, self.name)
        if obj is None:
            self.report({"ERROR"}, "no volume layer in this scene: add volume clouds first")
            return None
        return BakeJob(obj, context.scene)

    def _report(self, job):
        if job.error is not None:
            self.report({"ERROR"}, f"{job.name}: {job.error}")
            return {"CANCELLED"}
        n, total = len(job.infos), len(job.frames)
        if n < total:
            self.report(
                {"WARNING"}, f"{job.name}: stopped after {n} of {total} frames; the rest are written when shown"
            )
            return {"CANCELLED"}
        self.report({"INFO"}, f"{job.name}: {total} frames in {job.directory}")
        return {"FINISHED"}

    def execute(self, context):
        job = self._job(context)
        if job is None:
            return {"CANCELLED"}
        job.run()
        job.finish(context.scene.objects[job.name])
        return self._report(job)

    def invoke(self, context, event):
        if context.window is None:
            return self.execute(context)
        self._bake = self._job(context)
        if self._bake is None:
            return {"CANCELLED"}
        self._bake.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.progress_begin(0.0, 1.0)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._bake
        if event.type == "ESC":
            job.cancel()
        elif event.type != "TIMER":
            return {"PASS_THROUGH"}
        elif not job.done:
            context.window_manager.progress_update(job.fraction)
            if context.workspace:
                context.workspace.status_text_set(job.status + " (Esc stops)")
            return {"RUNNING_MODAL"}
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)
        obj = context.scene.objects.get(job.name)
        if obj is not None:
            job.finish(obj)
        return self._report(job)


CLASSES = (NEPHELE_OT_bake_volume,)
