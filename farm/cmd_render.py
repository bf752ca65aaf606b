"""``nephele render SCENE --frames 1-240 --out DIR``: render a sequence on Dask."""

import json
import sys

from ..core.errors import UsageError
from ..core.parse import parse_size

HELP = "render frames of a .blend or example script on Dask (local, a scheduler, Slurm or PBS); resumes"


def add_cluster_arguments(p):
    """Options choosing where work runs (shared with ``nephele precompute``)."""
    g = p.add_argument_group("where to run")
    g.add_argument("--workers", type=int, help="local Dask workers, one bpy each (default: one per 8 cores, 1 to 4)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="use a running Dask scheduler, e.g. tls://head:8786")
    g.add_argument("--tls-ca-file", metavar="PEM", help="CA certificate for a TLS scheduler")
    g.add_argument("--tls-cert", metavar="PEM", help="client certificate for a TLS scheduler")
    g.add_argument("--tls-key", metavar="PEM", help="client key for a TLS scheduler")
    g.add_argument("--cluster", choices=("local", "slurm", "pbs"), default=None,
                   help="local Dask workers (default), or Slurm/PBS jobs through dask-jobqueue")
    q = g.add_mutually_exclusive_group()
    q.add_argument("--slurm", action="store_true", help="same as --cluster slurm")
    q.add_argument("--pbs", action="store_true", help="same as --cluster pbs")
    j = p.add_argument_group("Slurm / PBS jobs (one job = one worker = one bpy)")
    j.add_argument("--queue", help="Slurm partition / PBS queue")
    j.add_argument("--account", help="Slurm account / PBS project")
    j.add_argument("--walltime", default="01:00:00",
                   help="job wall time [D-]HH:MM:SS (default 01:00:00); a worker retires 20%% (at most 5 min) "
                        "before it and a new job takes over")
    j.add_argument("--job-cpus", type=int, default=1, help="CPUs per job = render threads of its one bpy")
    j.add_argument("--job-mem", default="4GB", help="memory per job, requested per node (default 4GB)")
    j.add_argument("--jobs", type=int, default=1, help="number of jobs (workers) kept running (default 1)")
    j.add_argument("--adapt", metavar="MIN:MAX",
                   help="adaptive scaling: between MIN and MAX jobs by the frames still queued (instead of --jobs)")
    j.add_argument("--python", metavar="PATH",
                   help="the Python the jobs run, e.g. /shared/venv/bin/python: it must import nephele and bpy "
                        "on the compute nodes (default: this Python, at the same path)")
    j.add_argument("--job-prologue", action="append", metavar="SHELL",
                   help="shell line run in each job before its worker, e.g. 'module load gcc' (repeatable)")
    j.add_argument("--interface", help="network interface of the scheduler that jobs connect to (e.g. ib0)")
    j.add_argument("--contact-address", metavar="HOST",
                   help="this machine's address as the compute nodes reach it, when it differs from --interface's")
    j.add_argument("--start-timeout", type=float, default=1800.0,
                   help="seconds to wait for the first job's worker (default 1800; 0: no limit)")
    g.add_argument("--dry-run", action="store_true",
                   help="check the inputs and print the plan (and the job script with --slurm/--pbs); render nothing")


def cluster_kwargs(args):
    """``scheduler``, ``security``, ``jobqueue``, ``jobs`` and ``workers`` keyword arguments from the options."""
    from .cluster import security

    sec = security(args.tls_ca_file, args.tls_cert, args.tls_key)
    system = "slurm" if args.slurm else "pbs" if args.pbs else args.cluster or "local"
    if args.cluster and (args.slurm or args.pbs) and args.cluster != system:
        raise UsageError(f"--cluster {args.cluster} contradicts --{system}")
    jobqueue = None
    if system != "local":
        if args.scheduler:
            raise UsageError("--scheduler cannot be combined with --cluster slurm/pbs")
        if args.jobs < 1:
            raise UsageError(f"--jobs must be >= 1, got {args.jobs}")
        if args.start_timeout < 0:
            raise UsageError(f"--start-timeout must be >= 0 seconds, got {args.start_timeout}")
        jobqueue = dict(system=system, queue=args.queue, account=args.account,
                        walltime=args.walltime, job_cpus=args.job_cpus, job_mem=args.job_mem,
                        interface=args.interface, python=args.python, prologue=args.job_prologue or (),
                        contact_host=args.contact_address, adapt=parse_adapt(args.adapt),
                        start_timeout=args.start_timeout or None)
    return dict(workers=args.workers, scheduler=args.scheduler, security=sec, jobqueue=jobqueue, jobs=args.jobs)


def parse_adapt(text):
    """``"MIN:MAX"`` into ``(min, max)``, or None."""
    if text is None:
        return None
    try:
        low, high = (int(v) for v in text.split(":"))
    except ValueError:
        raise UsageError(f"--adapt must be MIN:MAX, e.g. 0:8, got {text!r}") from None
    if not 0 <= low <= high or high < 1:
        raise UsageError(f"--adapt must have 0 <= MIN <= MAX and MAX >= 1, got {text!r}")
    return low, high


def print_job_script(jobqueue, security=None):
    """Print the job script dask-jobqueue would submit (starts only a scheduler, no job)."""
    from .cluster import jobqueue_cluster

    params = {k: v for k, v in jobqueue.items() if k not in ("adapt", "start_timeout")}
    cluster = jobqueue_cluster(params.pop("system"), security=security, **params)
    try:
        print(cluster.job_script())
    finally:
        cluster.close()


def parse_options(items):
    """``KEY=VALUE`` pairs into a dict; values are JSON when they parse, else strings."""
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key.isidentifier():
            raise UsageError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except ValueError:
            out[key] = value
    return out


def add_arguments(p):
    p.add_argument("scene", metavar="SCENE", help="a saved .blend, or an example script defining build(**options)")
    p.add_argument("--frames", required=True, help="frames: 1-240, 1-240x2 (step) or 1,5,9-12")
    p.add_argument("--out", required=True, help="output directory (frames, logs/, manifest.json)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="option passed to an example's build()")
    r = p.add_argument_group("render settings (override the scene's)")
    r.add_argument("--engine", type=str.upper, help="CYCLES, BLENDER_EEVEE or BLENDER_WORKBENCH")
    r.add_argument("--samples", type=int, help="samples per pixel")
    r.add_argument("--resolution", metavar="WxH", help="frame size in pixels")
    r.add_argument("--percentage", type=int, help="resolution percentage")
    r.add_argument("--device", type=str.upper, help="Cycles device: CPU, OPTIX, CUDA, HIP, METAL or ONEAPI")
    r.add_argument("--persistent-data", action="store_true",
                   help="Cycles keeps scene data between a worker's frames (faster, more memory)")
    r.add_argument("--format", default="PNG", type=str.upper, help="PNG (default) or EXR")
    f = p.add_argument_group("robustness")
    f.add_argument("--chunk", type=int, default=1, help="frames per Dask task (default 1)")
    f.add_argument("--retries", type=int, default=2, help="extra attempts per failing frame (default 2)")
    f.add_argument("--timeout", type=float, help="seconds one frame may take before its worker is killed")
    f.add_argument("--overwrite", action="store_true", help="re-render every frame, even valid ones")
    f.add_argument("--verify", action="store_true", help="on resume, re-hash frames against the manifest")
    f.add_argument("--precompute", action="store_true", help="run the scene's core tasks into the cache first")
    f.add_argument("--cache", help="cache directory of an example script's scene (default: beside the script)")
    f.add_argument("--force", action="store_true",
                   help="go on when the frames left will not fit on the disk (estimated from the first frame)")
    f.add_argument("--quiet", action="store_true", help="no progress line")
    add_cluster_arguments(p)


def run(args):
    from .render import render_sequence

    kwargs = cluster_kwargs(args)
    settings = dict(
        engine=args.engine, samples=args.samples,
        resolution=parse_size(args.resolution, "--resolution", example="1920x1080") if args.resolution else None,
        percentage=args.percentage, device=args.device, persistent=args.persistent_data, fmt=args.format,
        chunk=args.chunk, retries=args.retries, timeout=args.timeout, scene_options=parse_options(args.set),
        precompute=args.precompute, cache_dir=args.cache, overwrite=args.overwrite, verify=args.verify,
        force=args.force,
    )
    if args.dry_run:
        return _dry_run(args, settings, kwargs)
    result = render_sequence(args.scene, args.frames, args.out, progress=not args.quiet, **kwargs, **settings)
    rendered = len(result.rendered)
    print(f"nephele render: {len(result.frames) - len(result.failed)}/{len(result.frames)} frames valid in "
          f"{result.out_dir} ({rendered} rendered, {len(result.skipped)} already there) in {result.seconds:.1f} s",
          file=sys.stderr)
    if result.failed:
        from .frames import format_frames

        print(f"nephele render: FAILED frames {format_frames(result.failed)}:", file=sys.stderr)
        for line in result.failure_report():
            print("  " + line, file=sys.stderr)
        return 1
    return 0


def _dry_run(args, settings, kwargs):
    from .frames import format_frames, parse_frames
    from .manifest import Manifest, classify
    from .render import _check_options, check_out_dir, check_scene

    scene, kind = check_scene(args.scene)
    frames = parse_frames(args.frames)
    _check_options(settings["engine"], settings["samples"], settings["resolution"], settings["percentage"],
                   settings["device"], settings["fmt"], settings["retries"], settings["timeout"],
                   settings["chunk"], kwargs["workers"], settings["scene_options"])
    out = check_out_dir(args.out)
    manifest = Manifest.load(out, move_aside=False)
    done, todo = classify(manifest, frames, settings["fmt"], views=tuple(manifest.run.get("views") or ("",)))
    print(f"scene: {scene} ({kind})\nframes: {format_frames(frames)}\n"
          f"already valid: {format_frames(done) or 'none'}\nto render: {format_frames(todo) or 'none'}")
    if kwargs["jobqueue"]:
        print_job_script(kwargs["jobqueue"], kwargs["security"])
    return 0
