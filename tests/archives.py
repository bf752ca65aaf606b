"""Small NetCDF files laid out as the archives deliver them (written with netCDF4, no network).

* ERA5 from the current Copernicus Climate Data Store: ``valid_time`` (seconds since 1970, standard name
  time), ``pressure_level`` (hPa, decreasing), ``latitude`` decreasing, a scalar ``number`` or an ensemble
  ``number`` dimension, ``expver`` strings along ``valid_time``, fields packed as shorts with
  ``scale_factor``/``add_offset``; the zip the CDS hands out with one NetCDF per step type.
* MERRA-2 ``inst3_3d_asm_Nv`` (GEOS): 72 layers numbered by ``lev`` (units ``layer``, positive down) with
  mid-layer pressure ``PL``, heights ``H``, thickness ``DELP``, cloud ``QL``/``QI``/``CLOUD``.
* CMIP6 CMOR ``cl``: hybrid sigma-pressure ``lev`` with ``formula_terms`` ``p0: p0 a: a b: b ps: ps``,
  bounds, ``time_bnds``, 360-day or no-leap calendars, percent cloud fraction.
* ICON and MPAS output on unstructured cells.

The attribute sets follow files from those archives (names, units, standard names, orders).
"""

import zipfile

import numpy as np

netCDF4 = __import__("pytest").importorskip("netCDF4")


def _axes(nc, lat, lon, lat_name="latitude", lon_name="longitude"):
    nc.createDimension(lat_name, lat.size)
    nc.createDimension(lon_name, lon.size)
    v = nc.createVariable(lat_name, "f8", (lat_name,))
    v.setncatts({"units": "degrees_north", "standard_name": "latitude", "long_name": "latitude"})
    v[:] = lat
    v = nc.createVariable(lon_name, "f8", (lon_name,))
    v.setncatts({"units": "degrees_east", "standard_name": "longitude", "long_name": "longitude"})
    v[:] = lon


def era5_values(name, times, levels, lat, lon, member=0):
    """The values the ERA5 test files hold (time, level, lat, lon), float64."""
    t = np.arange(len(times))[:, None, None, None]
    p = np.asarray(levels, dtype=float)[None, :, None, None]
    la, lo = np.deg2rad(lat)[None, None, :, None], np.deg2rad(lon)[None, None, None, :]
    base = {"t": 300.0 - 60.0 * (1.0 - p / 1000.0), "z": 9.80665 * 44330.8 * (1.0 - (p / 1013.25) ** 0.1903),
            "cc": 0.5 + 0.0 * p, "clwc": 1e-4 * p / 1000.0, "w": 0.1 + 0.0 * p}[name]
    return base + {"t": 5.0, "z": 20.0, "cc": 0.4, "clwc": 5e-5,
                   "w": 0.05}[name] * np.cos(la) * np.sin(lo + 0.3 * t) + 0.5 * member * (name == "t")


def era5_cds(path, *, members=None, packed=True, times=4, levels=(1000, 850, 500), names=("t", "z", "cc", "clwc", "w")):
    """A CDS ERA5 pressure-level file (``data_stream-oper_stepType-instant.nc``); returns the values written."""
    lat, lon = np.linspace(90, -90, 13), np.arange(0, 360, 30.0)
    valid = np.datetime64("2024-06-01T00:00", "s") + np.arange(times) * np.timedelta64(6, "h")
    units = {"t": "K", "z": "m**2 s**-2", "cc": "(0 - 1)", "clwc": "kg kg**-1", "w": "Pa s**-1"}
    std = {"t": "air_temperature", "z": "geopotential", "cc": "cloud_area_fraction_in_atmosphere_layer",
           "clwc": "specific_cloud_liquid_water_content", "w": "lagrangian_tendency_of_air_pressure"}
    written = {}
    with netCDF4.Dataset(path, "w") as nc:
        nc.setncatts({"GRIB_centre": "ecmf",
                      "GRIB_centreDescription": "European Centre for Medium-Range Weather Forecasts",
                      "Conventions": "CF-1.7", "institution": "European Centre for Medium-Range Weather Forecasts"})
        dims = []
        if members:
            nc.createDimension("number", members)
            v = nc.createVariable("number", "i8", ("number",))
            v.setncatts({"long_name": "ensemble member numerical id", "units": "1", "standard_name": "realization"})
            v[:] = np.arange(members)
            dims.append("number")
        else:
            v = nc.createVariable("number", "i8", ())
            v.setncatts({"long_name": "ensemble member numerical id", "units": "1", "standard_name": "realization"})
            v.assignValue(0)
        nc.createDimension("valid_time", times)
        v = nc.createVariable("valid_time", "i8", ("valid_time",))
        v.setncatts({"long_name": "time", "standard_name": "time", "units": "seconds since 1970-01-01",
                     "calendar": "proleptic_gregorian"})
        v[:] = valid.astype(np.int64)
        nc.createDimension("pressure_level", len(levels))
        v = nc.createVariable("pressure_level", "f8", ("pressure_level",))
        v.setncatts({"long_name": "pressure", "units": "hPa", "positive": "down", "stored_direction": "decreasing",
                     "standard_name": "air_pressure"})
        v[:] = levels
        _axes(nc, lat, lon)
        nc["latitude"].stored_direction = "decreasing"
        v = nc.createVariable("expver", str, ("valid_time",))
        v.long_name = "experiment version"
        for i in range(times):
            v[i] = "0001"
        dims += ["valid_time", "pressure_level", "latitude", "longitude"]
        for name in names:
            a = np.stack([era5_values(name, valid, levels, lat, lon, m) for m in range(members or 1)])
            if not members:
                a = a[0]
            if packed:  # the CDS's classic packing: int16 -32766..32767 spanning the range, -32767 left for missing
                lo, hi = float(a.min()), float(a.max())
                scale = (hi - lo) / (2**16 - 3) or 1.0
                offset = lo + scale * 32766
                v = nc.createVariable(name, "i2", dims, fill_value=np.int16(-32767))
                v.setncatts({"scale_factor": scale, "add_offset": offset, "missing_value": np.int16(-32767)})
                v.set_auto_maskandscale(True)
                written[name] = np.round((a - offset) / scale) * scale + offset
            else:
                v = nc.createVariable(name, "f4", dims, fill_value=np.float32(np.nan), zlib=True)
                written[name] = a.astype(np.float32)
            v.setncatts({"units": units[name], "standard_name": std[name], "long_name": name,
                         "coordinates": "number valid_time pressure_level latitude longitude expver",
                         "GRIB_shortName": name, "GRIB_gridType": "regular_ll"})
            v[:] = a
    return {"values": written, "times": valid, "lat": lat, "lon": lon, "levels": np.asarray(levels, float)}


def era5_zip(path, **kw):
    """The CDS zip: the instant fields, and a second NetCDF of accumulated 2-D fields."""
    inst = path.with_name("data_stream-oper_stepType-instant.nc")
    accum = path.with_name("data_stream-oper_stepType-accum.nc")
    info = era5_cds(inst, **kw)
    with netCDF4.Dataset(accum, "w") as nc:
        nc.createDimension("valid_time", 4)
        v = nc.createVariable("valid_time", "i8", ("valid_time",))
        v.setncatts({"standard_name": "time", "units": "seconds since 1970-01-01", "calendar": "proleptic_gregorian"})
        v[:] = info["times"].astype(np.int64)
        _axes(nc, info["lat"], info["lon"])
        v = nc.createVariable("tp", "f4", ("valid_time", "latitude", "longitude"))
        v.units = "m"
        v[:] = 0.001
    with zipfile.ZipFile(path, "w") as z:
        z.write(inst, inst.name)
        z.write(accum, accum.name)
    inst.unlink()
    accum.unlink()
    return info


def merra2(path, nlev=72, times=2):
    """A MERRA-2 M2I3NVASM-like file on a 5 x 4 degree subset; returns what it holds."""
    lat, lon = np.arange(-20.0, 21.0, 4.0), np.arange(-180.0, 180.0, 30.0)
    rng = np.random.default_rng(3)
    ps = 100000.0 + 1500.0 * rng.standard_normal((times, lat.size, lon.size))
    edges = np.concatenate([[1.0], np.geomspace(2.0, 1.0, nlev)])  # relative layer thickness, top down
    frac = np.cumsum(edges[1:]) / np.sum(edges[1:])
    # top (ptop = 1 Pa) to surface
    p_half = 1.0 + (ps[:, None] - 1.0) * np.concatenate([[0.0], frac])[None, :, None, None]
    delp = np.diff(p_half, axis=1)
    pl = 0.5 * (p_half[:, 1:] + p_half[:, :-1])
    t = 220.0 + 70.0 * (pl / 1e5)
    h = 7000.0 * np.log(ps[:, None] / pl) + 100.0
    ql = 1e-5 * np.exp(-((pl - 70000.0) / 15000.0) ** 2)
    with netCDF4.Dataset(path, "w") as nc:
        nc.setncatts({"Conventions": "CF-1", "Source": "CVS tag: GEOSadas-5_12_4", "ShortName": "M2I3NVASM",
                      "Title": "MERRA2 inst3_3d_asm_Nv: "
                               "3d,3-Hourly,Instantaneous,Model-Level,Assimilation,Assimilated Meteorological Fields"})
        _axes(nc, lat, lon, "lat", "lon")
        nc.createDimension("lev", nlev)
        v = nc.createVariable("lev", "f8", ("lev",))
        v.setncatts({"long_name": "vertical level", "units": "layer", "positive": "down", "coordinate": "eta",
                     "standard_name": "model_layers"})
        v[:] = np.arange(1, nlev + 1)
        nc.createDimension("time", None)
        v = nc.createVariable("time", "i4", ("time",))
        v.setncatts({"long_name": "time", "units": "minutes since 2017-01-01 00:00:00", "time_increment": 30000,
                     "begin_date": 20170101, "begin_time": 0})
        v[:] = np.arange(times) * 180
        spec = {"T": (t, "K", "air_temperature"), "PL": (pl, "Pa", "mid_level_pressure"),
                "H": (h, "m", "mid_layer_heights"), "DELP": (delp, "Pa", "pressure_thickness"),
                "QL": (ql, "kg kg-1", "mass_fraction_of_cloud_liquid_water_condensate"),
                "QI": (0.3 * ql, "kg kg-1", "mass_fraction_of_cloud_ice_water"),
                "CLOUD": (np.minimum(ql / 1e-5, 1.0), "1", "cloud_fraction_for_radiation")}
        for name, (a, units, long_name) in spec.items():
            v = nc.createVariable(name, "f4", ("time", "lev", "lat", "lon"), fill_value=np.float32(1e15))
            v.setncatts({"long_name": long_name, "units": units, "missing_value": np.float32(1e15),
                         "fmissing_value": np.float32(1e15), "vmax": np.float32(1e15), "vmin": np.float32(-1e15)})
            v[:] = a
        v = nc.createVariable("PS", "f4", ("time", "lat", "lon"), fill_value=np.float32(1e15))
        v.setncatts({"long_name": "surface_pressure", "units": "Pa"})
        v[:] = ps
    return {"T": t, "PL": pl, "H": h, "QL": ql, "ps": ps, "lat": lat, "lon": lon}


def cmip6_cl(path, calendar="360_day", nlev=5, times=3):
    """A CMIP6 CMOR ``cl`` file (monthly means, ``days since 1850-01-01``)."""
    lat, lon = np.array([-45.0, -15.0, 15.0, 45.0]), np.arange(0.0, 360.0, 60.0)
    a = np.linspace(0.05, 0.0, nlev)  # a p0 shrinks toward the surface, b grows
    b = np.linspace(0.0, 0.95, nlev) ** 1.5
    ps = 98000.0 + 1000.0 * np.arange(times)[:, None, None] + 500.0 * np.cos(np.deg2rad(lat))[None, :, None] + 0.0 * lon
    cl = 10.0 + 5.0 * np.arange(nlev)[None, :, None, None] + 0.0 * ps[:, None]
    month = 30.0 if calendar == "360_day" else 365.0 / 12.0
    mid = (np.arange(times) + 0.5) * month
    with netCDF4.Dataset(path, "w") as nc:
        nc.setncatts({"Conventions": "CF-1.7 CMIP-6.2", "mip_era": "CMIP6", "table_id": "Amon", "variable_id": "cl",
                      "source_id": "UKESM1-0-LL" if calendar == "360_day" else "CESM2", "frequency": "mon"})
        nc.createDimension("time", None)
        nc.createDimension("bnds", 2)
        v = nc.createVariable("time", "f8", ("time",))
        v.setncatts({"bounds": "time_bnds", "units": "days since 1850-01-01", "calendar": calendar, "axis": "T",
                     "long_name": "time", "standard_name": "time"})
        v[:] = mid
        v = nc.createVariable("time_bnds", "f8", ("time", "bnds"))
        v[:] = np.stack([mid - month / 2, mid + month / 2], axis=1)
        nc.createDimension("lev", nlev)
        v = nc.createVariable("lev", "f8", ("lev",))
        v.setncatts({"bounds": "lev_bnds", "units": "1", "axis": "Z", "positive": "down",
                     "long_name": "hybrid sigma pressure coordinate",
                     "standard_name": "atmosphere_hybrid_sigma_pressure_coordinate", "formula": "p = a*p0 + b*ps",
                     "formula_terms": "p0: p0 a: a b: b ps: ps"})
        v[:] = a + b
        v = nc.createVariable("lev_bnds", "f8", ("lev", "bnds"))
        v.setncatts({"formula": "p = a*p0 + b*ps", "formula_terms": "p0: p0 a: a_bnds b: b_bnds ps: ps",
                     "standard_name": "atmosphere_hybrid_sigma_pressure_coordinate", "units": "1"})
        v[:] = np.stack([a + b - 0.01, a + b + 0.01], axis=1)
        v = nc.createVariable("p0", "f8", ())
        v.setncatts({"long_name": "vertical coordinate formula term: reference pressure", "units": "Pa"})
        v.assignValue(100000.0)
        for name, val in (("a", a), ("b", b)):
            v = nc.createVariable(name, "f8", ("lev",))
            v.long_name = f"vertical coordinate formula term: {name}(k)"
            v[:] = val
            v = nc.createVariable(f"{name}_bnds", "f8", ("lev", "bnds"))
            v.long_name = f"vertical coordinate formula term: {name}(k+1/2)"
            v[:] = np.stack([val, val], axis=1)
        _axes(nc, lat, lon, "lat", "lon")
        nc["lat"].bounds, nc["lon"].bounds = "lat_bnds", "lon_bnds"
        for name, c, step in (("lat_bnds", lat, 30.0), ("lon_bnds", lon, 60.0)):
            v = nc.createVariable(name, "f8", (name[:3], "bnds"))
            v[:] = np.stack([c - step / 2, c + step / 2], axis=1)
        v = nc.createVariable("ps", "f4", ("time", "lat", "lon"))
        v.setncatts({"standard_name": "surface_air_pressure", "long_name": "Surface Air Pressure", "units": "Pa"})
        v[:] = ps
        v = nc.createVariable("cl", "f4", ("time", "lev", "lat", "lon"), fill_value=np.float32(1e20))
        v.setncatts({"standard_name": "cloud_area_fraction_in_atmosphere_layer", "long_name": "Percentage Cloud Cover",
                     "units": "%", "cell_methods": "area: time: mean", "missing_value": np.float32(1e20)})
        v[:] = cl
    return {"a": a, "b": b, "ps": ps, "cl": cl, "mid": mid, "month": month}


def icon(path):
    """ICON output on its triangular cells (CDI's ``ncells``, ``clon``/``clat`` in radians with bounds)."""
    with netCDF4.Dataset(path, "w") as nc:
        nc.createDimension("ncells", 20480)
        nc.createDimension("vertices", 3)
        nc.createDimension("height", 4)
        nc.createDimension("time", None)
        for name, std in (("clon", "longitude"), ("clat", "latitude")):
            v = nc.createVariable(name, "f8", ("ncells",))
            v.setncatts({"standard_name": std, "units": "radian", "bounds": f"{name}_bnds"})
            v[:] = 0.0
            nc.createVariable(f"{name}_bnds", "f8", ("ncells", "vertices"))
        v = nc.createVariable("height", "f8", ("height",))
        v.setncatts({"standard_name": "height", "units": "m", "positive": "up"})
        v[:] = [100.0, 500.0, 1000.0, 2000.0]
        v = nc.createVariable("time", "f8", ("time",))
        v.setncatts({"standard_name": "time", "units": "hours since 2024-01-01"})
        v[:] = [0.0]
        v = nc.createVariable("temp", "f4", ("time", "height", "ncells"))
        v.setncatts({"standard_name": "air_temperature", "units": "K", "CDI_grid_type": "unstructured",
                     "number_of_grid_in_reference": 1, "coordinates": "clat clon"})
    return path


def mpas(path):
    """MPAS output: ``nCells`` with ``latCell``/``lonCell`` (radians), ``theta(Time, nCells, nVertLevels)``."""
    with netCDF4.Dataset(path, "w") as nc:
        nc.createDimension("Time", None)
        nc.createDimension("nCells", 2562)
        nc.createDimension("nVertLevels", 5)
        for name in ("latCell", "lonCell"):
            v = nc.createVariable(name, "f8", ("nCells",))
            v.units = "radians"
        v = nc.createVariable("theta", "f4", ("Time", "nCells", "nVertLevels"))
        v.units = "K"
    return path
