"""Zarr stores (directories ``*.zarr``) through xarray, read like CF NetCDF.

A Zarr store written from a CF dataset (``xarray.Dataset.to_zarr``) keeps its
variables and attributes, so :class:`~nephele.core.climate.netcdf.NetCDFDataset`
reads it the same way as the NetCDF file it came from: lazily, one chunked
step at a time.

References
----------
.. [1] Zarr storage specification v2/v3, https://zarr.dev
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

from ..errors import DataError
from .netcdf import NetCDFDataset


def open_zarr_store(path, **kw):
    """Open a Zarr store as a lazy :class:`~nephele.core.climate.netcdf.NetCDFDataset`.

    Raises
    ------
    DataError
        zarr missing, or not a readable store, naming the path.
    """
    import xarray as xr

    if kw.pop("level_type", None) is not None:
        raise DataError("level_type= chooses among the kinds of level of a GRIB file, not of a Zarr store", path=path,
                        field="level_type")
    try:
        import zarr  # noqa: F401  (xarray's zarr engine needs it; say so in one line)
    except ImportError:
        raise DataError("reading Zarr stores needs the zarr package ('pip install zarr')", path=path) from None
    try:
        ds = xr.open_zarr(path, decode_times=False, mask_and_scale=True, consolidated=None)
    except Exception as exc:  # zarr raises many types for a bad store
        first = (str(exc).strip().splitlines() or [""])[0]
        raise DataError(f"cannot open as a Zarr store ({type(exc).__name__}: {first})", path=path) from exc
    return NetCDFDataset(path, opened=ds, **kw)


__all__ = ["open_zarr_store"]
