"""GRIB1/GRIB2 files through cfgrib and ecCodes, read like CF NetCDF.

cfgrib turns each GRIB hypercube (fields sharing one kind of level:
``isobaricInhPa``, ``hybrid``, ``heightAboveGround``…) into a CF-style
xarray dataset; :func:`open_grib` takes the one with the most 3-D fields (or
the ``level_type=`` asked for) and hands it to
:class:`~nephele.core.climate.netcdf.NetCDFDataset`, so pressure levels, units and
names are understood the same way.  Regular latitude/longitude and Gaussian
grids are read, and projected grids (Lambert conformal, polar stereographic)
as curvilinear grids on the 2-D latitude/longitude ecCodes computes; reduced
(thinned) grids are refused with one clear line, as are files when cfgrib or
ecCodes is missing.

References
----------
.. [1] ECMWF, cfgrib: https://github.com/ecmwf/cfgrib (GRIB to CF mapping).
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import logging
import warnings

from ..errors import DataError
from .netcdf import NetCDFDataset

_REGULAR = ("regular_ll", "regular_gg")


def _cubes(path):
    try:
        import cfgrib
    except ImportError as exc:  # cfgrib also fails to import when the ecCodes library is missing
        raise DataError(f"reading GRIB needs cfgrib and ecCodes ('pip install cfgrib eccodes'): {exc}", path=path) from None
    # cfgrib logs a traceback per corrupted message and skips it; the user gets one line instead.
    log = logging.getLogger("cfgrib")
    level = log.level
    log.setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # xarray's merge defaults inside cfgrib, not the user's concern
            cubes = cfgrib.open_datasets(str(path), backend_kwargs={"indexpath": ""}, decode_times=False)
    except Exception as exc:  # ecCodes raises its own types for bad messages
        first = (str(exc).strip().splitlines() or [""])[0]
        raise DataError(f"cannot open as GRIB ({type(exc).__name__}: {first})", path=path) from exc
    finally:
        log.setLevel(level)
    if not cubes:
        raise DataError("cannot open as GRIB (no readable GRIB message: corrupted or not GRIB)", path=path)
    return cubes


def _level_type(cube):
    for var in cube.data_vars.values():
        return str(var.attrs.get("GRIB_typeOfLevel", "unknown"))
    return "none"


def open_grib(path, *, level_type=None, **kw):
    """Open a GRIB file as a lazy :class:`~nephele.core.climate.netcdf.NetCDFDataset`.

    Parameters
    ----------
    path : path
    level_type : str, optional
        The GRIB ``typeOfLevel`` to read (``"isobaricInhPa"``, ``"hybrid"``…);
        by default the kind of level with the most 3-D fields.
    **kw
        Passed to :class:`~nephele.core.climate.netcdf.NetCDFDataset` (``p0``, ``time_units``…).

    Raises
    ------
    DataError
        cfgrib/ecCodes missing, not GRIB, no 3-D field, or a grid that is not
        regular latitude/longitude.
    """
    found = {}
    for cube in _cubes(path):
        found.setdefault(_level_type(cube), (sum(var.ndim >= 3 for var in cube.data_vars.values()), cube))
    if level_type is not None:
        if level_type not in found:
            raise DataError(f"no fields on level type {level_type!r} (found: {', '.join(sorted(found))})", path=path, field="level_type")
        n3, cube = found[level_type]
    else:
        level_type, (n3, cube) = max(found.items(), key=lambda kv: kv[1][0], default=(None, (0, None)))
    # Projected grids (polar stereographic, Lambert conformal) come with cfgrib's 2-D latitude/longitude: curvilinear.
    two_d = cube is not None and all(n in cube.coords and cube[n].ndim == 2 for n in ("latitude", "longitude"))
    for name, var in (cube.data_vars.items() if cube is not None else ()):
        grid = str(var.attrs.get("GRIB_gridType", "unknown"))
        if grid not in _REGULAR and not two_d:
            raise DataError(
                f"grid type {grid!r} ({var.attrs.get('GRIB_gridDefinitionDescription', '')}) is not supported; "
                "regular latitude/longitude, Gaussian and projected grids with 2-D latitude/longitude are read",
                path=path,
                field=name,
            )
    if n3 == 0:
        raise DataError(f"no 3-D field (level types: {', '.join(sorted(found)) or 'none'})", path=path, field="variables")
    return NetCDFDataset(path, opened=cube, **kw)


__all__ = ["open_grib"]
