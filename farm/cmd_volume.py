"""``nephele volume FILE --var cloud --out DIR``: write a VDB sequence, one file per model time step.

The files (``DIR/clouds_0001.vdb`` …, step 0 in file 1) load natively in
Blender as a volume sequence, so a farm needs neither the add-on nor this
command at render time; ``DIR/sequence.json`` records how they were made.
In the exact mode (the default) each ``.vdb`` holds the support grid, an
``.exr`` of the same name the values atlas, and ``clouds_heights.exr`` the
level heights (a curvilinear grid adds ``clouds_index.exr``, its column
index map); ``sequence.json`` then carries the atlas ``layout`` the material
needs (:mod:`nephele.volume_files`) and, for a rotated-pole grid, the
``rotation`` (3×3, rows) that turns the volume object into place.
"""

import json
import os
import sys
from pathlib import Path

from ..core.errors import UsageError
from ..core.files import atomic_write
from ..core.parse import parse_range
from .reader_options import add_reader_options, open_with_overrides

HELP = "resample a variable into a sparse VDB volume sequence (one .vdb per time step) for Blender"


def add_arguments(p):
    p.add_argument("source", metavar="FILE", help='dataset: "demo", "demo:small", a NetCDF .nc or a GrADS .ctl file')
    p.add_argument("--var", default="cloud", metavar="NAME", help="variable behind the opacity (default cloud)")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the .vdb files")
    p.add_argument("--threshold", type=float, default=0.3, help="opacity is zero up to this value (default 0.3)")
    p.add_argument("--full", type=float, default=1.0, help="value where the opacity reaches --opacity (default 1)")
    p.add_argument("--opacity", type=float, default=1.0, help="opacity at --full (default 1)")
    p.add_argument("--tf", metavar="JSON", help='custom transfer function [[value, opacity], ...] (overrides the ramp)')
    p.add_argument("--color-var", default="altitude", metavar="NAME",
                   help='second grid: "altitude" (default), a variable such as temperature, or "" for none')
    p.add_argument("--mode", choices=("exact", "voxels"), default="exact",
                   help="exact (default): atlas images for a shader that evaluates the curvilinear field, plus a "
                        "support VDB; voxels: the opacity resampled into a VDB")
    p.add_argument(
        "--voxel-size", type=float, metavar="S", help="voxel mode: scene units between voxels (default 0.0027)"
    )
    p.add_argument("--support-size", type=float, metavar="S",
                   help="exact mode: scene units between support voxels (default 0.01)")
    p.add_argument("--exaggeration", type=float, metavar="E", help="vertical exaggeration (default 30)")
    p.add_argument("--radius", type=float, default=1.0, help="sea-level radius in scene units (default 1)")
    p.add_argument("--steps", metavar="A-B", help="time steps to write, e.g. 0-23 (default: all)")
    p.add_argument("--prefix", default="clouds", help="file name prefix (default clouds)")
    p.add_argument("--force", action="store_true",
                   help="go on when the frames left will not fit on the disk (estimated from the first frame)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_reader_options(p)


def run(args):
    import numpy as np

    from ..core.climate.grid import DEFAULT_EXAGGERATION
    from ..core.errors import DataError
    from ..core.volume.sparse import DEFAULT_VOXEL_SIZE
    from ..core.volume.transfer import TransferFunction

    voxel = DEFAULT_VOXEL_SIZE if args.voxel_size is None else args.voxel_size
    exaggeration = DEFAULT_EXAGGERATION if args.exaggeration is None else args.exaggeration
    if not (np.isfinite(voxel) and voxel > 0):
        raise UsageError(f"--voxel-size must be > 0, got {voxel}")
    if not (np.isfinite(exaggeration) and exaggeration > 0):
        raise UsageError(f"--exaggeration must be > 0, got {exaggeration}")
    if not args.radius > 0:
        raise UsageError(f"--radius must be > 0, got {args.radius}")
    if not args.prefix or os.sep in args.prefix:
        raise UsageError(f"--prefix must be a plain file name prefix, got {args.prefix!r}")
    try:
        if args.tf:
            tf = TransferFunction.from_dict({"points": json.loads(args.tf)})
        else:
            tf = TransferFunction.ramp(args.threshold, args.full, args.opacity)
    except (DataError, json.JSONDecodeError, TypeError) as exc:
        raise UsageError(f"bad transfer function: {exc}") from None

    ds, source = open_with_overrides(args)
    if args.var not in ds:
        raise DataError(f"no such variable (available: {', '.join(sorted(ds.variables))})", path=args.source,
                        field=args.var)
    color_var = args.color_var or ""
    if color_var and color_var != "altitude" and color_var not in ds:
        raise DataError(f"no such colour variable (available: altitude, {', '.join(sorted(ds.variables))})",
                        path=args.source, field=color_var)
    nt = ds.times.size
    first, last = parse_range(args.steps, "--steps", lo=0, hi=nt - 1) if args.steps else (0, nt - 1)
    if not np.isfinite(ds.read(args.var, first)).any():  # cheap: the bake reads this step from the cache
        raise DataError(f"every value at time step {first} is missing (NaN): nothing to show", path=ds.source,
                        field=ds.resolve(args.var))
    # Frame k (1-based) shows step first + k - 1: frames advance one step each.
    step_hours = float(np.median(np.diff(ds.hours))) if ds.hours.size > 1 else 1.0
    params = {
        "source": source, "var": args.var, "tf": tf.to_dict(), "color_var": color_var, "voxel_size": voxel,
        "exaggeration": exaggeration, "radius": args.radius,
        "frame_start": 1 - first, "hours_per_frame": step_hours, "mode": args.mode,
    }
    from ..volume_files import bake_sequence

    out = Path(args.out)
    if args.mode == "exact":
        from ..core.volume.volume_atlas import DEFAULT_SUPPORT_SIZE, atlas_layout
        from ..volume_files import write_exr

        support = DEFAULT_SUPPORT_SIZE if args.support_size is None else args.support_size
        if not (np.isfinite(support) and support > 0):
            raise UsageError(f"--support-size must be > 0, got {support}")
        del params["voxel_size"]
        params["support_size"] = support
        layout = atlas_layout(ds.grid, args.radius, exaggeration)
        write_exr(out / f"{args.prefix}_heights.exr", layout.heights)
        if layout.index is not None:  # a curvilinear grid's column lookup
            write_exr(out / f"{args.prefix}_index.exr", layout.index.image)
        params["layout"] = layout.to_dict()
        if ds.grid.rotation is not None:  # shaded in the grid's frame: the volume object takes this matrix
            params["rotation"] = ds.grid.rotation.tolist()

    def progress(i, n, info):
        if not args.quiet:
            print(f"[{i}/{n}] {Path(info['path']).name}: {info['hours']:g} h, {info['blocks']} blocks, "
                  f"{info['active_voxels']} active voxels ({info['seconds']:.2f} s)", file=sys.stderr)

    infos = bake_sequence(params, range(1, last - first + 2), out, args.prefix, progress=progress, force=args.force)
    meta = dict(params, steps=[first, last], files=[Path(i["path"]).name for i in infos],
                value_max=max(i["value_max"] for i in infos),
                grids=["support"] if args.mode == "exact" else ["density"] + ([color_var] if color_var else []))
    with atomic_write(out / "sequence.json") as tmp, open(tmp, "w") as f:
        json.dump(meta, f, indent=1)
    voxels = sum(i["active_voxels"] for i in infos)
    print(f"{out}: {len(infos)} VDB files ({args.prefix}_0001.vdb ...), {voxels} active voxels")
    if voxels == 0:
        lo = tf.support()[0] if tf.support() else float("nan")
        print(f"nephele volume: warning: every volume is empty (threshold {lo:g}, largest {args.var} "
              f"{meta['value_max']:g})", file=sys.stderr)
    return 0
