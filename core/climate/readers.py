"""Open climate data: the embedded demo, CF NetCDF files and GrADS ``.ctl``/``.dat`` files.

:func:`open_dataset` is the one entry point; every reader returns a lazy
:class:`~nephele.core.climate.dataset.Dataset` that reads one time step of one field
at a time.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

from pathlib import Path

from ..errors import DataError
from .synthetic import SIZES, demo_dataset

GRIB_SUFFIXES = (".grib", ".grib1", ".grib2", ".grb", ".grb1", ".grb2")


def open_dataset(source, **kw):
    """Open ``source`` as a :class:`~nephele.core.climate.dataset.Dataset`.

    Parameters
    ----------
    source : str or os.PathLike
        ``"demo"`` (the synthetic 320×160×19 climate, 240 hourly steps),
        ``"demo:small"`` (64×32×8, 48 steps, for tests), a CF NetCDF file
        (``.nc``, ``.nc4``, ``.cdf``), a GRIB file (``.grib``, ``.grib2``,
        ``.grb``, ``.grb2``; needs cfgrib + ecCodes), a Zarr store
        (``.zarr`` directory; needs zarr) or a GrADS descriptor (``.ctl``).
    **kw
        Passed to the reader: for the demo ``seed``; for NetCDF and GRIB the
        overrides of what a file gets wrong or leaves out, ``p0=`` (Pa,
        reference pressure of hybrid levels) and ``time_units=`` (CF units
        such as ``"days since 1988-01-01"``); for GRIB also ``level_type=``.

    Raises
    ------
    DataError
        Missing file, unknown format or bad contents, naming file and field.
    """
    text = str(source)
    if text == "demo" or text.startswith("demo:"):
        size = text.partition(":")[2] or "full"
        if size not in SIZES:
            raise DataError(f"unknown demo size {size!r} (choose from {', '.join(SIZES)})", path=text)
        return demo_dataset(size, **kw)
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix in (".nc", ".nc4", ".cdf", ".netcdf"):
        if not path.is_file():
            raise DataError("file not found", path=path)
        from .netcdf import open_netcdf

        return open_netcdf(path, **kw)
    if suffix == ".zarr":
        if not path.exists():
            raise DataError("file not found", path=path)
        from .zarrstore import open_zarr_store

        return open_zarr_store(path, **kw)
    if suffix in GRIB_SUFFIXES:
        if not path.is_file():
            raise DataError("file not found", path=path)
        from .grib import open_grib

        return open_grib(path, **kw)
    if suffix == ".ctl":
        if not path.is_file():
            raise DataError("file not found", path=path)
        from .grads import open_grads

        return open_grads(path, **kw)
    if not path.exists():
        raise DataError("file not found", path=path)
    raise DataError(f"unknown format {suffix or '(no extension)'!r}: expected demo, .nc, .grib2, .zarr or .ctl", path=path)


__all__ = ["open_dataset"]
