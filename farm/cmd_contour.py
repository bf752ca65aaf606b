"""``nephele contour FILE --var NAME --level X [--time I] -o OUT.ply|.glb|.obj``: export one contour surface."""

from pathlib import Path

from ..core.errors import UsageError
from .reader_options import add_reader_options, reader_kwargs

HELP = "export the contour surface of a variable at one time step as .ply, .glb or .obj"


def add_arguments(p):
    p.add_argument("source", metavar="FILE",
                   help='dataset: "demo", "demo:small", a NetCDF .nc (or a .zip of them), a GRIB file, a Zarr store '
                        'or a GrADS .ctl file')
    p.add_argument("--var", required=True, metavar="NAME",
                   help="variable to contour, by its standard, file or GRIB name (e.g. cloud, cloud_water, clwmr)")
    p.add_argument("--level", required=True, type=float, metavar="X", help="contour value (e.g. 0.15)")
    p.add_argument("--time", type=int, default=0, metavar="I",
                   help="time step index (default 0; negative counts from the end)")
    p.add_argument("--exaggeration", type=float, metavar="E", help="vertical exaggeration of heights (default 30)")
    p.add_argument("--radius", type=float, default=1.0, help="sea-level radius in scene units (default 1)")
    p.add_argument("--method", choices=("cubes", "tetra5"), default="cubes",
                   help="marching cubes, or the paper's 5-tetrahedra split (default cubes)")
    p.add_argument("--color-var", metavar="NAME",
                   help="also sample this variable on the surface (vertex attribute; altitude is always written)")
    p.add_argument("-o", "--out", required=True, metavar="OUT", help="output mesh: .ply, .glb or .obj")
    add_reader_options(p)


def run(args):
    import numpy as np

    from ..core.climate.grid import DEFAULT_EXAGGERATION
    from ..core.climate.readers import open_dataset
    from ..core.errors import DataError
    from ..core.surface.contour import isosurface
    from ..core.surface.mesh import EXPORT_FORMATS

    out = Path(args.out)
    if out.suffix.lower() not in EXPORT_FORMATS:
        raise UsageError(f"-o must end in {', '.join(EXPORT_FORMATS)}, got {out.name!r}")
    if not np.isfinite(args.level):
        raise UsageError(f"--level must be a finite number, got {args.level}")
    exaggeration = DEFAULT_EXAGGERATION if args.exaggeration is None else args.exaggeration
    if not exaggeration >= 0:
        raise UsageError(f"--exaggeration must be >= 0, got {exaggeration}")
    if not args.radius > 0:
        raise UsageError(f"--radius must be > 0, got {args.radius}")

    ds = open_dataset(args.source, **reader_kwargs(args))
    values = ds.read(args.var, args.time)
    name = ds.resolve(args.var)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        raise DataError(f"every value at time step {args.time} is missing (NaN): nothing to contour", path=ds.source,
                        field=name)
    lo, hi = float(finite.min()), float(finite.max())
    if not lo <= args.level <= hi:
        raise DataError(f"level {args.level:g} is outside the data range {lo:g}..{hi:g} at time step {args.time}: "
                        "the contour would be empty", path=ds.source, field=name)
    attributes = {"altitude": ds.grid.height.astype(np.float32)}
    if args.color_var:
        attributes[args.color_var] = ds.read(args.color_var, args.time)
    points = ds.grid.points(radius=args.radius, exaggeration=exaggeration)
    periodic = ds.grid.periodic_lon
    mesh = isosurface(points, values, args.level, periodic_lon=periodic, close_poles=periodic,
                      method=args.method, attributes=attributes)
    if len(mesh.faces) == 0:
        raise DataError(f"the contour at level {args.level:g} is empty at time step {args.time} (values "
                        f"{lo:g}..{hi:g}; the level is only met next to missing values)", path=ds.source, field=name)
    mesh.save(out)
    when = np.datetime_as_string(ds.times[args.time], unit="h") if ds.times.size else "?"
    print(f"{out}: {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles "
          f"({args.var} = {args.level:g} at {when}, area {mesh.area():.4g})")
    return 0
