"""Command-line options overriding what a data file gets wrong or leaves out.

The same overrides as :func:`nephele.core.climate.readers.open_dataset` takes
(``vertical=``, ``p0=``, ``time_units=``, ``radius=``, ``variables=``, and the
choices ``level_type=`` of a GRIB file and ensemble ``member=``), shared
by ``info``, ``contour``, ``volume`` and ``advect`` (``--vertical-coord`` because
``advect --vertical`` chooses how points move vertically).  ``--earth-radius`` is the
planet radius in metres (``--radius`` of the drawing commands is the globe's
radius in scene units).
"""

from ..core.errors import UsageError

VERTICAL_CHOICES = ("pressure_hpa", "pressure_pa", "height_m", "height_km", "ncar_hybrid")
"""Mirror of :data:`nephele.core.climate.netcdf.VERTICAL_KINDS` (kept here so ``--help`` needs no xarray)."""


def add_reader_options(p):
    """Add ``--vertical-coord``, ``--p0``, ``--time-units``, ``--earth-radius``, ``--var-map``, ``--level-type`` and
    ``--member`` to parser ``p``."""
    g = p.add_argument_group("reading the file (override what it gets wrong or leaves out)")
    g.add_argument("--vertical-coord", dest="read_vertical", choices=VERTICAL_CHOICES, metavar="KIND",
                   help=f"what the level coordinate is when the file does not say ({', '.join(VERTICAL_CHOICES)})")
    g.add_argument("--p0", type=float, metavar="PA",
                   help="reference pressure of hybrid levels in Pa (default: the file's, else 100000)")
    g.add_argument("--time-units", metavar="UNITS",
                   help='CF time units replacing the file\'s, e.g. "days since 1988-01-01"')
    g.add_argument("--earth-radius", type=float, metavar="M",
                   help="planet radius in metres (default: the file's grid mapping or model convention, else 6371000)")
    g.add_argument("--var-map", action="append", default=[], metavar="STD=NAME",
                   help="read the file's variable NAME as the standard field STD (e.g. temperature=T2); repeatable")
    g.add_argument("--level-type", metavar="KIND",
                   help="GRIB: the kind of level to read, e.g. isobaricInhPa or hybrid (default: the one with the most "
                        "3-D fields; 'nephele info' lists them)")
    g.add_argument("--member", type=int, metavar="N",
                   help="ensemble member to read (default: the control, 0, or the lowest)")


def reader_kwargs(args):
    """The keyword arguments of :func:`~nephele.core.climate.readers.open_dataset` that ``args`` asks for."""
    kw = {}
    if getattr(args, "read_vertical", None):
        kw["vertical"] = args.read_vertical
    if getattr(args, "p0", None) is not None:
        if not args.p0 > 0:
            raise UsageError(f"--p0 must be > 0 Pa, got {args.p0}")
        kw["p0"] = args.p0
    if getattr(args, "time_units", None):
        kw["time_units"] = args.time_units
    if getattr(args, "earth_radius", None) is not None:
        if not 1e5 <= args.earth_radius <= 1e9:  # a radius in km (6371) is the likely slip
            raise UsageError(f"--earth-radius is in metres (e.g. 6371229), got {args.earth_radius}")
        kw["radius"] = args.earth_radius
    mapping = {}
    for item in getattr(args, "var_map", None) or ():
        std, sep, raw = item.partition("=")
        if not (sep and std.strip() and raw.strip()):
            raise UsageError(f"--var-map must look like STD=NAME (e.g. temperature=T2), got {item!r}")
        mapping[std.strip()] = raw.strip()
    if mapping:
        kw["variables"] = mapping
    if getattr(args, "level_type", None):
        kw["level_type"] = args.level_type
    if getattr(args, "member", None) is not None:
        if args.member < 0:
            raise UsageError(f"--member must be >= 0 (0 is the control), got {args.member}")
        kw["member"] = args.member
    return kw


def open_with_overrides(args):
    """The dataset of ``args.source`` opened with the overrides, and the source name the tasks use
    (:func:`~nephele.core.pipeline.sources.open_with_overrides`)."""
    from ..core.pipeline.sources import open_with_overrides

    return open_with_overrides(args.source, **reader_kwargs(args))


__all__ = ["add_reader_options", "open_with_overrides", "reader_kwargs"]
