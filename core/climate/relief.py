"""Earth relief (land height and sea depth) for terrain-following grids and the globe.

The package ships a 1° version of NOAA's ETOPO60 relief
(``core/resources/relief_1deg.npz``, int16 metres, about 100 KB) so that the
demo needs no download.  :func:`load_etopo` reads the full ETOPO ``.cdf``
files (20' and 60') for users who want more detail, and :func:`write_relief`
rebuilds the shipped file from ``etopo60.cdf``::

    python -m nephele.core.climate.relief tests/data/terrain/etopo60.cdf core/resources/relief_1deg.npz

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (Fig. 1: clouds over a relief globe).
.. [2] NOAA National Geophysical Data Center, ETOPO5/ETOPO60 global relief,
   as distributed with Ferret (``ferret-datasets``).
"""

import io
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..files import atomic_write

RELIEF_FILE = Path(__file__).resolve().parent.parent / "resources" / "relief_1deg.npz"
"""The shipped 1° relief: arrays ``lon`` (360,), ``lat`` (180,), ``elevation`` int16 (180, 360)."""


def load_relief(path=RELIEF_FILE):
    """The shipped relief grid.

    Returns
    -------
    lon : (ni,) float64
        Cell-centre longitudes, ascending, in [0, 360).
    lat : (nj,) float64
        Cell-centre latitudes, ascending.
    elevation : (nj, ni) float64
        Metres above sea level; negative over the sea floor.
    """
    try:
        with np.load(path, allow_pickle=False) as f:
            return f["lon"].astype(np.float64), f["lat"].astype(np.float64), f["elevation"].astype(np.float64)
    except (OSError, KeyError, ValueError) as exc:
        raise DataError(f"cannot read relief file ({exc})", path=path, field="elevation") from exc


def _tidy_lon(lon, values, path):
    """Longitudes into [0, 360), ascending, with a repeated seam column dropped."""
    lon = np.mod(np.asarray(lon, dtype=np.float64), 360.0)
    order = np.argsort(lon, kind="stable")
    lon, values = lon[order], values[:, order]
    step = np.median(np.diff(lon))
    keep = np.concatenate([[True], np.diff(lon) > 0.5 * step])
    lon, values = lon[keep], values[:, keep]
    if lon[-1] - lon[0] > 360.0 - 0.5 * step:  # the same meridian at both ends
        lon, values = lon[:-1], values[:, :-1]
    if not np.all(np.isfinite(lon)):
        raise DataError("has NaN longitudes", path=path, field="lon")
    return lon, values


def load_etopo(path):
    """Read an ETOPO relief ``.cdf`` (NetCDF 3, as shipped with Ferret).

    Finds the one 2-D variable (``ROSE`` in the Ferret files) and its two
    coordinate variables; missing values become NaN; longitudes are wrapped
    into [0, 360) and sorted, and the duplicated seam column of ``etopo20``
    (1081 columns for 360°) is dropped.

    Returns
    -------
    lon : (ni,) float64, lat : (nj,) float64, elevation : (nj, ni) float64 metres
    """
    from scipy.io import netcdf_file

    path = Path(path)
    if not path.is_file():
        raise DataError("file not found", path=path)
    try:
        return _read_etopo(netcdf_file, path)
    except (DataError, MemoryError):
        raise
    except Exception as exc:  # scipy's reader raises many types (IndexError, KeyError...) for damaged bytes
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        raise DataError(f"not a NetCDF 3 relief file ({type(exc).__name__}: {first})", path=path) from exc


class _Bounded(io.FileIO):
    """A file whose ``read(n)`` never asks for more than the bytes left: scipy's reader passes sizes from
    the header to ``read``, which allocates that much first (a damaged header claiming terabytes)."""

    def read(self, n=-1):
        if n is not None and n > 0:
            n = min(n, max(os.fstat(self.fileno()).st_size - self.tell(), 0))
        return super().read(n)


def _read_etopo(netcdf_file, path):
    with _Bounded(path, "r") as raw, netcdf_file(raw, "r", mmap=False) as f:
        fields = [n for n, v in f.variables.items() if len(v.dimensions) == 2]
        if len(fields) != 1:
            raise DataError(f"expected one 2-D relief variable, found {fields}", path=path, field="elevation")
        name = fields[0]
        var = f.variables[name]
        ydim, xdim = var.dimensions
        if ydim not in f.variables or xdim not in f.variables:
            raise DataError(f"coordinate variables {ydim!r}/{xdim!r} are missing", path=path, field=name)
        z = np.array(var.data, dtype=np.float64)
        for key in ("missing_value", "_FillValue"):
            if key in var._attributes:
                z[z == float(np.asarray(var._attributes[key]).ravel()[0])] = np.nan
        lat = np.array(f.variables[ydim].data, dtype=np.float64)
        lon = np.array(f.variables[xdim].data, dtype=np.float64)
    if not np.all(np.isfinite(lat)):
        raise DataError("has NaN latitudes", path=path, field=ydim)
    if lat[0] > lat[-1]:
        lat, z = lat[::-1], z[::-1]
    if not np.all(np.diff(lat) > 0):
        raise DataError("latitudes are not monotonic", path=path, field=ydim)
    lon, z = _tidy_lon(lon, z, path)
    return lon, lat, z


def write_relief(etopo_path, out_path=RELIEF_FILE):
    """Make the shipped 1° relief from ``etopo60.cdf``: int16 metres, compressed npz, written atomically."""
    lon, lat, z = load_etopo(etopo_path)
    if np.isnan(z).any():
        raise DataError("has missing values; cannot make a complete relief", path=etopo_path, field="elevation")
    out_path = Path(out_path)
    with atomic_write(out_path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, lon=lon.astype(np.float32), lat=lat.astype(np.float32),
                            elevation=np.rint(z).astype(np.int16))
    return out_path


def sample_relief(lon, lat, relief=None):
    """Bilinear relief (metres) at any longitudes/latitudes (degrees).

    Longitude is periodic (any value, wraps across the seam); beyond the first
    and last latitude rows the value is held constant toward the pole.

    Parameters
    ----------
    lon, lat : array_like
        Broadcast together.
    relief : (lon, lat, elevation), optional
        A grid as returned by :func:`load_relief` or :func:`load_etopo`
        (longitudes evenly spaced covering the full circle); the shipped
        relief by default.
    """
    glon, glat, z = load_relief() if relief is None else relief
    lon, lat = np.broadcast_arrays(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
    ni, nj = glon.size, glat.size
    dlon = 360.0 / ni
    x = np.mod(lon - glon[0], 360.0) / dlon
    i0 = np.floor(x).astype(np.intp)
    fx = x - i0
    i0 %= ni
    dlat = np.diff(glat)
    if np.allclose(dlat, dlat[0], rtol=1e-6):  # evenly spaced: no search needed
        y = np.clip((lat - glat[0]) / dlat[0], 0.0, nj - 1.0)
    else:
        y = np.interp(lat, glat, np.arange(nj, dtype=np.float64))
    j0 = np.minimum(np.floor(y).astype(np.intp), nj - 2)
    fy = y - j0
    # Flat indices into a copy whose last column repeats the first: one gather per corner.
    flat = np.concatenate([z, z[:, :1]], axis=1).ravel()
    i = j0 * (ni + 1) + i0
    top = flat[i] * (1.0 - fx) + flat[i + 1] * fx
    bottom = flat[i + ni + 1] * (1.0 - fx) + flat[i + ni + 2] * fx
    return top * (1.0 - fy) + bottom * fy


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: python -m nephele.core.climate.relief ETOPO60.cdf [OUT.npz]")
    print(write_relief(*sys.argv[1:]))
