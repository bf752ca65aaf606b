"""``nephele advect SOURCE --frames A-B``: precompute advected-texture contours into the cache.

Streams the frames in order (the restart and compose strategies advance one
frame at a time, so a range costs one frame of tracing per frame) and stores
each frame under the same key the Blender object of kind
``"advected_contour"`` with the same settings looks up.
"""

import time

from ..core.errors import UsageError
from ..core.parse import parse_range
from .reader_options import add_reader_options, open_with_overrides

HELP = "precompute the contour and texture start coordinates of an advected cloud texture for a frame range"


def add_arguments(p):
    p.add_argument("source", metavar="SOURCE", help='dataset: "demo", "demo:small", a NetCDF .nc or a GrADS .ctl file')
    p.add_argument("--frames", required=True, metavar="A-B", help="frame range, inclusive (e.g. 1-240)")
    p.add_argument("--var", default="cloud", help="contoured variable (default cloud)")
    p.add_argument("--level", type=float, default=0.15, help="contour level (default 0.15)")
    p.add_argument("--strategy", choices=("restart", "compose", "full"), default="restart",
                   help="restart: 2 cross-faded copies; compose: one copy composed frame by frame; full: the paper's")
    p.add_argument("--period", type=int, default=24, help="restart period in frames (even, default 24)")
    p.add_argument("--integrator", choices=("rk4", "rk2", "euler"), default="rk4")
    p.add_argument("--vertical", choices=("auto", "w", "levels"), default="auto",
                   help="vertical motion from w, or points keep their level (exact for the demo); "
                        "auto (default): keep levels where the dataset says its levels follow the air")
    p.add_argument("--hours-per-frame", type=float, default=1.0)
    p.add_argument("--frame-start", type=int, default=1, help="frame showing model time 0 (default 1)")
    p.add_argument("--exaggeration", type=float, help="vertical exaggeration (default 30, as the add-on)")
    p.add_argument("--radius", type=float, default=1.0)
    p.add_argument("--color-var", default="altitude")
    p.add_argument("--method", choices=("cubes", "tetra5"), default="cubes", help="contouring method")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--cache", metavar="DIR", help="cache directory (default: $NEPHELE_CACHE or ~/.cache/nephele)")
    where.add_argument("--blend", metavar="FILE", help="use the cache beside this .blend (as Blender does)")
    add_reader_options(p)


def run(args):
    from ..core.climate.grid import DEFAULT_EXAGGERATION
    from ..core.pipeline.cache import Cache, default_cache_dir
    from ..core.pipeline.tasks import plan, run_cached

    first, last = parse_range(args.frames)
    if args.strategy == "restart" and (args.period < 2 or args.period % 2):
        raise UsageError(f"--period must be an even number >= 2, got {args.period}")
    if not args.hours_per_frame > 0:
        raise UsageError(f"--hours-per-frame must be > 0, got {args.hours_per_frame}")
    _, source = open_with_overrides(args)  # bad data fails here, before any frame
    obj_params = {
        "kind": "advected_contour", "source": source, "var": args.var, "level": args.level,
        "exaggeration": DEFAULT_EXAGGERATION if args.exaggeration is None else args.exaggeration,
        "radius": args.radius, "color_var": args.color_var, "method": args.method,
        "hours_per_frame": args.hours_per_frame, "frame_start": args.frame_start,
        "strategy": args.strategy, "period": args.period, "integrator": args.integrator,
        "vertical": args.vertical,
    }
    cache = Cache(args.cache) if args.cache else Cache(default_cache_dir(args.blend))
    total = 0.0
    for f in range(first, last + 1):
        t0 = time.perf_counter()
        (kind, tp), = plan(obj_params, f)
        out = run_cached(kind, tp, cache)
        dt = time.perf_counter() - t0
        total += dt
        print(f"frame {f}: {len(out['vertices'])} vertices, model time {tp['hours']:g} h, {dt:.2f} s", flush=True)
    n = last - first + 1
    print(f"{n} frames in {total:.1f} s ({total / n:.2f} s per frame) into {cache.root}")
    return 0
