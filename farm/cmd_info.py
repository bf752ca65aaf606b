"""``nephele info FILE``: what a dataset holds — grid, levels, variables, times."""

import json
import textwrap

from .reader_options import add_reader_options, reader_kwargs

HELP = "describe a dataset: grid type, shape, longitudes/latitudes, levels, variables, times"


def add_arguments(p):
    p.add_argument("source", metavar="FILE", nargs="?",
                   help='dataset: "demo", "demo:small", a NetCDF .nc (or a .zip of them), a GRIB file, a Zarr store '
                        'or a GrADS .ctl file')
    p.add_argument("--version", action="store_true", help="print Nephele's version and which kernels run, and exit")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_reader_options(p)


def describe(ds):
    """A dict describing a :class:`~nephele.core.climate.dataset.Dataset` (what ``nephele info`` prints)."""
    import numpy as np

    g = ds.grid
    nk, nj, ni = g.shape
    flat = bool(np.all(np.ptp(g.height.reshape(nk, -1), axis=1) == 0.0))
    vertical = getattr(ds, "vertical", "") or ("flat levels" if flat else "terrain-following levels")
    kind = ("rectilinear" if flat else "curvilinear, terrain following") + f" ({vertical})"
    step = np.diff(ds.hours)
    levels = [
        {"index": k, "min_m": float(g.height[k].min()), "max_m": float(g.height[k].max())}
        for k in range(nk)
    ]
    info = {
        "source": ds.source,
        "reader": type(ds).__name__,
        "grid": kind,
        "shape": {"lon": ni, "lat": nj, "levels": nk},
        "lon": [float(g.lon[0]), float(g.lon[-1])],
        "lon_step": float(np.median(np.diff(g.lon))),
        "periodic_lon": g.periodic_lon,
        "lat": [float(g.lat[0]), float(g.lat[-1])],
        "earth_radius_m": float(getattr(ds, "earth_radius", 0.0) or 0.0),
        "levels": levels,
        "variables": [
            {
                "name": v.name,
                "units": v.units,
                "about": v.long_name,
                "file_name": getattr(ds, "file_names", {}).get(v.name, v.name),
                "derived": getattr(ds, "derived", {}).get(v.name, ""),
            }
            for v in ds.variables.values()
        ],
        "skipped": getattr(ds, "skipped", {}),
        "times": {
            "count": int(ds.times.size),
            "first": str(ds.times[0]),
            "last": str(ds.times[-1]),
            "step_hours": float(np.median(step)) if step.size else None,
            "regular": bool(step.size == 0 or np.allclose(step, step[0])),
        },
        "notes": list(getattr(ds, "notes", ())),
    }
    if getattr(ds, "level_types", None):  # GRIB: every kind of level, the one read first
        info["level_type"] = ds.level_type
        info["level_types"] = {k: dict(v)
                               for k, v in sorted(ds.level_types.items(),
                                                  key=lambda kv: (kv[0] != ds.level_type, -kv[1]["3d"], kv[0]))}
    if getattr(ds, "members", None):
        info["members"] = list(ds.members)
        info["member"] = ds.member
    if g.curvilinear:
        info["grid"] += ", 2-D longitude/latitude (projected or curvilinear horizontal grid)"
    if g.rotation is not None or g.curvilinear:
        lon, lat = g.true_lonlat()
        west, east = _lon_span(lon)
        info["rotated_pole"] = g.rotation is not None
        info["curvilinear"] = g.curvilinear
        info["true_lon"] = [west, east]
        info["true_lat"] = [float(lat.min()), float(lat.max())]
    return info


def _lon_span(lon):
    """West and east edge (degrees, -180..360) of the shortest arc holding all longitudes ``lon``."""
    import numpy as np

    x = np.sort(np.mod(np.asarray(lon, dtype=np.float64).ravel(), 360.0))
    gaps = np.diff(np.append(x, x[0] + 360.0))
    k = int(np.argmax(gaps))  # the largest empty arc lies east of x[k]
    west = float(x[(k + 1) % x.size])
    east = west + 360.0 - float(gaps[k])
    if west >= 180.0:
        west, east = west - 360.0, east - 360.0
    return west, east


def format_text(info):
    """The human-readable form of :func:`describe`."""
    s = info["shape"]
    t = info["times"]
    lines = [
        f"{info['source']}  ({info['reader']})",
        f"  grid       {info['grid']}",
        f"  shape      {s['lon']} lon x {s['lat']} lat x {s['levels']} levels",
        f"  lon        {info['lon'][0]:g} .. {info['lon'][1]:g} degrees east, step {info['lon_step']:g}, "
        + ("periodic" if info["periodic_lon"] else "not periodic"),
        f"  lat        {info['lat'][0]:g} .. {info['lat'][1]:g} degrees north",
    ]
    if info.get("curvilinear"):
        lines[-2] = f"  grid x     columns 0 .. {s['lon'] - 1}"
        lines[-1] = f"  grid y     rows 0 .. {s['lat'] - 1}"
    elif info.get("rotated_pole"):
        lines[-2] = lines[-2].replace("  lon        ",
                                      "  grid lon   ").replace(" degrees east", " degrees (rotated pole)")
        lines[-1] = lines[-1].replace("  lat        ",
                                      "  grid lat   ").replace(" degrees north", " degrees (rotated pole)")
    if "true_lon" in info:
        lines += [
            f"  true lon   {info['true_lon'][0]:.4f} .. {info['true_lon'][1]:.4f} degrees east",
            f"  true lat   {info['true_lat'][0]:.4f} .. {info['true_lat'][1]:.4f} degrees north",
        ]
    lines += [
        f"  radius     {info['earth_radius_m']:.0f} m (planet)",
        "  levels     " + ", ".join(
            f"{lv['min_m']:.0f}" if lv["min_m"] == lv["max_m"] else f"{lv['min_m']:.0f}-{lv['max_m']:.0f}"
            for lv in info["levels"]
        ) + " m",
        "  variables",
    ]
    for v in info["variables"]:
        about = f"derived from {v['derived']}" if v["derived"] else v["about"]
        if v["file_name"] != v["name"]:
            about = f"'{v['file_name']}' in the file" + (f": {about}" if about else "")
        lines.append(f"    {v['name']:<12} [{v['units'] or '-'}]" + (f"  {about}" if about else ""))
    for name, why in info["skipped"].items():
        lines.append(f"    ({name}: not read, {why})")
    step = "" if t["step_hours"] is None else f", step {t['step_hours']:g} h" + ("" if t["regular"] else " (irregular)")
    lines.append(f"  times      {t['count']}: {t['first']} .. {t['last']}{step}")
    if "members" in info:
        m = info["members"]
        lines.append(f"  members    {len(m)} ({', '.join(map(str, m)) if len(m) < 8 else f'{m[0]}..{m[-1]}'}), reading "
                     + ("the control (0)" if info["member"] == 0 else str(info["member"])) + "; choose with --member")
    if "level_types" in info:
        kinds = info["level_types"]
        read = kinds[info["level_type"]]
        lines.append(f"  level type {info['level_type']} ({read['3d']} 3-D variables, {read['fields']} fields); "
                     "choose another with --level-type:")
        others = [f"{k} {v['3d']}" for k, v in kinds.items() if v["3d"] and k != info["level_type"]]
        flat = [f"{k} ({v['fields']})" for k, v in kinds.items() if not v["3d"]]
        lines += textwrap.wrap(", ".join(others) + " (3-D variables)", 100, initial_indent=" " * 13,
                               subsequent_indent=" " * 13) if others else []
        lines += textwrap.wrap("single-level only: " + ", ".join(flat), 100, initial_indent=" " * 13,
                               subsequent_indent=" " * 13) if flat else []
    lines += [f"  note       {n}" for n in info["notes"]]
    return "\n".join(lines)


def version_text():
    """Nephele's version and what runs its kernels (compiled, or the NumPy twins and why)."""
    import platform
    from importlib import metadata

    from ..core import native

    try:
        version = metadata.version("nephele")
    except metadata.PackageNotFoundError:
        version = "(not installed: run from source)"
    return "\n".join([f"nephele {version}",
                      f"python {platform.python_version()} on {platform.system()} {platform.machine()}",
                      f"kernels {native.status()}"])


def run(args):
    from ..core.climate.readers import open_dataset
    from ..core.errors import UsageError

    if args.version:
        print(version_text())
        return 0
    if args.source is None:
        raise UsageError("nephele info needs a FILE (or --version)")

    info = describe(open_dataset(args.source, **reader_kwargs(args)))
    print(json.dumps(info, indent=1) if args.json else format_text(info))
    return 0
