"""CF NetCDF climate files (read lazily with xarray, one step at a time).

Understood layouts: fields with dimensions ``([time,] level, lat, lon)`` in
any order, 1-D latitude and longitude (any direction, longitudes −180…180 or
0…360), and one of these vertical coordinates:

=========================== ======================================================
vertical coordinate         level heights (metres)
=========================== ======================================================
pressure (Pa, hPa)          mean geopotential height of each level in the first
                            step when the file has one (``zg``, ``z``, ``hgt``…;
                            geopotential in m²/s² is divided by g), else the ISO
                            standard atmosphere; flat levels, not terrain following
hybrid sigma-pressure       ``p = a p0 + b ps`` (or ``ap + b ps``) from its CF
                            ``formula_terms``, first-step ``ps``, converted with the
                            standard atmosphere: terrain following
atmosphere sigma            ``p = ptop + sigma (ps − ptop)``, as above
hybrid height               ``z = a + b orog`` from ``formula_terms``
height (m, km)              flat levels
=========================== ======================================================

Parametric coordinates are found by CF ``standard_name``/``formula_terms`` on
the level coordinate or on an auxiliary coordinate along the level dimension
(the UM's ``level_height``/``sigma``/``surface_altitude`` on
``model_level_number``), and by NCAR's convention: units
``hybrid_sigma_pressure`` or attributes ``A_var``/``B_var``/``P0_var``/``PS_var``
(CAM's ``hyam``/``hybm``/``P0``/``PS``).  A missing ``P0`` is CAM's
100000 Pa (or the ``p0=`` argument), reported in :attr:`notes`.

Horizontal grids: 1-D latitude/longitude; a CF rotated pole
(``grid_latitude``/``grid_longitude`` with a ``rotated_latitude_longitude``
grid mapping): the grid keeps its rotated coordinates (winds in such files are
grid-relative) and carries the rotation to the true globe
(:func:`~nephele.core.climate.grid.rotated_pole_matrix`); and curvilinear grids with
2-D latitude/longitude (CF ``lat(y, x)``/``lon(y, x)``, WRF's ``XLAT``/``XLONG``,
or only projection ``x``/``y`` with a Lambert conformal, polar stereographic,
stereographic or Mercator grid mapping, placed by
:func:`~nephele.core.projections.inverse`): :attr:`GlobeGrid.lon2d`.

WRF history files: eta levels at the heights ``(PH + PHB) / g`` of the first
step (destaggered), pressure ``P + PB``, ``temperature`` from ``T`` (the
perturbation potential temperature, kept as ``theta_perturbation``) by
Poisson's equation, ``cloud`` from ``CLDFRA``, WRF's radius 6370 km.
Fields on one staggered dimension (``U`` on ``west_east_stag``, ``V`` on
``south_north_stag``, ``W``, ``PH``, ``PHB`` on ``bottom_top_stag``) are read
at the mass points, each value the mean of its two staggered neighbours
(Arakawa C grid); ``u``/``v`` are turned from grid to earth axes with the
file's ``COSALPHA``/``SINALPHA`` (``u_e = U cos a - V sin a``,
``v_e = V cos a + U sin a``) when it has them.

Times come from CF units (``hours since 2001-01-01``…, any CF calendar as
elapsed time).  Anything else (units ``Month``, no units) becomes step
indices one hour apart with a note; a scalar ``time`` or no time axis gives
one step.  ``time_units=`` overrides the file's units.

References
----------
.. [1] CF Conventions 1.11, Appendix D (parametric vertical coordinates).
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import re
import shutil
from pathlib import Path

import numpy as np

from ..errors import DataError
from .dataset import Variable
from .grid import EARTH_RADIUS, GlobeGrid, right_handed, rotated_pole_matrix
from .gridfile import (
    FileDataset,
    cf_times,
    cf_times_or_steps,
    parse_iso,
    plausible_units,
    standard_name,
    step_times,
    tidy_lonlat,
)
from .humidity import G0, RH_CRIT
from .netcdflevels import CAM_P0, VERTICAL_KINDS, VerticalCoordinates, _attr  # noqa: F401  (CAM_P0, VERTICAL_KINDS: public here)
from .projections import inverse

_LON_UNITS = ("degrees_east", "degree_east", "degree_e", "degrees_e", "degreee", "degreese")
_LAT_UNITS = ("degrees_north", "degree_north", "degree_n", "degrees_n", "degreen", "degreesn")
CAM_RADIUS = 6371220.0
"""CAM's planet radius (m, ``rearth`` in CAM's shr_const_mod), used for files with NCAR hybrid levels."""


def _find_axis(ds, path, kind):
    names, units, std = (
        (("lon", "longitude", "long", "x", "nav_lon"), _LON_UNITS, "longitude")
        if kind == "lon"
        else (("lat", "latitude", "y", "nav_lat"), _LAT_UNITS, "latitude")
    )
    # A rotated-pole grid's own axes come first: its true lon/lat (if stored) are 2-D.
    for name, var in ds.variables.items():
        if var.ndim == 1 and _attr(var, "standard_name").lower() == f"grid_{std}":
            return name
    for name, var in ds.variables.items():
        if _attr(var, "standard_name").lower() == std or _attr(var, "units").lower().replace(" ", "") in units:
            return name
    for name in ds.variables:
        if name.lower() in names:
            return name
    raise DataError(f"no {std} coordinate (looked for standard_name {std}, units {units[0]}, names "
                    f"{'/'.join(names[:2])})", path=path, field=kind)


def _find_time(ds):
    """The time coordinate: a 1-D one first (cfgrib's ``valid_time`` along ``step``), else a scalar one."""
    for ndim in (1, 0):
        for name, var in ds.variables.items():
            if var.ndim == ndim and (_attr(var, "standard_name").lower() == "time" or _attr(var, "axis").upper() == "T"
                                     or " since " in _attr(var, "units")):
                return name
    return "time" if "time" in ds.variables else None


def _grid_mapping(ds):
    """Name of the grid-mapping variable the data variables point to, or None."""
    for var in ds.data_vars.values():
        name = _attr(var, "grid_mapping").split(":")[0].strip()
        if name and name in ds.variables:
            return name
    return None


_MONTHS_SINCE = re.compile(r"\s*(months?|years?|common_years?)\s+since\s+(.+?)\s*$", re.IGNORECASE)


def _month_times(values, units, calendar, path, field):
    """``(times, note)`` for ``months since``/``years since`` units, or None for other units.

    A month is a calendar month of the file's calendar (30 days in
    ``360_day``, as cftime and CF define it there; the months of the
    ``noleap``, ``standard``… calendars otherwise, which is what monthly model
    output means by them) and a year twelve of them; a fraction is that part
    of the month it falls in.  Times are the elapsed time in that calendar
    from the reference date, as for other non-standard calendars.
    """
    m = _MONTHS_SINCE.match(units or "")
    if not m:
        return None
    try:
        import cftime
    except ImportError:
        raise DataError(f"time units {units!r} need the cftime package ('pip install cftime')", path=path,
                        field=field) from None
    cal = (calendar or "standard").strip().lower()
    if cal == "none":
        raise DataError(f"time units {units!r} with calendar 'none' have no months", path=path, field=field)
    ref = parse_iso(m.group(2), path, field)
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if not np.all(np.isfinite(values)):
        raise DataError("has NaN times", path=path, field=field)
    months = values * (1.0 if m.group(1).lower().startswith("month") else 12.0)
    text = str(ref)  # YYYY-MM-DDThh:mm:ss (year may be negative)
    date, _, clock = text.rpartition("T") if "T" in text else (text, "", "00:00:00")
    y, mo, d = (int(v) for v in re.match(r"(-?\d+)-(\d+)-(\d+)", date).groups())
    hh, mi, ss = (int(v) for v in clock.split(":"))
    try:
        start = cftime.datetime(y, mo, d, hh, mi, ss, calendar=cal)

        def shifted(n):
            k = mo - 1 + int(n)
            for day in range(d, 27, -1):  # the 31st of a shorter month is its last day
                try:
                    return cftime.datetime(y + k // 12, k % 12 + 1, day, hh, mi, ss, calendar=cal)
                except ValueError:
                    continue
            return cftime.datetime(y + k // 12, k % 12 + 1, d, hh, mi, ss, calendar=cal)

        secs = []
        for x in months:
            n = np.floor(x)
            a = shifted(n)
            span = (shifted(n + 1) - a).total_seconds() if x != n else 0.0
            secs.append((a - start).total_seconds() + (x - n) * span)
    except ValueError as exc:
        raise DataError(f"time units {units!r} in calendar {cal!r}: {exc}", path=path, field=field) from None
    times = ref + np.rint(secs).astype(np.int64).astype("timedelta64[s]")
    note = None
    if cal != "360_day":
        note = (f"{field}: units {units!r} read as calendar months of the {cal!r} calendar (CF's month is 1/12 of "
                "365.24 days; monthly model output means calendar months)")
    return times, note


_LENGTH = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "km": 1000.0, "kilometer": 1000.0,
           "kilometers": 1000.0}


def _projection_axes(ds):
    """Names of the 1-D projection x and y coordinates (CF ``projection_x_coordinate``…), or None."""
    found = {}
    for name, var in ds.variables.items():
        kind = {"projection_x_coordinate": "x", "projection_y_coordinate": "y"}.get(_attr(var, "standard_name").lower())
        if kind and var.ndim == 1:
            found.setdefault(kind, name)
    return (found["x"], found["y"]) if len(found) == 2 else None


def projected_lonlat(mapping, x, y, path=None, field="grid_mapping"):
    """True longitude and latitude (degrees, ``(ny, nx)``) of 1-D projection coordinates (metres) and a list of notes.

    :func:`nephele.core.projections.inverse` on the grid of ``x`` × ``y``.
    """
    X, Y = np.meshgrid(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    return inverse(mapping, X, Y, path, field)


WRF_T0 = 300.0
"""WRF's base potential temperature (K): its ``T`` is ``theta - 300 K``."""
WRF_RCP = 2.0 / 7.0
"""WRF's ``R_d / c_p`` (``c_p = 7 R_d / 2``)."""
WRF_RADIUS = 6370000.0
"""WRF's planet radius (m, ``EARTH_RADIUS_M`` in WRF's module_model_constants)."""


WRF_STAGGER = {"bottom_top_stag": "bottom_top", "south_north_stag": "south_north", "west_east_stag": "west_east"}
"""WRF's staggered dimensions and the mass dimensions they straddle (one more point each)."""


def _wrf_staggered(ds, dims, time_dim):
    """WRF fields staggered along one of ``dims`` = (level, y, x): ``{name: staggered dims in the order of dims}``,
    and ``{name: reason}`` for those whose staggered size is not the mass size + 1."""
    found, bad = {}, {}
    for name, var in ds.data_vars.items():
        own = [d for d in var.dims if d != time_dim]
        stag = [d for d in own if d in WRF_STAGGER]
        if len(own) != 3 or len(stag) != 1 or sorted(WRF_STAGGER.get(d, d) for d in own) != sorted(dims):
            continue
        mass = WRF_STAGGER[stag[0]]
        if ds.sizes[stag[0]] != ds.sizes[mass] + 1:
            bad[name] = f"{stag[0]} has {ds.sizes[stag[0]]} points for {ds.sizes[mass]} on {mass} (expected one more)"
            continue
        found[name] = tuple(stag[0] if d == mass else d for d in dims)
    return found, bad


def destagger(a, axis):
    """Values at the mass points of a C grid: the mean of each pair of neighbours along ``axis``."""
    a = np.asarray(a, dtype=np.float64)
    n = a.shape[axis]
    if n < 2:
        raise ValueError(f"need at least 2 staggered points along axis {axis}, got {n}")
    return 0.5 * (np.take(a, np.arange(n - 1), axis=axis) + np.take(a, np.arange(1, n), axis=axis))


def _is_wrf(ds, zdim):
    """A WRF history file: mass levels ``bottom_top`` with the geopotential ``PH``/``PHB`` on ``bottom_top_stag``."""
    return zdim == "bottom_top" and all(n in ds.variables and "bottom_top_stag" in ds[n].dims for n in ("PH", "PHB"))


_MEMBER_DIMS = ("number", "realization", "member", "members", "ensemble", "ens", "member_id", "ensemble_member")
_CELL_DIMS = {"ncells": "ICON", "cell": "ICON", "ncol": "CAM-SE", "nCells": "MPAS", "nMesh2_face": "UGRID",
              "nmesh2d_face": "UGRID", "grid_cells": "unstructured"}


def _member_dim(ds):
    """The ensemble member dimension of the data variables (a known name, or a coordinate with standard_name
    realization)."""
    dims = {d for v in ds.data_vars.values() for d in v.dims}
    for name in dims:
        if name.lower() in _MEMBER_DIMS or (name in ds.variables
                                            and _attr(ds[name], "standard_name").lower() == "realization"):
            return name
    return None


def _refuse_unstructured(ds, path):
    """One line for output on unstructured cells (ICON, MPAS, CAM-SE, UGRID): no latitude x longitude grid to read."""
    found = None
    for name, var in ds.variables.items():
        if _attr(var, "cf_role") == "mesh_topology":
            found = ("UGRID", name)
        elif _attr(var, "CDI_grid_type").lower() == "unstructured":
            found = ("ICON/CDI",
                     next((d for d in var.dims if d in _CELL_DIMS or d.lower() in _CELL_DIMS), var.dims[-1]))
    if found is None:
        for dim in ds.dims:
            if dim in _CELL_DIMS and any(dim in v.dims for v in ds.data_vars.values()):
                found = (_CELL_DIMS[dim], dim)
                break
    if found is not None:
        kind, dim = found
        size = f"{ds.sizes[dim]} cells on dimension {dim!r}" if dim in ds.dims else f"mesh {dim!r}"
        raise DataError(f"is on an unstructured grid ({kind}: {size}); Nephele reads latitude/longitude, rotated and "
                        "projected grids: remap it first (e.g. 'cdo remapcon,r360x180')", path=path, field=dim)


def _from_zip(path):
    """The NetCDF inside a zip (the Copernicus Climate Data Store's ``data.zip``) with the most 3-D fields, unpacked
    once into Nephele's cache (never beside the zip), and a note naming it and the others."""
    import hashlib
    import zipfile

    from ..files import atomic_write, cache_folder, file_stamp

    try:
        with zipfile.ZipFile(path) as z:
            members = [m for m in z.infolist() if m.filename.lower().endswith((".nc", ".nc4", ".netcdf"))
                       and not m.is_dir()]
            if not members:
                raise DataError(f"the zip holds no NetCDF file ({', '.join(z.namelist()[:5]) or 'nothing'})", path=path)
            folder = cache_folder("zip") / hashlib.sha256(file_stamp(path).encode()).hexdigest()[:24]
            unpacked = []
            for m in members:
                out = folder / Path(m.filename).name
                if not out.is_file() or out.stat().st_size != m.file_size:
                    with atomic_write(out, fsync=False) as tmp, z.open(m) as src, open(tmp, "wb") as dst:
                        shutil.copyfileobj(src, dst, 1 << 20)
                unpacked.append(out)
    except zipfile.BadZipFile as exc:
        raise DataError(f"cannot open as a zip of NetCDF files ({exc})", path=path) from None
    except OSError as exc:
        raise DataError(f"cannot unpack the zip into the cache ({exc.strerror or exc})", path=path) from None
    best = max(unpacked, key=_three_d_count)
    others = [p.name for p in unpacked if p != best]
    note = f"zip: read {best.name}" + (f"; also in the zip: {', '.join(others)}" if others else "")
    return best, note


def _three_d_count(path):
    """How many variables of a NetCDF file have three or more dimensions besides time (0 when it does not open)."""
    try:
        ds = _open_netcdf(path)
    except DataError:
        return -1
    with ds:
        return sum(len([d for d in v.dims if d not in ("time", "valid_time", "Time")]) >= 3
                   for v in ds.data_vars.values())


def _open_netcdf(path):
    """``xarray.open_dataset`` of a NetCDF file (times left as numbers), its failure as one line."""
    import xarray as xr

    try:
        return xr.open_dataset(path, decode_times=False, mask_and_scale=True)
    except Exception as exc:  # netCDF4/HDF5/scipy raise many types for a bad file
        first = (str(exc).strip().splitlines() or [""])[0]
        if "did not find a match" in first:
            first = "the contents are not NetCDF 3 or NetCDF 4/HDF5"
        raise DataError(f"cannot open as NetCDF ({type(exc).__name__}: {first})", path=path) from exc


class NetCDFDataset(VerticalCoordinates, FileDataset):
    """A CF NetCDF file opened lazily; see the module docstring for what is understood."""

    def __init__(self, path, *, rh_crit=RH_CRIT, vertical=None, p0=None, time_units=None, radius=None, variables=None,
                 member=None, cache_steps=8, opened=None):
        """Open ``path``; the keywords override what a file gets wrong or leaves out.

        Parameters
        ----------
        vertical : str, optional
            What the level coordinate is when the file does not say
            (:data:`VERTICAL_KINDS`: ``"pressure_hpa"``, ``"pressure_pa"``,
            ``"height_m"``, ``"height_km"``, ``"ncar_hybrid"``).
        p0 : float, optional
            Reference pressure (Pa) of hybrid levels, replacing the file's or
            the default.
        time_units : str, optional
            CF time units (``"days since 1988-01-01"``) replacing the file's.
        radius : float, optional
            Planet radius (m), replacing the file's grid mapping or model convention.
        variables : dict, optional
            Standard name → file variable (``{"temperature": "T2"}``) where
            the file's names or ``standard_name`` are not recognised.
        member : int, optional
            The ensemble member to read where fields have a member dimension
            (ERA5's ``number``, CF ``realization``): its number, else the control
            (0) or the first.
        opened : xarray.Dataset, optional
            The file already opened by xarray (a Zarr store).
        """
        self._p0, self._vertical_kind, self._notes = p0, vertical, []
        ds = opened if opened is not None else _open_netcdf(path)
        _refuse_unstructured(ds, path)
        self._ds = ds = self._choose_member(ds, path, member)
        lon_name, lat_name, projected, curvilinear, rotation = self._horizontal_axes(ds, path)
        time_name, time_dim = self._time_axis(ds)
        names, skipped = self._three_d_fields(ds, path, lon_name, lat_name, time_name, time_dim)
        self._time_dim = time_dim
        if curvilinear:
            lon, lat, lon_index, lat_index, lon2d, lat2d = self._curvilinear(ds, path, lon_name, lat_name, projected,
                                                                             *self._lonlat_dims)
        else:
            lon, lat, lon_index, lat_index = tidy_lonlat(ds[lon_name].values, ds[lat_name].values, path, lon_name,
                                                         lat_name)
            lon2d = lat2d = None
        times = self._times(ds, path, time_name, time_dim, time_units)
        self._nt = times.size
        heights, level_index, pressure, vertical = self._levels(ds, path, names, skipped, lat_index, lon_index,
                                                                lat.size, lon.size)
        grid = GlobeGrid(lon, lat, heights, rotation=rotation, lon2d=lon2d, lat2d=lat2d).validate(path)
        self._planet_radius(radius, vertical)
        fields = self._field_map(ds, path, names, skipped, variables)
        super().__init__(path, grid, times, fields, (level_index, lat_index, lon_index), pressure=pressure,
                         rh_crit=rh_crit,
                         vertical=vertical, skipped=skipped, notes=self._notes, cache_steps=cache_steps)
        if self._wrf and "T" in names and pressure is not None and "temperature" not in self.variables:
            self.variables["temperature"] = Variable("temperature", "K",
                                                     "from WRF T + 300 K and P + PB (Poisson's equation)")
            self.derived["temperature"] = "WRF T (perturbation potential temperature) + 300 K, P + PB"
            self.aliases.pop("temperature", None)

    # ------------------------------------------------------------------ the steps of __init__
    def _choose_member(self, ds, path, member):
        """``ds`` at one ensemble member (:attr:`members` lists them, :attr:`member` is the one read)."""
        dim = _member_dim(ds)
        self.members, self.member = [], None
        if dim is None:
            if member is not None:
                raise DataError(f"member {member} asked for, but the file has no ensemble member dimension", path=path,
                                field="member")
            return ds
        values = ds[dim].values if dim in ds.variables else np.arange(ds.sizes[dim])
        numbered = np.issubdtype(np.asarray(values).dtype, np.integer)
        self.members = [int(v) for v in values] if numbered else list(range(len(values)))
        if member is None:
            member = 0 if 0 in self.members else self.members[0]
        elif int(member) not in self.members:
            raise DataError(f"no member {member} (members: {', '.join(map(str, self.members))})", path=path,
                            field="member")
        self.member = int(member)
        if not numbered:
            self._notes.append(f"members: {dim!r} holds names; member={self.member} is {values[self.member]!s}")
        return ds.isel({dim: self.members.index(self.member)})

    def _horizontal_axes(self, ds, path):
        """``(lon name, lat name, projection axes or None, curvilinear?, rotation or None)``; sets the planet
        radius the grid mapping states (None when it states none)."""
        projected = _projection_axes(ds)
        try:
            lon_name, lat_name = _find_axis(ds, path, "lon"), _find_axis(ds, path, "lat")
        except DataError:
            if projected is None or _grid_mapping(ds) is None:
                raise
            lon_name, lat_name = projected  # x/y and a grid mapping only: positions from the projection
        curvilinear = ds[lon_name].ndim != 1 or ds[lat_name].ndim != 1 or (lon_name, lat_name) == projected
        if curvilinear:
            self._lonlat_dims = self._curvilinear_dims(ds, path, lon_name, lat_name, projected)
            rotation, self.earth_radius = self._mapping(ds, path, None)
        else:
            self._lonlat_dims = ds[lon_name].dims[0], ds[lat_name].dims[0]
            rotation, self.earth_radius = self._mapping(ds, path, lon_name)
        return lon_name, lat_name, projected, curvilinear, rotation

    @staticmethod
    def _time_axis(ds):
        """``(time coordinate or None, time dimension or None)``."""
        time_name = _find_time(ds)
        time_dim = ds[time_name].dims[0] if time_name and ds[time_name].ndim == 1 else None
        for dim in ("time", "Time"):  # a time dimension without a coordinate (WRF's 'Time'): numbered steps
            if time_dim is None and dim in ds.dims:
                time_name, time_dim = None, dim
        return time_name, time_dim

    def _three_d_fields(self, ds, path, lon_name, lat_name, time_name, time_dim):
        """Names of the 3-D fields on the most common level dimension, and ``{name: why}`` of the rest;
        sets :attr:`_dims` = (level, lat, lon) dimensions."""
        lon_dim, lat_dim = self._lonlat_dims
        candidates, skipped = {}, {}
        # Cell bounds and grid mappings describe coordinates; they are not fields to list as skipped.
        described = {_attr(v, "bounds")
                     for v in ds.variables.values()} | {_attr(v, "grid_mapping").split(":")[0].strip()
                                                        for v in ds.data_vars.values()}
        for name, var in ds.data_vars.items():
            if name in described:
                continue
            dims = [d for d in var.dims if d != time_dim]
            if lat_dim in dims and lon_dim in dims and len(dims) == 3:
                candidates[name] = [d for d in dims if d not in (lat_dim, lon_dim)][0]
            elif name not in (lon_name, lat_name, time_name):
                skipped[name] = f"dimensions {var.dims} are not (time, level, lat, lon)"
        if not candidates:
            raise DataError(f"no 3-D field on (level, {lat_dim}, {lon_dim}) (variables: "
                            f"{', '.join(ds.data_vars) or 'none'})",
                            path=path, field="variables")
        dims = list(candidates.values())
        self._zdim = zdim = max(set(dims), key=dims.count)
        for name, d in candidates.items():
            if d != zdim:
                skipped[name] = f"on levels {d!r}, not {zdim!r}"
        self._dims = (zdim, lat_dim, lon_dim)
        return [n for n, d in candidates.items() if d == zdim], skipped

    def _times(self, ds, path, time_name, time_dim, time_units):
        """The time axis (datetime64[s]): CF units (months too), step numbers, or one step."""
        if time_name is None and time_dim:
            times = step_times(ds.sizes[time_dim])
            self._notes.append(f"time: dimension {time_dim!r} has no coordinate variable; the {times.size} step(s) "
                               f"are numbered 0..{times.size - 1}, one hour apart")
            return times
        if not time_name:
            self._notes.append("time: the file has no time axis; one step")
            return np.array(["1970-01-01T00:00:00"], dtype="datetime64[s]")
        tv = ds[time_name]
        monthly = _month_times(tv.values, time_units or _attr(tv, "units"), tv.attrs.get("calendar"), path, time_name)
        if monthly is not None:
            times, note = monthly
        elif time_units:  # the user's own units must be right: no falling back to step numbers
            times, note = cf_times(tv.values, time_units, tv.attrs.get("calendar"), path, time_name), None
        else:
            times, note = cf_times_or_steps(tv.values, _attr(tv, "units"), tv.attrs.get("calendar"), path, time_name)
        if note:
            self._notes.append(note)
        if monthly is not None or not note:  # CF dates (not step numbers): keep the file's calendar
            self.calendar = (str(tv.attrs.get("calendar") or "standard")).strip().lower()
            self.time_origin = parse_iso(re.split(r"\s+since\s+", time_units or _attr(tv, "units"), maxsplit=1,
                                                  flags=re.IGNORECASE)[1], path, time_name)
        return times

    def _levels(self, ds, path, names, skipped, lat_index, lon_index, nj, ni):
        """``(heights, level index, pressure(t) or None, description)``: WRF eta levels or the CF vertical
        coordinate."""
        zdim = self._zdim
        self._wrf = _is_wrf(ds, zdim) and self._vertical_kind is None
        self._stagger, self._alpha = {}, None
        if not self._wrf:
            return self._vertical(ds, path, zdim, names, lat_index, lon_index, nj, ni)
        levels = self._wrf_levels(ds, path, zdim, lat_index, lon_index)
        self._stagger, bad = _wrf_staggered(ds, self._dims, self._time_dim)
        skipped.update(bad)
        for name in self._stagger:
            skipped.pop(name, None)
            names.append(name)
        if self._stagger:
            self._notes.append(f"staggered: {', '.join(sorted(self._stagger))} read at the mass points (mean of the "
                               "two neighbours)")
        if {"U", "V"} <= set(self._stagger):
            if "COSALPHA" in ds.variables and "SINALPHA" in ds.variables:
                self._alpha = tuple(self._wrf_plane(ds, n, lat_index, lon_index) for n in ("COSALPHA", "SINALPHA"))
                self._notes.append("wind: U, V turned from grid to earth axes with COSALPHA/SINALPHA")
            else:
                self._notes.append("wind: U, V are along the grid's axes (the file has no COSALPHA/SINALPHA to turn "
                                   "them east/north)")
        return levels

    def _planet_radius(self, radius, vertical):
        """:attr:`earth_radius`: the ``radius=`` override, the grid mapping's, the model's convention, else
        the mean Earth."""
        if radius is not None:
            self.earth_radius = float(radius)
        elif self.earth_radius is None and "NCAR" in vertical:
            self.earth_radius = CAM_RADIUS
            self._notes.append(f"radius: NCAR hybrid levels, so CAM's planet radius {CAM_RADIUS:g} m")
        elif self.earth_radius is None and self._wrf:
            self.earth_radius = WRF_RADIUS
            self._notes.append(f"radius: WRF file, so WRF's planet radius {WRF_RADIUS:g} m")
        elif self.earth_radius is None:
            self.earth_radius = EARTH_RADIUS

    def _field_map(self, ds, path, names, skipped, variables):
        """``{standard name: (file name, units, long name)}`` of the 3-D fields (``variables=`` first, then
        CF standard names and known names); a second file field for the same standard name is skipped."""
        chosen = {raw: std for std, raw in (variables or {}).items()}
        if self._wrf:  # WRF's T is the perturbation potential temperature (theta - 300 K), not air temperature
            for raw, std in (("T", "theta_perturbation"), ("CLDFRA", "cloud")):
                if raw in names and raw not in chosen and std not in chosen.values():
                    chosen[raw] = std
        for raw in chosen:
            if raw not in names:
                raise DataError(f"is not a 3-D field on the grid (fields: {', '.join(names)})", path=path, field=raw)
        fields, taken = {}, {}
        for name in sorted(names, key=lambda n: n not in chosen):
            std = chosen.get(name) or standard_name(name, ds[name].attrs)
            if std in fields:
                skipped[name] = f"another variable ({taken[std]!r}) already gives {std!r}"
                continue
            units = _attr(ds[name], "units")
            if std in ("temperature", "rh", "cloud"):
                units, note = plausible_units(std, units, self._raw(name, 0))
                if note:
                    self._notes.append(note)
            fields[std], taken[std] = (name, units, _attr(ds[name], "long_name")), name
        return fields

    def _read(self, name, t):
        if (name in ("u", "v") and self._alpha is not None
                and self.file_names.get("u") == "U" and self.file_names.get("v") == "V"):
            # WRF's U, V are along the grid's x and y; COSALPHA/SINALPHA turn them to east and north.
            u, v = (np.asarray(super(NetCDFDataset, self)._read(n, t), dtype=np.float64) for n in ("u", "v"))
            cos_a, sin_a = self._alpha
            return (u * cos_a - v * sin_a if name == "u" else v * cos_a + u * sin_a).astype(np.float32)
        if name == "temperature" and self._wrf and "temperature" not in self._fields:
            theta = np.asarray(self._read("theta_perturbation", t), dtype=np.float64) + WRF_T0
            return (theta * (np.asarray(self._pressure(t), dtype=np.float64) / 1.0e5) ** WRF_RCP).astype(np.float32)
        return super()._read(name, t)

    # ------------------------------------------------------------------ WRF
    def _wrf_levels(self, ds, path, zdim, lat_index, lon_index):
        """WRF eta levels: heights of the mass levels from the first step's geopotential ``(PH + PHB) / g`` on
        the staggered levels (mean of the two around each mass level); pressure ``P + PB``."""
        take = np.ix_(lat_index, lon_index)
        ydim, xdim = self._dims[1:]

        def plane(name, t):
            a = ds[name]
            if self._time_dim in a.dims:
                a = a.isel({self._time_dim: t})
            stag = [d for d in a.dims if d not in (ydim, xdim)]
            return np.asarray(a.transpose(*stag, ydim, xdim).values, dtype=np.float64)[(slice(None),) + take]

        z_stag = (plane("PH", 0) + plane("PHB", 0)) / G0
        if z_stag.shape[0] != ds.sizes[zdim] + 1:
            raise DataError(f"PH has {z_stag.shape[0]} staggered levels for {ds.sizes[zdim]} mass levels (expected "
                            "one more)", path=path, field="PH")
        heights = 0.5 * (z_stag[:-1] + z_stag[1:])
        level_index = self._level_order(heights.reshape(heights.shape[0], -1).mean(axis=1), path, zdim)
        heights = heights[level_index]
        pressure = None
        if "P" in ds.variables and "PB" in ds.variables:

            def pressure(t):
                return (plane("P", t) + plane("PB", t))[level_index].astype(np.float32)

        return heights, level_index, pressure, "WRF eta levels (terrain following, heights from PH + PHB)"

    def _wrf_plane(self, ds, name, lat_index, lon_index):
        """A 2-D WRF field (first step) in Nephele's (y, x) order, shaped (1, ny, nx) to broadcast over levels."""
        var = ds[name]
        var = var.isel({d: 0 for d in var.dims if d not in self._dims[1:]})
        plane = np.asarray(var.transpose(*self._dims[1:]).values, dtype=np.float64)
        return plane[np.ix_(lat_index, lon_index)][None]

    # ------------------------------------------------------------------ horizontal
    @staticmethod
    def _mapping(ds, path, lon_name):
        """``(rotation or None, planet radius in m or None)`` from the grid mapping."""
        name = _grid_mapping(ds)
        gm = ds[name].attrs if name else {}
        radius = gm.get("earth_radius", gm.get("semi_major_axis"))
        radius = float(radius) if radius is not None else None
        if lon_name is None or _attr(ds[lon_name], "standard_name").lower() != "grid_longitude":
            return None, radius
        if str(gm.get("grid_mapping_name", "")) != "rotated_latitude_longitude":
            raise DataError("has standard_name grid_longitude but no rotated_latitude_longitude grid mapping",
                            path=path, field=lon_name)
        try:
            pole = [float(gm[k]) for k in ("grid_north_pole_longitude", "grid_north_pole_latitude")]
        except KeyError as exc:
            raise DataError(f"grid mapping lacks {exc.args[0]}", path=path, field=name) from None
        return rotated_pole_matrix(*pole, float(gm.get("north_pole_grid_longitude", 0.0))), radius

    # ------------------------------------------------------------------ curvilinear
    @staticmethod
    def _curvilinear_dims(ds, path, lon_name, lat_name, projected):
        """``(x dim, y dim)`` of a grid with 2-D longitude/latitude (the last two dimensions; WRF's
        ``XLAT(Time, south_north, west_east)`` too) or of projection-only x/y axes."""
        if (lon_name, lat_name) == projected:
            return ds[lon_name].dims[0], ds[lat_name].dims[0]
        lon_dims, lat_dims = ds[lon_name].dims, ds[lat_name].dims
        if len(lon_dims) < 2 or lon_dims[-2:] != lat_dims[-2:]:
            raise DataError(f"longitude dimensions {lon_dims} and latitude dimensions {lat_dims} do not match",
                            path=path, field=lon_name)
        return lon_dims[-1], lon_dims[-2]

    def _curvilinear(self, ds, path, lon_name, lat_name, projected, xdim, ydim):
        """Axes, index orders and true 2-D positions of a curvilinear grid.

        Positions: the file's 2-D latitude/longitude (first step where they
        carry a time dimension), else the grid mapping's inverse projection
        (:func:`projected_lonlat`).  The grid keeps index axes ``0..n-1``; rows
        are reversed where needed so that (i, j, up) is right-handed like a
        longitude × latitude grid (contour normals then point the same way).
        """
        if (lon_name, lat_name) == projected:
            mapping = _grid_mapping(ds)
            scale = [_LENGTH.get(_attr(ds[n], "units").lower(), None) for n in projected]
            if None in scale:
                raise DataError("projection coordinates need units m or km, got "
                                f"{[_attr(ds[n], 'units') for n in projected]}", path=path, field=lon_name)
            lon2d, lat2d, notes = projected_lonlat(dict(ds[mapping].attrs), ds[lon_name].values * scale[0],
                                                   ds[lat_name].values * scale[1], path, mapping)
            name = _attr(ds[mapping], "grid_mapping_name")
            self._notes += ([f"grid: longitudes/latitudes computed from the {name} grid mapping"]
                            + [f"grid: {n}" for n in notes])
        else:
            planes = []
            for name in (lon_name, lat_name):
                var = ds[name]
                extra = {d: 0 for d in var.dims if d not in (ydim, xdim)}  # WRF: XLAT(Time, south_north, west_east)
                planes.append(np.asarray(var.isel(extra).transpose(ydim, xdim).values, dtype=np.float64))
            lon2d, lat2d = planes
        if lon2d.shape[0] < 2 or lon2d.shape[1] < 2:
            raise DataError(f"a curvilinear grid needs at least 2 x 2 columns, got {lon2d.shape}", path=path,
                            field=lon_name)
        if not (np.all(np.isfinite(lon2d)) and np.all(np.isfinite(lat2d))):
            raise DataError("has NaN or infinite 2-D longitudes/latitudes (masked land points?)", path=path,
                            field=lon_name)
        lon_index, lat_index = np.arange(lon2d.shape[1]), np.arange(lon2d.shape[0])
        if not right_handed(lon2d, lat2d):
            lat_index = lat_index[::-1]
        lon2d, lat2d = lon2d[lat_index], lat2d[lat_index]
        return np.arange(lon_index.size,
                         dtype=np.float64), np.arange(lat_index.size,
                                                      dtype=np.float64), lon_index, lat_index, lon2d, lat2d

    def _raw(self, name, t):
        var = self._ds[name]
        if self._time_dim in var.dims:
            var = var.isel({self._time_dim: t})
        staggered = self._stagger.get(name)
        if staggered is not None:  # WRF's C grid: to the mass points
            axis = next(i for i, d in enumerate(staggered) if d in WRF_STAGGER)
            return destagger(var.transpose(*staggered).values, axis).astype(np.float32)
        return np.asarray(var.transpose(*self._dims).values, dtype=np.float32)

    def close(self):
        """Close the file."""
        self._ds.close()


def open_netcdf(path, **kw):
    """Open a CF NetCDF file (or a ``.zip`` of them, as the Copernicus Climate Data Store delivers) as a lazy
    :class:`NetCDFDataset`."""
    if kw.pop("level_type", None) is not None:
        raise DataError("level_type= chooses among the kinds of level of a GRIB file; a NetCDF file has one level "
                        "coordinate per field", path=path, field="level_type")
    if str(path).lower().endswith(".zip"):
        inner, note = _from_zip(path)
        ds = NetCDFDataset(inner, **kw)
        ds.source = ds.path = str(path)
        ds.notes.append(note)
        return ds
    return NetCDFDataset(path, **kw)


__all__ = ["NetCDFDataset", "destagger", "open_netcdf"]
