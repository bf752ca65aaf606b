"""``nephele cluster-check --cluster slurm ...``: can this cluster render? For setting up a new one.

Prints the job script dask-jobqueue submits, then (unless ``--dry-run``)
submits one job and prints the environment its worker sees (host, Python,
where ``nephele`` and ``bpy`` come from, CPUs, render threads, the job's
variables) and renders one tiny frame there into ``--out``, which the client
then reads back: that also proves ``--out`` is a directory the nodes share.
"""

import os
import sys
import time
from pathlib import Path

from .cmd_render import add_cluster_arguments, cluster_kwargs, print_job_script

HELP = "print the job script and a worker's environment, and render one test frame on the cluster"

JOB_VARS = ("SLURM_JOB_ID", "SLURM_JOB_PARTITION", "SLURM_CPUS_PER_TASK", "SLURM_MEM_PER_NODE", "SLURM_JOB_NODELIST",
            "PBS_JOBID", "PBS_QUEUE", "NCPUS", "VIRTUAL_ENV", "NEPHELE_CACHE")


def add_arguments(p):
    p.add_argument("--out", default="nephele-cluster-check",
                   help="directory for the test frame; must be shared with the compute nodes (default "
                        "./nephele-cluster-check)")
    add_cluster_arguments(p)


def worker_environment():
    """Dask task: what a worker runs with (JSON-able dict)."""
    import platform
    import socket

    import nephele

    from .worker import _import_bpy, batch_job, render_threads

    env = {
        "host": socket.gethostname(),
        "python": f"{sys.executable} ({platform.python_version()})",
        "nephele": str(Path(nephele.__file__).resolve().parent),
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "render threads": render_threads(),
        "job": batch_job(),
        "cwd": os.getcwd(),
    }
    try:
        bpy = _import_bpy()
        env["bpy"] = f"{bpy.app.version_string} ({Path(bpy.__file__).resolve().parent})"
    except ImportError as exc:
        env["bpy"] = f"MISSING: {exc}"
    for var in JOB_VARS:
        if os.environ.get(var):
            env[var] = os.environ[var]
    return env


def check_frame(out_dir):
    """Dask task: render a 32x24 Workbench cube into ``out_dir/cluster_check.png`` (atomically); returns seconds."""
    from ..core.files import atomic_write
    from .worker import _import_bpy, decode, render_threads

    bpy = _import_bpy()
    t0 = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mesh = bpy.data.meshes.new("check")
    corners = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.vertices.add(8)
    mesh.vertices.foreach_set("co", [c for v in corners for c in v])
    mesh.loops.add(24)
    mesh.loops.foreach_set("vertex_index", [i for q in quads for i in q])
    mesh.polygons.add(6)
    mesh.polygons.foreach_set("loop_start", range(0, 24, 4))
    mesh.polygons.foreach_set("loop_total", [4] * 6)
    mesh.update()
    scene.collection.objects.link(bpy.data.objects.new("check", mesh))
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.location, cam.rotation_euler = (5.0, -5.0, 4.0), (1.0, 0.0, 0.785)
    scene.collection.objects.link(cam)
    scene.camera = cam
    r = scene.render
    r.engine = "BLENDER_WORKBENCH"
    r.resolution_x, r.resolution_y, r.resolution_percentage = 32, 24, 100
    threads = render_threads()
    if threads:
        r.threads_mode, r.threads = "FIXED", threads
    r.image_settings.file_format = "PNG"
    with atomic_write(Path(out_dir) / "cluster_check.png") as tmp:
        r.filepath = str(tmp)
        bpy.ops.render.render(write_still=True)
        decode(tmp, (32, 24))
    return time.perf_counter() - t0


def run(args):
    from .frames import InvalidFrame, check_image
    from .render import check_out_dir

    kwargs = cluster_kwargs(args)
    if kwargs["jobqueue"]:
        print("# the job script (one per worker job)")
        print_job_script(kwargs["jobqueue"], kwargs["security"])
    if args.dry_run:
        return 0
    out = check_out_dir(args.out)
    (out / "cluster_check.png").unlink(missing_ok=True)
    jobqueue = kwargs["jobqueue"] and {**kwargs["jobqueue"], "log_dir": str(out / "jobs"), "adapt": None}
    from .cluster import open_client

    t0 = time.perf_counter()
    with open_client(workers=1 if not kwargs["scheduler"] else None, scheduler=kwargs["scheduler"],
                     security=kwargs["security"], jobqueue=jobqueue, jobs=1) as client:
        joined = time.perf_counter() - t0
        print(f"# a worker joined after {joined:.1f} s; its environment:")
        env = client.submit(worker_environment, pure=False).result()
        for key, value in env.items():
            print(f"{key}: {value}")
        try:
            seconds = client.submit(check_frame, str(out), pure=False).result()
        except Exception as exc:  # the worker's own error, shown as is
            print(f"one-frame job: FAILED: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
    frame = out / "cluster_check.png"
    try:
        check_image(frame)
    except (InvalidFrame, OSError) as exc:
        print(f"one-frame job: the worker wrote {frame}, but this machine cannot read it ({exc}): "
              "--out must be a directory the compute nodes share", file=sys.stderr)
        return 1
    print(f"one-frame job: OK, {frame} (32x24) rendered in {seconds:.2f} s on the worker, "
          f"{time.perf_counter() - t0:.1f} s from submission")
    return 0
