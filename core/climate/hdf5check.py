"""NetCDF headers checked before the C library reads them.

A NetCDF 3 header (``CDF\x01``/``CDF\x02``) is walked in Python first
(:func:`check_classic`): fuzzing found a header whose dimension count was
flipped to 67 million, for which netCDF-C allocates gigabytes and, when that
fails under a memory limit, crashes the process (SIGSEGV).  A NetCDF-4 (HDF5)
file's header is read under a watchdog (:func:`check_header`).

Fuzzing the readers found a one-byte change in the header of a NetCDF-4 file
(``tests/data/toa_brightness_stereographic.nc``, byte 3479) that makes the HDF5
library loop without end inside ``nc_open``: no error, no return, the process (or
Blender) stuck.  C code cannot be interrupted from Python, but netCDF4 releases
the GIL while it opens, so :func:`check_header` opens the file in a helper thread
and gives up after :data:`HEADER_SECONDS` with one clear line.  The stuck thread
keeps one core busy until the process ends (it touches only that file: other
files, HDF5 ones too, open and read meanwhile), which the message says.  At exit
the process then ends at once with status 1 (:func:`os._exit`): HDF5's own exit
handler would free what the stuck thread still reads and crash (SIGSEGV).
``nephele`` commands exit with their own status (:func:`nephele.farm.cli.main`).
"""

import atexit
import os
import sys
import threading

from ..errors import DataError

HEADER_SECONDS = 8.0
"""Longest a header may take to read: a whole file's header reads in milliseconds, even on a loaded machine."""
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
STUCK = []
"""Paths whose header read never returned (their threads are still running)."""


def check_header(path, seconds=HEADER_SECONDS):
    """Raise :class:`~nephele.core.errors.DataError` when the HDF5 library does not finish reading
    ``path``'s header within ``seconds``; files not in the HDF5 format (NetCDF 3) pass at once."""
    with open(path, "rb") as f:
        if f.read(8) != HDF5_MAGIC:
            return
    try:
        import netCDF4
    except ImportError:
        return  # xarray then picks another engine (h5netcdf) or says netCDF4 is missing

    def probe():
        try:
            netCDF4.Dataset(str(path)).close()
        except Exception:  # noqa: BLE001 - the reader itself reports a header that fails
            pass

    t = threading.Thread(target=probe, name="nephele-hdf5-header", daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        if not STUCK:
            atexit.register(end_now, 1)
        STUCK.append(str(path))
        raise DataError(f"the HDF5 library did not finish reading the file's header in {seconds:g} s: the file is "
                        "damaged (its reading thread keeps one CPU busy until this program ends)", path=path)


def end_now(status):
    """End the process with ``status`` at once when a header read is stuck (see the module docstring)."""
    if STUCK:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)


def check_classic(path):
    """Raise :class:`~nephele.core.errors.DataError` unless ``path``'s NetCDF 3 header (dimensions, attributes,
    variables and where their data lie) reads whole in pure Python; other formats pass at once.

    scipy's reader walks the header (never reading more than the file holds, see
    :class:`~nephele.core.climate.relief._Bounded`) and maps the data without reading it: milliseconds.
    """
    import warnings

    with open(path, "rb") as f:
        if f.read(4) not in (b"CDF\x01", b"CDF\x02"):
            return
    try:
        from scipy.io import netcdf_file
    except ImportError:
        return
    from .relief import _Bounded

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns when mapped arrays outlive the file: none are kept
            with _Bounded(path, "r") as raw, netcdf_file(raw, "r", mmap=True) as nc:
                nc.variables.clear()
    except Exception as exc:  # noqa: BLE001 - any failure of the pure-Python walk is a damaged header
        first = (str(exc).strip().splitlines() or [""])[0][:160]
        raise DataError(f"cannot open as NetCDF (damaged NetCDF 3 header: {type(exc).__name__}: {first})",
                        path=path) from None


__all__ = ["check_classic", "check_header", "end_now"]
