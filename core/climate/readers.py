"""Open climate data: the embedded demo, CF NetCDF files and GrADS ``.ctl``/``.dat`` files.

:func:`open_dataset` is the one entry point; every reader returns a lazy
:class:`~nephele.core.climate.dataset.Dataset` that reads one time step of one field
at a time.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import math
from pathlib import Path
from urllib.parse import parse_qsl, urlencode

from ..errors import DataError
from .synthetic import SIZES, demo_dataset

GRIB_SUFFIXES = (".grib", ".grib1", ".grib2", ".grb", ".grb1", ".grb2")
OVERRIDES = ("vertical", "p0", "time_units", "radius", "variables", "level_type", "member")
"""Keywords of :func:`open_dataset` that override what a NetCDF, GRIB or Zarr file gets wrong or leaves out,
or choose what to read from it (``level_type`` of a GRIB file, ensemble ``member``)."""
OVERRIDE_FIELDS = {"vertical": "vertical coordinate", "p0": "P0", "time_units": "time units",
                   "radius": "earth radius", "variables": "variable map", "level_type": "level type",
                   "member": "member"}
"""How an override is named in messages (the Blender panel's labels)."""
VERTICAL_CHOICES = ("pressure_hpa", "pressure_pa", "height_m", "height_km", "ncar_hybrid")
"""What ``vertical=`` may say (:data:`~nephele.core.climate.netcdf.VERTICAL_KINDS`, kept here without xarray)."""


def parse_var_map(text, path=None):
    """``"temperature=T2, rh=RH"`` as ``{"temperature": "T2", "rh": "RH"}`` (commas or new lines between pairs)."""
    mapping = {}
    for item in str(text or "").replace("\n", ",").split(","):
        if not item.strip():
            continue
        std, sep, raw = item.partition("=")
        if not (sep and std.strip() and raw.strip()):
            raise DataError(f"must look like STD=NAME (e.g. temperature=T2), got {item.strip()!r}", path=path,
                            field=OVERRIDE_FIELDS["variables"])
        mapping[std.strip()] = raw.strip()
    return mapping


def check_overrides(path=None, *, vertical=None, p0=None, time_units=None, radius=None, variables=None, level_type=None,
                    member=None):
    """The overrides given (not ``None``/empty), checked, as keywords of :func:`open_dataset`.

    Parameters
    ----------
    path : str, optional
        The file they are for (named in errors).
    vertical, p0, time_units, radius, variables
        As :class:`~nephele.core.climate.netcdf.NetCDFDataset` takes them:
        a :data:`VERTICAL_CHOICES` entry, P0 in Pa (> 0), CF time units
        (``"<unit> since <date>"``, months and years too), the planet radius in metres (1e5..1e9:
        a radius in km is the likely slip), ``{standard name: file variable}``
        or its text form for :func:`parse_var_map`.
    level_type : str
        The GRIB kind of level to read (ecCodes ``typeOfLevel``, e.g. ``"hybrid"``).
    member : int
        The ensemble member to read (>= 0).

    Raises
    ------
    DataError
        One line naming the file and the override.
    """

    def bad(key, problem):
        return DataError(problem, path=path, field=OVERRIDE_FIELDS[key])

    kw = {}
    if vertical:
        if vertical not in VERTICAL_CHOICES:
            raise bad("vertical", f"{vertical!r} is not one of {', '.join(VERTICAL_CHOICES)}")
        kw["vertical"] = str(vertical)
    if p0 is not None:
        if not (isinstance(p0, (int, float)) and math.isfinite(p0) and p0 > 0):
            raise bad("p0", f"must be a pressure > 0 in Pa (e.g. 100000), got {p0!r}")
        kw["p0"] = float(p0)
    if time_units and str(time_units).strip():
        from .gridfile import cf_times, parse_iso
        from .netcdf import _MONTHS_SINCE

        units, field = str(time_units).strip(), OVERRIDE_FIELDS["time_units"]
        try:
            months = _MONTHS_SINCE.match(units)  # calendar months/years, which the reader takes through cftime
            parse_iso(months.group(2), path, field) if months else cf_times([0.0], units, None, path, field)
        except DataError as exc:
            raise bad("time_units", exc.problem) from None
        kw["time_units"] = str(time_units).strip()
    if radius is not None:
        if not (isinstance(radius, (int, float)) and 1e5 <= radius <= 1e9):
            raise bad("radius", f"is in metres (e.g. 6371229), got {radius!r}")
        kw["radius"] = float(radius)
    if isinstance(variables, str):
        variables = parse_var_map(variables, path)
    if variables:
        kw["variables"] = dict(variables)
    if level_type is not None and str(level_type).strip():
        if not str(level_type).strip().isidentifier():
            raise bad("level_type",
                      f"must be an ecCodes typeOfLevel such as isobaricInhPa or hybrid, got {level_type!r}")
        kw["level_type"] = str(level_type).strip()
    if member is not None and member != "":
        try:
            number = int(member)
        except (TypeError, ValueError):
            number = -1
        if number < 0 or str(number) != str(member).strip():
            raise bad("member", f"must be a whole number >= 0 (0 is the control), got {member!r}")
        kw["member"] = number
    return kw


def override_source(source, **kw):
    """The source name of ``source`` read with the overrides ``kw``: ``SOURCE?key=value&...``.

    The same name ``nephele`` commands give such a dataset; :func:`open_dataset`
    opens it in any process (a saved scene, a farm worker).  A trailing
    ``&file=ID`` (the CLI's file identity for cache keys) is allowed and ignored.
    """
    flat = {k: (",".join(f"{s}:{r}" for s, r in sorted(v.items())) if isinstance(v, dict) else v)
            for k, v in sorted(kw.items())}
    return f"{source}?{urlencode(flat)}" if flat else str(source)


def split_source(text):
    """``(path, overrides)`` of a name made by :func:`override_source` (``(text, {})`` for a plain one)."""
    text = str(text)
    base, sep, query = text.partition("?")
    if not sep or Path(text).exists():
        return text, {}
    kw = {}
    for key, value in parse_qsl(query, keep_blank_values=True):
        if key == "file":
            continue
        if key not in OVERRIDES:
            raise DataError(f"unknown override {key!r} in the source name (known: {', '.join(OVERRIDES)})", path=base)
        if key == "member":
            pass  # check_overrides reads and checks the number
        elif key in ("p0", "radius"):
            try:
                value = float(value)
            except ValueError:
                raise DataError(f"is not a number: {value!r}", path=base, field=OVERRIDE_FIELDS[key]) from None
        elif key == "variables":
            value = parse_var_map(value.replace(":", "="), base)
        kw[key] = value
    return base, check_overrides(base, **kw)


def open_dataset(source, **kw):
    """Open ``source`` as a :class:`~nephele.core.climate.dataset.Dataset`.

    Parameters
    ----------
    source : str or os.PathLike
        ``"demo"`` (the synthetic 320×160×19 climate, 240 hourly steps),
        ``"demo:small"`` (64×32×8, 48 steps, for tests), a CF NetCDF file
        (``.nc``, ``.nc4``, ``.cdf``; or a ``.zip`` of them as the Copernicus
        Climate Data Store delivers ERA5), a GRIB file (``.grib``, ``.grib2``,
        ``.grb``, ``.grb2``; needs ecCodes), a Zarr store
        (``.zarr`` directory; needs zarr) or a GrADS descriptor (``.ctl``).
        It may also be a name from :func:`override_source`
        (``path?radius=6371220&...``): the file opened with those overrides.
    vertical : str, optional
        NetCDF and Zarr: what the level coordinate is when the file does not
        say: ``"pressure_hpa"``, ``"pressure_pa"``, ``"height_m"``,
        ``"height_km"`` or ``"ncar_hybrid"``.
    p0 : float, optional
        NetCDF and Zarr: reference pressure of hybrid levels (Pa).
    time_units : str, optional
        NetCDF and Zarr: CF time units, such as ``"days since 1988-01-01"``.
    radius : float, optional
        Planet radius (m), replacing the file's.
    variables : dict, optional
        Standard name → the file's variable name where the names are not
        recognised, e.g. ``{"temperature": "T2"}``.
    level_type : str, optional
        GRIB: the ecCodes ``typeOfLevel`` to read (``"isobaricInhPa"``,
        ``"hybrid"``...); by default the kind of level with the most 3-D
        variables (``nephele info`` lists them).
    member : int, optional
        NetCDF, Zarr and GRIB: the ensemble member; by default the control
        (0) or the lowest.
    **kw
        Passed to the reader: for the demo ``seed``; for files ``rh_crit``
        (Sundqvist's critical relative humidity, one value or one per level).

    Returns
    -------
    Dataset
        Lazy: fields are read one time step at a time.

    Raises
    ------
    DataError
        Missing file, unknown format or bad contents, naming file and field;
        an override the format does not take (GrADS takes none; GRIB states
        its levels and times, so not ``vertical``, ``p0`` or ``time_units``).
    """
    text, named = split_source(source)
    if named:
        both = sorted(set(named) & set(kw))
        if both:
            raise DataError(f"overrides {', '.join(both)} given twice (in the source name and as arguments)", path=text)
        kw = {**named, **kw}
        source = text
    given = sorted(k for k in OVERRIDES if k in kw)
    if text == "demo" or text.startswith("demo:"):
        size = text.partition(":")[2] or "full"
        if size not in SIZES:
            raise DataError(f"unknown demo size {size!r} (choose from {', '.join(SIZES)})", path=text)
        if given:
            raise DataError(f"the demo takes no file overrides ({', '.join(given)})", path=text)
        return demo_dataset(size, **kw)
    path = Path(source)
    opener, kind = _opener(path)
    if kind == "GrADS" and given:
        raise DataError(f"GrADS files take no overrides ({', '.join(given)}); they apply to NetCDF, GRIB and Zarr",
                        path=path)
    try:
        return opener(path, **kw)
    except (DataError, MemoryError, ImportError):
        raise
    except Exception as exc:  # the readers' libraries raise many types for damaged bytes (netCDF4: "HDF error")
        if isinstance(exc, TypeError) and "keyword argument" in str(exc):
            raise  # the caller's slip, not the file's
        raise DataError(f"cannot read as {kind} ({type(exc).__name__}: {_first_line(exc)})", path=path) from exc


def _first_line(exc):
    return (str(exc).strip().splitlines() or [""])[0][:200]


def _netcdf(path, **kw):
    import xarray  # noqa: F401  (a missing extra is said first: 'pip install nephele[data]')

    from .hdf5check import check_classic, check_header
    from .netcdf import open_netcdf

    check_classic(path)  # netCDF-C trusts a NetCDF 3 header's counts (and crashes when their memory fails)
    check_header(path)  # libhdf5 loops forever on some damaged headers: refuse them in seconds
    return open_netcdf(path, **kw)


def _grib(path, **kw):
    from .grib import open_grib
    from .gribcheck import check_grib

    check_grib(path)  # ecCodes crashes on some damaged messages: refuse them first
    return open_grib(path, **kw)


def _opener(path):
    """The reader of ``path`` by its suffix and the format's name; DataError when missing or unknown."""
    suffix = path.suffix.lower()
    if suffix in (".nc", ".nc4", ".cdf", ".netcdf", ".zip"):
        if not path.is_file():
            raise DataError("file not found", path=path)
        return _netcdf, "NetCDF"
    if suffix == ".zarr":
        if not path.exists():
            raise DataError("file not found", path=path)
        from .zarrstore import open_zarr_store

        return open_zarr_store, "a Zarr store"
    if suffix in GRIB_SUFFIXES:
        if not path.is_file():
            raise DataError("file not found", path=path)
        return _grib, "GRIB"
    if suffix == ".ctl":
        if not path.is_file():
            raise DataError("file not found", path=path)
        from .grads import open_grads

        return open_grads, "GrADS"
    if not path.exists():
        raise DataError("file not found", path=path)
    raise DataError(f"unknown format {suffix or '(no extension)'!r}: expected demo, .nc, .zip (of NetCDF), .grib2, "
                    ".zarr or .ctl", path=path)


__all__ = ["OVERRIDES", "check_overrides", "open_dataset", "override_source", "parse_var_map", "split_source"]
