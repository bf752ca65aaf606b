"""Readers on real files (issues 17 and 37): time to open a file and read one 3-D step of one field, with
the error against the same array read by plain xarray (the anchor, measured in the same run).

NetCDF (section ``readers``): the CAM history file (NCAR hybrid levels), the NCL sample (non-CF time,
kelvin labelled degC), the UM rotated-pole hybrid-height file, the ECHAM5 pressure-level file from
tests/data, a Zarr store written from them, and a projection-only Lambert conformal file.

GRIB (section ``readers-grib``, ``--grib``): the NCEP GFS forecast in GRIB2 and GRIB1 and the ERA5
ensemble (tests/data/fetch_grib_samples.py), and a ~2 GB multi-level GRIB2 file built here in
``/tmp/nephele-bench-grib`` (never committed): Nephele's first open (one header scan), second open
(index from the cache), ``nephele info`` as a command on its second run, one 3-D field read against
reading the same messages' bytes; the anchor is ``xarray.open_dataset(engine="cfgrib")`` with the
hand-written ``filter_by_keys={"typeOfLevel": "isobaricInhPa"}``, its index in a temporary folder.

    .venv/bin/python benchmarks/bench_readers.py [--quick] [--grib] [--big-gb 2]

``--quick`` runs one repeat, skips the 2 GB file and writes nothing.
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
    return (name, f"{ni}x{nj}x{nk}", var, f"{t_open * 1e3:.1f}", f"{t_read * 1e3:.1f}",
            f"{(t_open + t_read) * 1e3:.1f}",
            f"{t_anchor * 1e3:.1f}", f"{err:.1e}" + ("" if nan_same else " (NaN differ)"),
            ", ".join(dict.fromkeys(n.split(":")[0] for n in ds.notes)) or "-")


def written_files(tmp):
    """A Zarr store from the CAM file and a projection-only Lambert conformal NetCDF file."""
    import xarray as xr

    out = {}
    try:
        import zarr  # noqa: F401

        with xr.open_dataset(DATA / "cam_vinth2p.nc", decode_times=False) as f:
            f.to_zarr(tmp / "cam.zarr", mode="w")
        out["zarr"] = tmp / "cam.zarr"
    except ImportError:
        pass
    x = (np.arange(200) - 99.5) * 12000.0
    y = (np.arange(150) - 74.5) * 12000.0
    z = np.linspace(100.0, 15000.0, 30)
    t = (300.0 - 0.0065 * z[:, None, None] + 0.001 * x[None, None, :] / 1000.0 + 0.0
         * y[None, :, None]).astype(np.float32)
    xr.Dataset(
        {"T": (("z", "y", "x"), t, {"units": "K", "grid_mapping": "lambert"}),
         "lambert": ((), 0, {"grid_mapping_name": "lambert_conformal_conic", "standard_parallel": [30.0, 60.0],
                             "longitude_of_central_meridian": -100.0, "latitude_of_projection_origin": 45.0,
                             "earth_radius": 6370000.0})},
        coords={"z": ("z", z, {"units": "m", "standard_name": "height"}),
                "y": ("y", y, {"units": "m", "standard_name": "projection_y_coordinate"}),
                "x": ("x", x, {"units": "m", "standard_name": "projection_x_coordinate"})},
    ).to_netcdf(tmp / "lcc.nc")
    out["lcc"] = tmp / "lcc.nc"
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, print only (docs untouched)")
    ap.add_argument("--grib", action="store_true", help="the GRIB section (real products and the big file) instead")
    ap.add_argument("--big-gb", type=float, default=2.0, help="size of the big GRIB file in GB (0: none)")
    args = ap.parse_args()
    if args.grib:
        return grib_section(args.quick, args.big_gb)
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
            cases.append(("Zarr store of the CAM file", extra["zarr"], "T",
                          lambda p: xr.open_zarr(p, decode_times=False)))
        cases.append(("Lambert conformal, x/y only", extra["lcc"], "T", nc))
        rows = [row(*c, repeat) for c in cases]
    header = ("file", "grid", "field", "open ms", "read ms", "Nephele total ms", "xarray anchor ms", "max abs diff",
              "notes on")
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


# ---------------------------------------------------------------------------------------------- GRIB (issue 37)
BIG = Path("/tmp/nephele-bench-grib")
BIG_VARS = ("t", "u", "v", "w", "r", "q", "gh", "clwmr", "icmr", "o3mr")
BIG_LEVELS = (1000, 975, 950, 925, 900, 875, 850, 825, 800, 775, 750, 700, 650, 600, 550, 500, 450, 400, 350, 300, 250,
              225, 200, 175, 150, 125, 100, 70, 50, 30, 20, 10, 7, 5, 3, 2, 1)


def big_grib(gb):
    """A GFS-like 0.25 degree file (1440 x 721, 16-bit simple packing, ~2.1 MB a message): 10 isobaric variables on
    37 levels and 30 surface fields per step, as many 3-hourly steps as make ``gb`` GB.  Built once, in /tmp."""
    import eccodes

    path = BIG / f"gfs-like-0p25-{gb:g}GB.grib2"
    if path.is_file():
        return path
    BIG.mkdir(parents=True, exist_ok=True)
    lon, lat = np.arange(1440) * 0.25, 90.0 - np.arange(721) * 0.25
    base = (np.cos(np.deg2rad(lat))[:, None] * np.sin(np.deg2rad(3 * lon))[None]).ravel()
    template = eccodes.codes_grib_new_from_samples("regular_ll_pl_grib2")
    for k, v in (("centre", "kwbc"), ("Ni", 1440), ("Nj", 721), ("latitudeOfFirstGridPointInDegrees", 90.0),
                 ("longitudeOfFirstGridPointInDegrees", 0.0), ("latitudeOfLastGridPointInDegrees", -90.0),
                 ("longitudeOfLastGridPointInDegrees", 359.75), ("iDirectionIncrementInDegrees", 0.25),
                 ("jDirectionIncrementInDegrees", 0.25), ("bitsPerValue", 16), ("dataDate", 20240601), ("dataTime", 0)):
        eccodes.codes_set(template, k, v)
    per_step = (len(BIG_VARS) * len(BIG_LEVELS) + 30) * (1440 * 721 * 2 + 200)
    steps = max(1, int(np.ceil(gb * 1e9 / per_step)))  # at least gb
    tmp = path.with_suffix(".part")
    with open(tmp, "wb") as out:
        for step in range(steps):
            for name in BIG_VARS:
                for p in BIG_LEVELS:
                    h = eccodes.codes_clone(template)
                    eccodes.codes_set(h, "step", 3 * step)
                    eccodes.codes_set(h, "shortName", name)
                    eccodes.codes_set(h, "level", p)
                    eccodes.codes_set_values(h, 250.0 + p / 20.0 + 10.0 * base + step)
                    eccodes.codes_write(h, out)
                    eccodes.codes_release(h)
            for n in range(30):  # single-level fields of other kinds, as in the real product
                h = eccodes.codes_clone(template)
                eccodes.codes_set(h, "step", 3 * step)
                eccodes.codes_set(h, "typeOfFirstFixedSurface", 1)
                eccodes.codes_set(h, "parameterNumber", n)
                eccodes.codes_set_values(h, base + n)
                eccodes.codes_write(h, out)
                eccodes.codes_release(h)
    eccodes.codes_release(template)
    os.replace(tmp, path)
    return path


class _Skipped(__import__("logging").Handler):
    """The variables cfgrib logs it skipped (its 'key present and new value is different' merge failures)."""

    def __init__(self):
        super().__init__()
        self.names = set()

    def emit(self, record):
        text = record.getMessage()
        if "skipping variable" in text and "shortName=" in text:
            self.names.add(text.split("shortName=")[1].split()[0].strip("',"))


def _cfgrib(path, idx_dir):
    """The anchor: xarray's cfgrib engine with the hand-written isobaric filter, its index in ``idx_dir``;
    and the names of the variables it skipped."""
    import logging
    import warnings

    import xarray as xr

    log, skipped = logging.getLogger("cfgrib"), _Skipped()
    log.addHandler(skipped)
    log.propagate = False  # its tracebacks are not this table's business
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = xr.open_dataset(path, engine="cfgrib", decode_times=False,
                                 backend_kwargs={"filter_by_keys": {"typeOfLevel": "isobaricInhPa"},
                                                 "indexpath": str(Path(idx_dir) / "{short_hash}.idx")})
    finally:
        log.removeHandler(skipped)
    return ds, sorted(skipped.names)


def _anchor_t(ads, member):
    t = ads["t"]
    for dim in ("number", "time", "step", "valid_time"):
        if dim in t.dims:
            t = t.isel({dim: member if dim == "number" else 0})
    t = t.sortby("isobaricInhPa", ascending=False).sortby("latitude")
    return np.asarray(t.values, dtype=np.float32)


def grib_row(name, path, repeat, member=None):
    """Nephele against the anchor on one file: cold and warm opens, one 3-D read, and the largest difference in t."""
    cold, cpu, warm, warm_cpu, read = [], [], [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as cache:
            os.environ["NEPHELE_CACHE"] = cache
            t0, c0 = time.perf_counter(), time.process_time()
            ds = open_dataset(path)
            cold.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            t0, c0 = time.perf_counter(), time.process_time()
            ds = open_dataset(path)
            warm.append(time.perf_counter() - t0)
            warm_cpu.append(time.process_time() - c0)
            t0 = time.perf_counter()
            a = ds.read("temperature", 0)
            read.append(time.perf_counter() - t0)
    a_cold, a_cpu, a_warm = [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as idx:
            t0, c0 = time.perf_counter(), time.process_time()
            ads, skipped = _cfgrib(path, idx)
            ref = _anchor_t(ads, member or 0)
            a_cold.append(time.perf_counter() - t0)
            a_cpu.append(time.process_time() - c0)
            t0 = time.perf_counter()
            ads, _ = _cfgrib(path, idx)
            _anchor_t(ads, member or 0)
            a_warm.append(time.perf_counter() - t0)
    both = np.isfinite(a) & np.isfinite(ref)
    err = float(np.max(np.abs(a[both] - ref[both]))) if a.shape == ref.shape else float("nan")
    n3 = sum(1 for v in ds.variables if v not in ds.derived)
    nk, nj, ni = ds.grid.shape
    return (name, f"{path.stat().st_size / 1e6:.1f} MB", f"{ni}x{nj}x{nk}", f"{min(cold):.2f} ({min(cpu):.2f})",
            f"{min(warm):.3f} ({min(warm_cpu):.3f})",
            f"{min(read) * 1e3:.0f}", f"{n3}", f"{min(a_cold):.2f} ({min(a_cpu):.2f})", f"{min(a_warm):.2f}",
            f"{len(ads.data_vars)}" + (f" (not: {', '.join(skipped)})" if skipped else ""), f"{err:.1e}")


def big_row(path):
    """The big file: ``nephele info`` as a command (first and second run), one 3-D field against reading its bytes."""
    import subprocess

    nephele = [str(Path(sys.executable).parent / "nephele")]
    runs = []
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NEPHELE_CACHE": cache}
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run(nephele + ["info", str(path)], check=True, capture_output=True, env=env)
            runs.append(time.perf_counter() - t0)
        os.environ["NEPHELE_CACHE"] = cache
        t0 = time.perf_counter()
        ds = open_dataset(path)
        warm_open = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        ds.read("temperature", 1)
        read, read_cpu = time.perf_counter() - t0, time.process_time() - c0
    table = ds._table[ds.file_names["temperature"]][1]
    index = ds._index
    nbytes, t0 = 0, time.perf_counter()
    with open(path, "rb") as f:  # the same messages' bytes, read plainly: the disk (here: page cache) speed
        for i in table:
            f.seek(int(index.offset[i]))
            nbytes += len(f.read(2 * 1440 * 721 + 200))
    plain = time.perf_counter() - t0
    anchor = []
    with tempfile.TemporaryDirectory() as idx:
        for _ in range(2):  # the anchor: its own index first built, then used; t of the second step loaded
            t0 = time.perf_counter()
            ads, _ = _cfgrib(path, idx)
            np.asarray(ads["t"].isel(step=1).values if "step" in ads["t"].dims else ads["t"].values)
            anchor.append(time.perf_counter() - t0)
    return runs, warm_open, (read, read_cpu), nbytes, plain, len(index), ds.grid.shape, anchor


def grib_section(quick, big_gb):
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("fetch", ROOT / "tests" / "data" / "fetch_grib_samples.py")
    fetch = module_from_spec(spec)
    spec.loader.exec_module(fetch)
    samples = fetch.ensure()
    repeat = 1 if quick else 3
    import eccodes  # its definitions load on first use, once per process: not part of any row

    eccodes.codes_release(eccodes.codes_grib_new_from_samples("regular_ll_pl_grib2"))
    load = os.getloadavg()
    rows = [grib_row("NCEP GFS 2.5 deg GRIB2 (pygrib sample)", samples / "gfs.t12z.pgrbf120.2p5deg.grib2", repeat),
            grib_row("the same forecast in GRIB1", samples / "gfs.t12z.pgrbf120.2p5deg.grib1", repeat),
            grib_row("ERA5 ensemble, 10 members (cfgrib sample)", samples / "era5-levels-members.grib", repeat,
                     member=0)]
    header = ("file", "size", "grid", "Nephele 1st open s (CPU s)", "2nd open s (CPU s)", "read t ms", "fields read",
              "cfgrib+filter 1st s (CPU s)", "2nd s", "cfgrib fields", "max abs diff t")
    body = (f"Best of {repeat}; load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) at the "
            "start, 2 shared cores (CPU s: the process's own CPU time, what an idle machine would take).  Nephele: "
            "first open = one header scan + the index written to a fresh cache; second open = "
            "the index from the cache; both build the grid, levels (mean gh heights) and every isobaric variable.  "
            "Anchor: `xarray.open_dataset(engine=\"cfgrib\", filter_by_keys={\"typeOfLevel\": \"isobaricInhPa\"})` "
            "and t loaded, first with no index, then with its index; the fields it could not merge are named.\n\n"
            + md_table(header, rows))
    if not quick and big_gb > 0:
        path = big_grib(big_gb)
        runs, warm_open, (read, read_cpu), nbytes, plain, n, shape, anchor = big_row(path)
        body += (f"\n\nBig file: {path.stat().st_size / 1e9:.2f} GB, {n} messages ({shape[2]} x {shape[1]} x "
                 f"{shape[0]} levels, 10 isobaric variables, 30 single-level fields per step).  `nephele info` as a "
                 f"command (Python start-up included): first run {runs[0]:.1f} s (scan), second {runs[1]:.2f} s, "
                 f"third {runs[2]:.2f} s; open in process with the index {warm_open:.2f} s; one 3-D field (t, "
                 f"{shape[0]} messages, {nbytes / 1e6:.0f} MB) read and decoded in {read:.2f} s "
                 f"({nbytes / 1e6 / read:.0f} MB/s; {read_cpu:.2f} CPU s, {nbytes / 1e6 / read_cpu:.0f} MB per CPU "
                 f"second: ecCodes' unpacking bounds it) against {plain:.2f} s ({nbytes / 1e6 / plain:.0f} MB/s) to "
                 "read the same bytes plainly (page cache warm: the file was just written or read).  The anchor "
                 f"(cfgrib + filter, in process) opens it and loads that t in {anchor[0]:.1f} s the first time "
                 f"(building its index) and {anchor[1]:.1f} s "
                 f"with its index.  Load average at the end {os.getloadavg()[0]:.1f}.")
    if quick:
        print(body)
    else:
        write_section("readers-grib", body, title="Readers: GRIB products as delivered (issue 37)")


if __name__ == "__main__":
    main()
