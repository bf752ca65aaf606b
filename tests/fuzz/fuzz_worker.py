"""The fuzz worker: reads one case per line on stdin, runs the reader, answers one JSON line.

Run by :class:`fuzzlib.Runner`; its data segment is limited to ``argv[1]``
bytes above its size once the readers' libraries are imported, so a case
that tries to allocate more gets a ``MemoryError`` (a finding) instead of
swapping the machine.
"""

import json
import os
import resource
import sys
import threading
import traceback
import warnings

import numpy as np


def _climate(path):
    from nephele.core.climate import open_dataset

    ds = open_dataset(path)
    try:
        names = sorted(ds.variables)
        for name in names[:8]:
            ds.read(name, 0)
        if ds.times.size > 1 and names:
            ds.read(names[0], ds.times.size - 1)
    finally:
        close = getattr(ds, "close", None)
        if close is not None:
            close()


def _relief(path):
    from nephele.core.climate.relief import load_etopo

    load_etopo(path)


def _pqr(path):
    from nephele.core.muscle.molecules import atom_gaussians, read_pqr

    atom_gaussians(read_pqr(path))


def _vtu(path):
    from nephele.core.flowvol.unstructured import UnstructuredVelocity

    v = UnstructuredVelocity(path)
    lo, hi = v.bounds[:, 0], v.bounds[:, 1]
    v(lo + np.linspace(0.0, 1.0, 7)[:, None] * (hi - lo), 0.0)
    v.updraft()


def _selftest(path):
    """The harness's own check: a hang, a crash and an allocation over the limit, by the file's word."""
    import os
    import time

    word = open(path).read()
    if word == "spin":
        t = time.process_time()
        while time.process_time() - t < 60:
            pass
    elif word == "crash":
        os.abort()
    elif word == "allocate":
        np.ones(3 << 30, dtype=np.uint8)


TARGETS = {"selftest": _selftest, "netcdf": _climate, "grib": _climate, "zarr": _climate, "grads": _climate,
           "relief": _relief, "pqr": _pqr, "vtu": _vtu}


def _data_size():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmData:"):
                return int(line.split()[1]) * 1024
    return 0


def main():
    limit = int(sys.argv[1])
    warnings.simplefilter("ignore")
    import logging

    logging.disable(logging.CRITICAL)
    from nephele.core.errors import DataError

    for module in ("xarray", "netCDF4", "scipy.io", "cfgrib", "zarr"):  # imported before the limit is set
        try:
            __import__(module)
        except ImportError:
            pass
    try:
        base = _data_size()
        resource.setrlimit(resource.RLIMIT_DATA, (base + limit, resource.RLIM_INFINITY))
    except (OSError, ValueError):
        pass
    print(json.dumps({"status": "ready"}), flush=True)
    for line in sys.stdin:
        case = json.loads(line)
        try:
            TARGETS[case["target"]](case["path"])
            out = {"status": "ok"}
        except DataError as exc:
            out = {"status": "data_error", "detail": str(exc)[:300]}
        except MemoryError:
            out = {"status": "memory", "detail": "".join(traceback.format_exc(limit=-6))[-2000:]}
        except Exception as exc:  # noqa: BLE001 - any other type escaping a reader is the finding
            out = {"status": "bug", "type": type(exc).__name__,
                   "detail": "".join(traceback.format_exc(limit=-6))[-2000:]}
        stuck = [t for t in threading.enumerate() if t.name == "nephele-hdf5-header"]
        if stuck:
            out["restart"] = True  # its reading thread spins on: a fresh worker for the next case
        print(json.dumps(out), flush=True)
        if stuck:
            os._exit(0)


if __name__ == "__main__":
    main()
