"""``nephele precompute SCENE --frames 1-240``: fill the scene's cache with its per-frame core work on Dask."""

import sys

from .cmd_render import add_cluster_arguments, cluster_kwargs, parse_options

HELP = "run a scene's per-frame core tasks (contours, volumes, ...) on Dask into its cache"


def add_arguments(p):
    p.add_argument("scene", metavar="SCENE", help="a saved .blend, or an example script defining build(**options)")
    p.add_argument("--frames", required=True, help="frames: 1-240, 1-240x2 (step) or 1,5,9-12")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="option passed to an example's build()")
    p.add_argument("--cache", help="cache directory of an example script's scene (default: beside the script)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_cluster_arguments(p)


def run(args):
    from .render import precompute_scene

    kwargs = cluster_kwargs(args)
    if args.dry_run:
        from .cmd_render import print_job_script
        from .frames import format_frames, parse_frames
        from .render import check_scene

        scene, kind = check_scene(args.scene)
        print(f"scene: {scene} ({kind})\nframes: {format_frames(parse_frames(args.frames))}")
        if kwargs["jobqueue"]:
            print_job_script(kwargs["jobqueue"], kwargs["security"])
        return 0
    info = precompute_scene(args.scene, args.frames, scene_options=parse_options(args.set), cache_dir=args.cache,
                            progress=not args.quiet, **kwargs)
    print(f"nephele precompute: {info['tasks']} tasks for objects {', '.join(info['objects']) or '(none)'}: "
          f"{info['computed']} computed, {info['tasks'] - info['computed']} already cached, in {info['cache']} "
          f"({info['seconds']:.1f} s)", file=sys.stderr)
    return 0
