"""The scattering cloud's solves as work the interface never waits on.

:class:`ScatterJob` is "Add scattering cloud" in small steps (the modal operator runs one step
per timer tick): the shooting solve, one group of bins a step, then one frame's view (the light
scattered toward that frame's camera, in a VDB with the density) per step.  An evolving cloud
(``evolve`` "Drifting noise": the noise drifts through the ellipsoids over the film,
:func:`..core.light.evolving.drifting_cloud`) is solved frame by frame, each solve warm-started
from the frame before, and each frame's VDB holds that frame's own density.

The cloud keeps its solve's inputs and its cameras (one position a frame, relative to the
cloud).  Editing the panel's albedo, g, sun or density with "Live update" on rewrites those
inputs and hands the new solve to :mod:`.frame`'s worker (:func:`resolve`): ``plan`` on the main
thread, ``compute`` on the worker (the solve, warm-started from the cloud's last solution, and
the emission toward each frame's camera: NumPy and the compiled kernels only), ``apply`` on the
main thread (the VDB sequence rewritten).  The status bar and the panel show the pass, the bins
and the residual; Esc stops it and the cloud keeps what it shows.  Headless and while rendering
the re-solve runs at once, like every Nephele layer.
"""

import json
import math
import time
from pathlib import Path

from ..core.light import evolving, scatter, scatter_task
from ..core.volume import cloud_density as cd
from ..fileio import dense_grids, write_vdb
from . import frame
from . import scatter_scene as ss

_LAST = {}  # object uid -> its last Solution (a warm start's first guess; this session only)


class ScatterJob:
    """The whole "Add scattering cloud" work in small steps (:meth:`step`); see the module doc."""

    def __init__(self, context, props):
        from ..core.memory import check_memory

        self.params = ss.cloud_params(props)
        check_memory(ss.BYTES_PER_CELL * (props.bins_per_face / 4) ** 2 * math.prod(self.params.shape),
                     f"the scattering solve on a {'x'.join(str(n) for n in props.resolution)} grid "
                     "(lower the grid)", field="resolution")
        self.scene = ss.own_scene(context) if props.own_scene else context.scene
        props = self.props = self.scene.nephele_scatter
        self.size = tuple(props.size)
        self.origin = ss.placement(self.scene, self.size)
        self.directory = ss.output_directory(props.directory)
        self.frames = list(range(self.scene.frame_start, self.scene.frame_end + 1))
        centre = tuple(o + 0.5 * d for o, d in zip(self.origin, self.size))
        sky = {"NONE": 0.0, "UNIFORM": props.sky_radiance}.get(props.sky)
        if sky is None:  # the scene's world, rendered around the cloud's centre
            sun_on = (ss.scene_sun(self.scene) if props.use_scene_sun else None) is not None or props.sun_irradiance
            sky = ss.bake_world(context.scene.world, centre, sun_disc=not sun_on,
                                bins_per_face=props.bins_per_face).tolist()
        # the same solve as the farm's "scatter" task (nephele precompute), cached under its key
        self.task = ss.panel_task(props, self.scene, {"solve": {"sky_radiance": sky}})
        self.sun = tuple(self.task["solve"]["sun_dir"])
        self.evolve = props.evolve == "DRIFT"
        self.prev = self.solution = self.last = self.gen = None
        self.frame_index = 0  # frames solved (evolving) or viewed
        self.cameras = []
        self.obj = None
        if self.scene.camera is None and props.orbit_camera:
            r = 1.7 * max(self.size)
            e = math.radians(props.orbit_elevation)
            ss.add_orbit_camera(centre, r * math.cos(e), r * math.sin(e), self.frames, scene=self.scene)
        if self.scene.camera is None:
            raise RuntimeError("the scene has no camera: add one or enable 'Orbit camera'")

    def sigma(self, i):
        """Frame ``i``'s extinction (the same every frame unless the cloud evolves)."""
        if self.evolve:
            return evolving.drifting_cloud(self.params, i, len(self.frames), tuple(self.props.drift),
                                           self.props.extinction)
        return self.props.extinction * cd.cloud_density(self.params)

    @property
    def fraction(self):
        n = max(len(self.frames), 1)
        if self.evolve:
            return self.frame_index / n
        if self.solution is None:
            if self.last is None:
                return 0.0
            # passes are unknown ahead: progress by residual on a log scale to the tolerance
            r = max(self.last.residual, 1e-300)
            done = math.log(max(r, self.props.tolerance)) / math.log(self.props.tolerance)
            return 0.7 * min(max(done, 0.0), 1.0)
        return 0.7 + 0.3 * self.frame_index / n

    @property
    def status(self):
        where = f"frame {self.frame_index + 1}/{len(self.frames)}, " if self.evolve else ""
        if self.obj is not None:
            return f"Scattering cloud: {self.solution.report}"
        if self.gen is not None and self.last is not None:
            return (f"Scattering: {where}pass {self.last.pass_index}, bins {self.last.group}/{self.last.groups}, "
                    f"residual {self.last.residual:.2e}")
        if self.solution is None:
            return "Scattering: starting"
        return f"Scattering: {self.solution.report}; view {self.frame_index}/{len(self.frames)}"

    def step(self, budget=0.15):
        """Work for about ``budget`` seconds; True when everything is done."""
        t_end = time.perf_counter() + budget
        while True:  # at least one unit of work per call
            if self.frame_index >= len(self.frames):
                self._finish()
                return True
            if self.evolve or self.solution is None:
                self._solve_step()
            else:
                self._write_view(self.frame_index)
                self.frame_index += 1
            if time.perf_counter() >= t_end:
                return False

    def _solve_step(self):
        """One group of bins of the (current frame's) solve; a frame's view when its solve ends."""
        if self.gen is None:
            self.gen = scatter.solve_steps(self.sigma(self.frame_index), self.size, warm=self.prev,
                                           **self.task["solve"])
        try:
            self.last = next(self.gen)
            return
        except StopIteration as stop:
            self.solution, self.gen = stop.value, None
        if not self.evolve:  # the one solve, for the farm's cache too
            scatter.save_solution(self.solution, self.directory / "solution.npz")
            from ..core.pipeline.cache import Cache
            from ..core.pipeline.kinds import KINDS
            from .frame import results_dir

            (kind,) = KINDS[ss.KIND].tasks  # stored where the farm's plan for this object looks
            Cache(results_dir()).store(kind, self.task, scatter.solution_arrays(self.solution))
            return
        self.prev = self.solution
        self._write_view(self.frame_index)
        self.frame_index += 1

    def _write_view(self, i):
        from mathutils import Vector

        scene = self.scene
        with frame.suspended():  # only the camera matters here: the layers update once, in _finish
            scene.frame_set(self.frames[i])
        local = tuple(Vector(scene.camera.matrix_world.translation) - Vector(self.origin))
        self.cameras.append([float(v) for v in local])
        src = scatter.view_source(self.solution, local)
        write_vdb(self.directory / f"scatter_{i + 1:04d}.vdb",
                  dense_grids({"density": self.solution.sigma, "emission": src}, self.size))

    def _finish(self):
        from .data_ops import stored_dir

        scene = self.scene
        scene.frame_set(self.frames[0])
        obj = ss._volume_object(ss.OBJECT_NAME, self.directory / "scatter_0001.vdb",
                                (self.frames[0], len(self.frames)), scene=scene)
        obj.location = self.origin
        obj.data.materials.append(ss.emission_material())
        params = {"kind": ss.KIND, "directory": stored_dir(self.directory),
                  "owned": self.props.directory == ss.DEFAULT_DIRECTORY, "frames": self.frames,
                  "report": self.solution.report, "sun_dir": list(self.sun)}
        if self.evolve:  # a sequence of solves, not one: the VDBs are the result (the farm renders them)
            params["evolve"] = {"drift": list(self.props.drift), "frames": len(self.frames)}
        else:
            params.update(solve_task=self.task, cameras=self.cameras)
        frame.set_params(obj, params)
        if not self.evolve:
            _LAST[obj.session_uid] = self.solution
            obj["nephele_shown"] = _key(params)
        self.obj = obj
        self.props.status = self.solution.report


# ---------------------------------------------------------------- the background re-solve

def _key(params):
    return json.dumps({"solve_task": params.get("solve_task"), "cameras": params.get("cameras")}, sort_keys=True)


def plan(obj, params, scene, frame_number):
    """The solve the cloud's parameters ask for, or None when it shows it (or is a sequence)."""
    if "solve_task" not in params or "cameras" not in params:
        return None
    key = _key(params)
    if obj.get("nephele_shown") == key:
        return None
    from .data_ops import layer_dir

    args = {"task": params["solve_task"], "cameras": params["cameras"], "uid": obj.session_uid,
            "directory": str(layer_dir(params)), "status": "starting"}
    return key, args, False


def compute(args, job=None):
    """Worker side: the solve (warm from the cloud's last solution) and each frame's emission."""
    sigma, size = scatter_task.task_grid(args["task"])
    gen = scatter.solve_steps(sigma, size, warm=_LAST.get(args["uid"]), **args["task"]["solve"])
    while True:
        try:
            p = next(gen)
        except StopIteration as stop:
            sol = stop.value
            break
        args["status"] = f"pass {p.pass_index}, bins {p.group}/{p.groups}, residual {p.residual:.2e}"
        if job is not None:
            job.check()
    args["status"] = "views"
    sources = []
    for cam in args["cameras"]:
        sources.append(scatter.view_source(sol, tuple(cam)))
        if job is not None:
            job.check()
    return sol, sources


def apply(obj, args, result):
    """Main-thread side: the cloud's VDB sequence rewritten with the new light, the volume reloaded."""
    sol, sources = result
    directory = Path(args["directory"])
    for i, src in enumerate(sources):
        write_vdb(directory / f"scatter_{i + 1:04d}.vdb",
                  dense_grids({"density": sol.sigma, "emission": src}, sol.size))
    scatter.save_solution(sol, directory / "solution.npz")
    _LAST[args["uid"]] = sol
    p = frame.params(obj)
    p["report"] = sol.report
    frame.set_params(obj, p)
    obj.data.filepath = obj.data.filepath  # reload the sequence's grids
    obj["nephele_status"] = f"Scattering: {sol.report}"


def progress(args):
    return args.get("status")


update_scatter = frame.register_job(ss.KIND, plan, compute, apply, progress)


def resolve(props, context):
    """Property update (albedo, g, sun, density): re-solve the scene's live scattering clouds with
    the panel's settings, in the background in the interface (at once headless)."""
    if not props.live_update:
        return
    scene = context.scene
    for obj in scene.objects:
        params = frame.params(obj)
        if params.get("kind") != ss.KIND or "cameras" not in params:
            continue
        params["solve_task"] = ss.panel_task(props, scene, params["solve_task"])
        params["sun_dir"] = params["solve_task"]["solve"]["sun_dir"]
        frame.set_params(obj, params)
        frame.submit(obj, scene)
        props.status = "Scattering: re-solving in the background" if frame.pending(obj) else frame.params(obj)["report"]


def live_status(obj):
    """What the panel says about ``obj``'s re-solve while it runs (its pass), or its last error."""
    if not frame.pending(obj):
        return frame.last_error(obj)
    return frame.progress_text() or "Scattering: queued"


__all__ = ["ScatterJob", "compute", "live_status", "plan", "resolve"]
