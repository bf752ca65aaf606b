"""Readers on real files (issue 17): time to open a file and read one 3-D step of one field, with
the error against the same array read by plain xarray (the anchor, measured in the same run).

Files: the CAM history file (NCAR hybrid levels), the NCL sample (non-CF time, kelvin labelled
degC), the UM rotated-pole hybrid-height file, the ECHAM5 pressure-level file from tests/data,
a Zarr store and a 3-level GRIB2 file written from them, and a projection-only Lambert conformal
file (positions from the inverse projection).  Writes the section ``readers`` of
docs/benchmarks.md; ``--quick`` runs one repeat and writes nothing.

    .venv/bin/python benchmarks/bench_readers.py [--quick]
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

from report import md_table, write_section  # noqa: E402

from nephele.core.climate.readers import open_dataset  # noqa: E402

DATA = ROOT / "tests" / "data"


def best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def nephele_read(path, var):
    t0 = time.perf_counter()
    ds = open_dataset(path)
    t1 = time.perf_counter()
    a = ds.read(var, 0)
    return t1 - t0, time.perf_counter() - t1, ds, a


def anchor(opened, ds, raw):
    """The file's own array of step 0 in the reader's (level, lat, lon) order, float32."""
    var = opened[raw]
    tdim = ds._time_dim
    if tdim in var.dims:
        var = var.isel({tdim: 0})
    a = np.asarray(var.transpose(*ds._dims).values, dtype=np.float32)
    return a[np.ix_(*ds._order)]


def row(name, path, var, open_anchor, repeat):
    times = []
    for _ in range(repeat):
        times.append(nephele_read(path, var))
    t_open = min(t[0] for t in times)
    t_read = min(t[1] for t in times)
    ds, a = times[-1][2], times[-1][3]

    def plain():
        with open_anchor(path) as f:
            return anchor(f, ds, ds.file_names.get(ds.resolve(var), var))

    t_anchor, ref = best(plain, repeat)
    both = np.isfinite(a) & np.isfinite(ref)
    err = float(np.max(np.abs(a[both] - ref[both]))) if both.any() else float("nan")
    nan_same = bool(np.array_equal(np.isnan(a), np.isnan(ref)))
    nk, nj, ni = ds.grid.shape
    return (name, f"{ni}x{nj}x{nk}", var, f"{t_open * 1e3:.1f}", f"{t_read * 1e3:.1f}", f"{(t_open + t_read) * 1e3:.1f}",
            f"{t_anchor * 1e3:.1f}", f"{err:.1e}" + ("" if nan_same else " (NaN differ)"),
            ", ".join(dict.fromkeys(n.split(":")[0] for n in ds.notes)) or "-")


def written_files(tmp):
    """A Zarr store from the CAM file, a 3-level GRIB2 file from the real polar stereographic message,
    and a projection-only Lambert conformal NetCDF file."""
    import xarray as xr

    out = {}
    try:
        import zarr  # noqa: F401

        with xr.open_dataset(DATA / "cam_vinth2p.nc", decode_times=False) as f:
            f.to_zarr(tmp / "cam.zarr", mode="w")
        out["zarr"] = tmp / "cam.zarr"
    except ImportError:
        pass
    try:
        import eccodes

        with open(DATA / "polar_stereo.grib2", "rb") as f:
            src = eccodes.codes_grib_new_from_file(f)
        base = eccodes.codes_get_values(src)
        with open(tmp / "ps3.grib2", "wb") as w:
            for k, p in enumerate((1000, 850, 500)):
                h = eccodes.codes_clone(src)
                eccodes.codes_set(h, "typeOfFirstFixedSurface", 100)
                eccodes.codes_set(h, "level", p)
                eccodes.codes_set_values(h, base - 10.0 * k)
                eccodes.codes_write(h, w)
                eccodes.codes_release(h)
        eccodes.codes_release(src)
        out["grib"] = tmp / "ps3.grib2"
    except ImportError:
        pass
    x = (np.arange(200) - 99.5) * 12000.0
    y = (np.arange(150) - 74.5) * 12000.0
    z = np.linspace(100.0, 15000.0, 30)
    t = (300.0 - 0.0065 * z[:, None, None] + 0.001 * x[None, None, :] / 1000.0 + 0.0 * y[None, :, None]).astype(np.float32)
    xr.Dataset(
        {"T": (("z", "y", "x"), t, {"units": "K", "grid_mapping": "lambert"}),
         "lambert": ((), 0, {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
                             "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0, "earth_radius": 6370000.0})},
        coords={"z": ("z", z, {"units": "m", "standard_name": "height"}),
                "y": ("y", y, {"units": "m", "standard_name": "projection_y_coordinate"}),
                "x": ("x", x, {"units": "m", "standard_name": "projection_x_coordinate"})},
    ).to_netcdf(tmp / "lcc.nc")
    out["lcc"] = tmp / "lcc.nc"
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, print only (docs untouched)")
    args = ap.parse_args()
    import xarray as xr

    repeat = 1 if args.quick else 5
    load = os.getloadavg()[0]
    nc = lambda p: xr.open_dataset(p, decode_times=False)  # noqa: E731
    cases = [
        ("CAM hybrid sigma-pressure", DATA / "cam_vinth2p.nc", "T", nc),
        ("NCL, time 'Month', K as degC", DATA / "ncl_nc4uvt_T.nc", "T", nc),
        ("UM rotated pole, hybrid height", DATA / "um_hybrid_height.nc", "air_potential_temperature", nc),
    ]
    echam = DATA / "climate" / "rectilinear_grid_3D.nc"
    if echam.exists():
        cases.append(("ECHAM5 pressure levels", echam, "t", nc))
    with tempfile.TemporaryDirectory() as d:
        extra = written_files(Path(d))
        if "zarr" in extra:
            cases.append(("Zarr store of the CAM file", extra["zarr"], "T", lambda p: xr.open_zarr(p, decode_times=False)))
        if "grib" in extra:
            cases.append(("GRIB2 polar stereographic, 3 levels", extra["grib"], "t",
                          lambda p: xr.open_dataset(p, engine="cfgrib", backend_kwargs={"indexpath": ""}, decode_times=False)))
        cases.append(("Lambert conformal, x/y only", extra["lcc"], "T", nc))
        rows = [row(*c, repeat) for c in cases]
    header = ("file", "grid", "field", "open ms", "read ms", "Nephele total ms", "xarray anchor ms", "max abs diff", "notes on")
    table = md_table(header, rows)
    body = (
        f"Best of {repeat} (each a fresh open), machine load {load:.1f} at the start (2 shared cores).  "
        "Nephele total = open (coordinates, vertical coordinate, units checks, one read of each field's first step "
        "for plausibility) + read of step 0; the anchor opens the same file with plain xarray and reads the same "
        "array.  max abs diff compares the values in the reader's level/lat/lon order (units already agree: the "
        "NCL 'C' field holds kelvin, kept as read); 'notes on' lists what the reader reported assuming.\n\n" + table
    )
    if args.quick:
        print(body)
    else:
        write_section("readers", body, title="Readers: real climate files (issue 17)")


if __name__ == "__main__":
    main()
