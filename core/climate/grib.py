"""GRIB1/GRIB2 files as forecast centres deliver them, read through ecCodes.

An NCEP or ECMWF product file mixes many kinds of level (isobaric, model,
surface, tropopause, cloud layers...), ensemble members and forecast steps.
:func:`open_grib` scans the message headers once (:mod:`.gribscan`, cached in
Nephele's cache) and reads:

* **one kind of level**: the one holding the most 3-D variables (fields on two
  or more levels; isobaric for GFS and IFS pressure-level products), or the one
  ``level_type=`` names; :attr:`GribDataset.level_types` lists every kind with
  its variables, and single-level fields anywhere are listed, never an error;
* **one ensemble member**: the control (number 0) or the lowest number, or
  ``member=``; :attr:`GribDataset.members` lists them;
* **valid time** (reference time + step) as the time axis, whether the file has
  many steps, many reference times or both; where two messages give the same
  variable, level and valid time, the later reference time (the shorter lead) wins;
* **one level axis** shared by every 3-D variable: the union of their levels;
  a variable lacks the levels it does not have (NaN there);
* the grid at its true positions (:mod:`.gribgrid`): regular and reduced
  Gaussian (expanded), rotated (ECMWF and NCEP encodings), Lambert, polar
  stereographic and other projections;
* the vertical (:mod:`.griblevels`): pressure levels at the mean height of
  their geopotential, hybrid model levels from the messages' ``pv``
  coefficients and surface pressure (``lnsp`` or ``sp``) with heights from the
  hypsometric equation, NCEP's native levels from their own pressure and
  height fields, height levels.

Values are decoded by ecCodes, one message at a time (no GRIB decoding here).

References
----------
.. [1] ECMWF, ecCodes; WMO FM 92 GRIB.
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import numpy as np

from ..errors import DataError
from .grid import EARTH_RADIUS, GlobeGrid, right_handed
from .gridfile import FileDataset, standard_name, tidy_lonlat
from .humidity import RH_CRIT

ATMOSPHERE_SKIP = ("depthBelowLand", "depthBelowLandLayer", "soil", "soilLayer", "snow", "snowLayer", "depthBelowSea",
                   "oceanSurface", "seaIce")
"""Kinds of level below ground or at sea that are never chosen by default (their fields are not the air's)."""
_PREFER = ("isobaricInhPa", "hybrid")


class GribDataset(FileDataset):
    """A GRIB file read lazily; see :func:`open_grib`.

    Attributes
    ----------
    level_type : str
        The kind of level read.
    level_types : dict
        Every kind of level in the file → ``{"3d": 3-D variables, "fields": messages}``.
    members : list of int
        The ensemble members of the chosen kind of level (empty when the file has none).
    member : int or None
        The member read.
    """

    def __init__(self, path, *, level_type=None, member=None, radius=None, variables=None, rh_crit=RH_CRIT,
                 cache_steps=8):
        from . import griblevels
        from .gribscan import open_index

        self._index = index = open_index(path)
        self._notes = list(index.notes)
        self.level_types = self._survey(index)
        self.level_type = self._choose_level_type(path, level_type)
        rows = np.flatnonzero(np.isin(index.group, [g for g, info in enumerate(index.groups)
                                                    if info["typeOfLevel"] == self.level_type]))
        rows = self._choose_member(path, rows, member)
        names, skipped = self._variables(path, rows)
        self._levels, times = self._axes(names)
        self._valid = times
        self._names = names
        first = self._first_message(names)
        g = self._grid(path, first, next(iter(names)))
        self._geometry = g
        self._notes += g.notes
        lon, lat, lon_index, lat_index, lon2d, lat2d = self._horizontal(path, g)
        self.earth_radius = float(radius) if radius is not None else (g.radius or EARTH_RADIUS)
        self._nt = times.size
        heights, level_index, pressure, vertical = griblevels.vertical(self, path, lat_index, lon_index)
        grid = GlobeGrid(lon, lat, heights, rotation=g.rotation, lon2d=lon2d, lat2d=lat2d).validate(path)
        fields = self._field_map(path, names, skipped, variables)
        super().__init__(path, grid, times, fields, (level_index, lat_index, lon_index), pressure=pressure,
                         rh_crit=rh_crit,
                         vertical=vertical, skipped=skipped, notes=self._notes, cache_steps=cache_steps)
        index.save()

    # ------------------------------------------------------------------ what the file holds
    def _survey(self, index):
        """``{typeOfLevel: {"3d": n, "fields": n}}``: 3-D variables (a parameter on two or more levels) and
        fields per kind."""
        by_type = {}
        for g, info in enumerate(index.groups):
            by_type.setdefault(info["typeOfLevel"], {}).setdefault(tuple(info["raw"]), []).append(g)
        out = {}
        for kind, params in by_type.items():
            n3 = 0
            count = 0
            for groups in params.values():
                rows = np.isin(index.group, groups)
                count += int(rows.sum())
                n3 += np.unique(index.level[rows]).size >= 2
            out[kind] = {"3d": int(n3), "fields": count}
        return out

    def _choose_level_type(self, path, asked):
        kinds = self.level_types
        if asked is not None:
            if asked not in kinds:
                raise DataError(f"no fields on level type {asked!r} (found: {', '.join(sorted(kinds))})", path=path,
                                field="level_type")
            if kinds[asked]["3d"] == 0:
                raise DataError(f"level type {asked!r} has no field on two or more levels (3-D fields: "
                                f"{_summary(kinds) or 'none'})", path=path, field="level_type")
            return asked
        usable = {k: v for k, v in kinds.items() if v["3d"] and k not in ATMOSPHERE_SKIP}
        if not usable:
            damaged = "".join(f"; {n}" for n in self._notes if n.startswith("scan:"))
            raise DataError("no 3-D field: no parameter on two or more levels of one kind (level types: "
                            f"{', '.join(sorted(kinds))})"
                            + damaged, path=path, field="variables")
        return max(usable, key=lambda k: (usable[k]["3d"], k in _PREFER, -_PREFER.index(k) if k in _PREFER else 0, k))

    def _choose_member(self, path, rows, member):
        numbers = np.unique(self._index.number[rows])
        self.members = [int(n) for n in numbers if n >= 0]
        if not self.members:
            if member is not None:
                raise DataError(f"member {member} asked for, but the file has no ensemble members", path=path,
                                field="member")
            self.member = None
            return rows
        if member is None:
            member = 0 if 0 in self.members else self.members[0]
        elif int(member) not in self.members:
            raise DataError(f"no member {member} (members: {_ranges(self.members)})", path=path, field="member")
        self.member = int(member)
        return rows[self._index.number[rows] == self.member]

    def _variables(self, path, rows):
        """``{name: rows}`` of the 3-D variables among ``rows``, and ``{name: why}`` of the single-level ones."""
        index = self._index
        found = {}
        for g in np.unique(index.group[rows]):
            c = index.concept(int(g))
            name = (c["shortName"] if c["shortName"] not in (None, "unknown")
                    else "param_" + "_".join(str(r) for r in index.groups[g]["raw"][1:4]))
            processing = index.groups[g]["raw"][5 if index.groups[g]["edition"] == 2 else 3]  # statistical processing
            found.setdefault((name, processing), []).append(int(g))
        names, skipped, self._concept_of = {}, {}, {}
        plain = {}
        for name, _ in found:
            plain[name] = plain.get(name, 0) + 1
        for (name, processing), groups in found.items():
            label = name if plain[name] == 1 else f"{name}_{processing}"
            sel = rows[np.isin(index.group[rows], groups)]
            levels = np.unique(index.level[sel])
            self._concept_of[label] = index.concept(groups[0])
            if levels.size >= 2:
                names[label] = sel
            else:
                skipped[label] = f"on one level only ({levels[0]:g}): a 2-D field"
        if not names:
            raise DataError(f"no field on two or more {self.level_type} levels", path=path, field="level_type")
        grids = {n: index.groups[int(index.group[r[0]])]["grid"] for n, r in names.items()}
        counts = list(grids.values())
        self._grid_id = max(set(counts), key=counts.count)
        for n, grid in grids.items():
            if grid != self._grid_id:
                skipped[n] = "on another grid than the other 3-D fields"
                del names[n]
        return names, skipped

    def _axes(self, names):
        """The shared level axis (ascending level values) and the valid times; fills :attr:`_table`."""
        index = self._index
        all_rows = np.concatenate(list(names.values()))
        levels = np.unique(index.level[all_rows])
        times = np.unique(index.valid[all_rows])
        self._table, clashes = {}, 0
        for name, rows in names.items():
            table = np.full((times.size, levels.size), -1, dtype=np.int64)
            order = rows[np.argsort(index.ref[rows], kind="stable")]  # later reference times overwrite earlier ones
            t = np.searchsorted(times, index.valid[order])
            k = np.searchsorted(levels, index.level[order])
            clashes += order.size - np.unique(t * levels.size + k).size
            table[t, k] = order
            self._table[name] = table
        if clashes:
            self._notes.append(f"time: {clashes} field(s) repeat a valid time from an earlier reference time; the "
                               "later reference time (shorter lead) is read")
        missing = {n: int((tab < 0).all(axis=0).sum()) for n, tab in self._table.items()}
        partial = [f"{n} ({levels.size - m} of {levels.size})" for n, m in sorted(missing.items()) if m]
        if partial:
            self._notes.append(f"levels: one axis of {levels.size} {self.level_type} levels shared by all variables; "
                               f"NaN where a variable has no level: {', '.join(partial)}")
        return levels, times

    def _first_message(self, names):
        tab = self._table[next(iter(names))]
        return int(tab[tab >= 0][0])

    def _grid(self, path, first, field):
        """The :class:`~nephele.core.climate.gribgrid.GribGrid` of message ``first``, kept with the index."""
        import json

        from .gribgrid import GribGrid, grid_of

        index, key = self._index, f"grid_{self._grid_id}_"
        if key + "meta" in index.extras:
            arrays = {k[len(key):]: v for k, v in index.extras.items() if k.startswith(key) and k != key + "meta"}
            return GribGrid.from_arrays(json.loads(str(index.extras[key + "meta"])), arrays)
        g = grid_of(index, first, path, field)
        meta, arrays = g.arrays()
        index.keep(key + "meta", np.array(json.dumps(meta)))
        for k, v in arrays.items():
            index.keep(key + k, v)
        return g

    def _horizontal(self, path, g):
        """``(lon, lat, lon index, lat index, lon2d, lat2d)`` in Nephele's order."""
        if g.lon2d is None:
            lon, lat, lon_index, lat_index = tidy_lonlat(g.lon, g.lat, path, "longitude", "latitude")
            return lon, lat, lon_index, lat_index, None, None
        nj, ni = g.shape
        lat_index = np.arange(nj) if right_handed(g.lon2d, g.lat2d) else np.arange(nj)[::-1]
        return (np.arange(ni, dtype=np.float64), np.arange(nj, dtype=np.float64), np.arange(ni), lat_index,
                g.lon2d[lat_index], g.lat2d[lat_index])

    def _field_map(self, path, names, skipped, variables):
        chosen = {raw: std for std, raw in (variables or {}).items()}
        for raw in chosen:
            if raw not in names:
                raise DataError(f"is not a 3-D field on the {self.level_type} levels (fields: {', '.join(names)})",
                                path=path, field=raw)
        fields, taken = {}, {}
        for name in sorted(names, key=lambda n: n not in chosen):
            c = self._concept_of[name]
            std = chosen.get(name) or standard_name(name, {"standard_name": c.get("cfName") or "",
                                                           "units": c.get("units") or ""})
            if std in fields:
                skipped[name] = f"another variable ({taken[std]!r}) already gives {std!r}"
                continue
            fields[std], taken[std] = (name, c.get("units") or "", c.get("name") or ""), name
        return fields

    # ------------------------------------------------------------------ reading
    def _raw(self, name, t):
        """Step ``t`` of variable ``name`` as ``(levels, rows, columns)`` in file order; NaN for missing levels."""
        table = self._table[name][t]
        nj, ni = self._geometry.shape
        out = np.empty((table.size, nj, ni), dtype=np.float32)
        for k, i in enumerate(table):
            out[k] = self._geometry.to_2d(self._index.values(int(i))) if i >= 0 else np.nan
        return out

    def single_level(self, short_name, t, level_types):
        """A 2-D field of the same member and valid time on one of ``level_types`` (file order), or None."""
        index = self._index
        want = self._valid[t]
        for g, info in enumerate(index.groups):
            if (info["typeOfLevel"] not in level_types or info["grid"] != self._grid_id
                    or index.short_name(g) != short_name):
                continue
            rows = np.flatnonzero((index.group == g) & (index.valid == want))
            if self.member is not None:
                rows = rows[index.number[rows] == self.member]
            if rows.size:
                return self._geometry.to_2d(index.values(int(rows[np.argmax(index.ref[rows])])), np.float64)
        return None

    def close(self):
        """Close the file."""
        self._index.close()


def _ranges(numbers):
    numbers = sorted(numbers)
    return (f"{numbers[0]}..{numbers[-1]}" if numbers == list(range(numbers[0], numbers[-1] + 1)) and len(numbers) > 2
            else ", ".join(map(str, numbers)))


def _summary(kinds):
    return ", ".join(f"{k} {v['3d']}" for k, v in sorted(kinds.items()) if v["3d"])


def open_grib(path, **kw):
    """Open a GRIB file as a lazy :class:`GribDataset`.

    Parameters
    ----------
    path : path
    level_type : str, optional
        The ecCodes ``typeOfLevel`` to read (``"isobaricInhPa"``, ``"hybrid"``...);
        by default the kind of level with the most 3-D variables.
    member : int, optional
        Ensemble member (``number``); by default the control or the lowest.
    radius : float, optional
        Planet radius (m), replacing the grid's.
    variables : dict, optional
        Standard name → GRIB ``shortName`` where the names are not recognised.

    Raises
    ------
    DataError
        ecCodes missing, not GRIB, no 3-D field, an unknown level type or
        member, a grid Nephele does not place; ``vertical=``, ``p0=`` and
        ``time_units=`` (GRIB states its levels and times).
    """
    given = sorted(k for k in ("vertical", "p0", "time_units") if kw.get(k) is not None)
    if given:
        raise DataError(f"GRIB files state their levels and times; {', '.join(given)} apply to NetCDF and Zarr files",
                        path=path, field=given[0])
    for k in ("vertical", "p0", "time_units"):
        kw.pop(k, None)
    from .gribscan import need_eccodes

    eccodes = need_eccodes(path)
    try:
        return GribDataset(path, **kw)
    except eccodes.CodesInternalError as exc:  # a message that scanned but will not open: one line, as everywhere
        raise DataError(f"cannot read as GRIB ({type(exc).__name__}: "
                        f"{str(exc).strip().splitlines()[0] if str(exc).strip() else ''})",
                        path=path) from None


__all__ = ["GribDataset", "open_grib"]
