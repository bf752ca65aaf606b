"""The vertical of a GRIB dataset: heights of its levels and the pressure on them.

=============================== =================================================================
kind of level                   heights (m) and pressure
=============================== =================================================================
``isobaricInhPa``/``InPa``      the mean geopotential height of each level in the first step
                                (``gh``, or ``z`` / g), else the ISO standard atmosphere; flat
``hybrid`` with ``pv``          ``p = a + b ps`` on half levels, full levels their mean
                                (:mod:`.modellevels`), ``ps`` from ``lnsp`` (its exponential) or
                                ``sp``; heights by the hypsometric equation from ``t`` (and ``q``)
                                up from the surface height (``z`` / g or ``orog``) where every level
                                from the lowest up is in the file, else the standard atmosphere of
                                the pressure; terrain following
``hybrid`` without ``pv``       NCEP's native levels (RAP, HRRR): pressure ``pres`` and heights
                                ``gh`` on the levels themselves
``heightAboveSea``/``Ground``   the level values (plus the orography above ground when the file has it)
others (``sigma``, ``theta``,   heights from ``gh`` (or ``z``) on the levels, pressure from ``pres``
``potentialVorticity``...)
=============================== =================================================================

Heights and pressure use the first step; levels are put bottom to top.

References
----------
.. [1] ECMWF, IFS Documentation, Part III, section 2.2 (hybrid levels).
.. [2] ISO 2533:1975, Standard Atmosphere.
"""

import numpy as np

from ..errors import DataError
from .humidity import G0, standard_height
from .modellevels import half_levels, hypsometric_heights, pressure_half

ISOBARIC = {"isobaricInhPa": 100.0, "isobaricInPa": 1.0}
"""Pressure kinds of level and their level unit in Pa."""


def vertical(ds, path, lat_index, lon_index):
    """``(heights (nk, nj, ni), level index, pressure(t) or None, description)`` of a GRIB dataset in the making.

    ``ds`` is a :class:`~nephele.core.climate.grib.GribDataset` whose level axis
    (``ds._levels``, ascending level values) and variables are set.
    """
    take = (slice(None), *np.ix_(lat_index, lon_index))
    kind = ds.level_type
    if kind in ISOBARIC:
        return _isobaric(ds, path, take)
    if kind == "hybrid":
        return _hybrid(ds, path, take)
    if kind in ("heightAboveSea", "heightAboveGround"):
        return _height_levels(ds, path, take)
    return _by_geopotential(ds, path, take)


def _order(upward, path, field):
    """Indices putting levels bottom to top from a quantity growing upward (NaN ignored)."""
    order = np.argsort(upward, kind="stable")
    if not np.all(np.diff(np.asarray(upward)[order]) > 0):
        raise DataError("levels do not stand in one order (two levels at the same height)", path=path, field=field)
    return order


def _geopotential(ds):
    """``(name, scale to metres)`` of a 3-D geopotential height (``gh``, gpm) or geopotential (``z``) field, or None."""
    for name in ds._names:
        c = ds._concept_of[name]
        units = (c.get("units") or "").replace(" ", "")
        if c["shortName"] in ("gh", "h") or units == "gpm":
            return name, 1.0
        if c["shortName"] == "z" or units in ("m**2s**-2", "m2s-2"):
            return name, 1.0 / G0
    return None


def _field(ds, short):
    return next((n for n in ds._names if ds._concept_of[n]["shortName"] == short), None)


def _isobaric(ds, path, take):
    p = ds._levels * ISOBARIC[ds.level_type]
    level_index = np.arange(p.size)[::-1]
    p = p[level_index]
    key = f"heights_{ds.level_type}_{ds.member}_{ds._grid_id}"
    if key in ds._index.extras:  # kept with the index (same file, same code): no field to decode
        heights, source = ds._index.extras[key], str(ds._index.extras[key + "_about"])
    else:
        heights, source = _isobaric_heights(ds, p, level_index, take)
        ds._index.keep(key, heights)
        ds._index.keep(key + "_about", np.array(source))
    nj, ni = ds._geometry.shape
    p3 = np.broadcast_to(p[:, None, None], (p.size, nj, ni)).astype(np.float32)
    return (np.broadcast_to(heights[:, None, None], (p.size, nj, ni)), level_index, lambda t: p3,
            f"pressure levels, heights from the {source} (not terrain following)")


def _isobaric_heights(ds, p, level_index, take):
    """Heights of pressure levels: the mean geopotential height of each in the first step, else the standard
    atmosphere."""
    heights = standard_height(p)
    source = "standard atmosphere"
    found = _geopotential(ds)
    if found is not None:
        name, scale = found
        z = ds._raw(name, 0)[level_index][take] * scale
        with np.errstate(invalid="ignore"), __import__("warnings").catch_warnings():
            __import__("warnings").simplefilter("ignore", RuntimeWarning)  # all-NaN levels: filled below
            mean = np.nanmean(z.reshape(z.shape[0], -1), axis=1)
        filled = np.where(np.isfinite(mean), mean, heights)
        if np.all(np.diff(filled) > 0):
            heights, source = filled, f"mean geopotential height ({name!r})"
            gaps = int((~np.isfinite(mean)).sum())
            if gaps:
                source += f"; {gaps} level(s) without it from the standard atmosphere"
        else:
            source += f" (the mean of {name!r} does not rise with the levels)"
    return heights, source


def _surface_pressure(ds, t, take):
    """Surface pressure (Pa) at step ``t`` from ``lnsp`` or ``sp``, Nephele's horizontal order; None when absent."""
    lnsp = ds.single_level("lnsp", t, ("hybrid",))
    if lnsp is not None:
        return np.exp(np.asarray(lnsp, dtype=np.float64))[take[1:]]
    sp = ds.single_level("sp", t, ("surface",))
    return None if sp is None else np.asarray(sp, dtype=np.float64)[take[1:]]


def _surface_height(ds, take):
    """Surface height (m) from ``z`` (geopotential on the surface or model level 1) or ``orog``; and where from."""
    for short, kinds, scale in (("z", ("surface", "hybrid"), 1.0 / G0), ("orog", ("surface",), 1.0)):
        a = ds.single_level(short, 0, kinds)
        if a is not None:
            return np.asarray(a, dtype=np.float64)[take[1:]] * scale, short
    return 0.0, None


def _hybrid(ds, path, take):
    first = ds._first_message(ds._names)
    pv = ds._index.get(first, ["pv"]).get("pv")
    if pv is None or np.size(pv) < 4:
        return _native(ds, path, take)
    a, b, numbered_from_top = half_levels(pv)
    nlev = a.size - 1
    n = ds._levels.astype(np.int64)
    if n.min() < 1 or n.max() > nlev:
        raise DataError(f"model levels {n.min()}..{n.max()} do not fit the {nlev} levels of the pv coefficients",
                        path=path, field="pv")
    upper = n - 1 if numbered_from_top else nlev - n  # half levels above and below each full level (top-down)
    if _surface_pressure(ds, 0, take) is None:
        if _field(ds, "pres") is not None:
            return _native(ds, path, take)
        raise DataError("hybrid levels need the surface pressure (lnsp on model level 1, or sp on the surface) for "
                        "the same times and member", path=path, field="pv")

    def pressure_of(t):
        ps = _surface_pressure(ds, t, take)
        if ps is None:
            raise DataError(f"no surface pressure (lnsp or sp) at step {t}", path=path, field="pv")
        return pressure_half(a, b, ps)

    p_mean = a[upper] + a[upper + 1] + (b[upper] + b[upper + 1]) * 101325.0
    level_index = _order(-p_mean, path, "level")

    def pressure(t):
        half = pressure_of(t)
        return (0.5 * (half[upper] + half[upper + 1]))[level_index].astype(np.float32)

    half0 = pressure_of(0)
    heights, how = _hybrid_heights(ds, take, half0, upper, level_index, nlev)
    ds._notes.append(f"levels: {n.size} of {nlev} hybrid levels, pressure a + b ps from the pv coefficients (ps from "
                     f"{'lnsp' if ds.single_level('lnsp', 0, ('hybrid',)) is not None else 'sp'})")
    return heights, level_index, pressure, f"hybrid sigma-pressure model levels (terrain following), heights {how}"


def _hybrid_heights(ds, take, half, upper, level_index, nlev):
    """Heights (Nephele's order) of model levels: hypsometric where possible, else the standard atmosphere."""
    found = _geopotential(ds)
    if found is not None:
        name, scale = found
        z = ds._raw(name, 0)[take][level_index] * scale
        if np.all(np.isfinite(z)):
            return z, f"from {name!r} on the levels"
    t_name, q_name = _field(ds, "t"), _field(ds, "q")
    full = np.arange(nlev)
    have = np.sort(upper)
    if t_name is not None and have.size and have[-1] == nlev - 1 and np.array_equal(have, full[have[0]:]):
        # every level from the lowest up: integrate upward (top-down arrays as modellevels wants)
        top_down = np.argsort(upper)
        t = ds._raw(t_name, 0)[take][top_down]
        q = ds._raw(q_name, 0)[take][top_down] if q_name is not None else None
        if np.all(np.isfinite(t)) and (q is None or np.all(np.isfinite(q))):
            zs, where = _surface_height(ds, take)
            z = hypsometric_heights(half[have[0]:], t, q, zs)
            rank = np.empty_like(top_down)
            rank[top_down] = np.arange(top_down.size)
            how = "by the hypsometric equation from t" + (" and q" if q is not None else " (dry air: no q)")
            how += f", surface at {where!r}" if where else ", surface at sea level (no z or orog in the file)"
            return z[rank][level_index], how
    p = 0.5 * (half[upper] + half[upper + 1])[level_index]
    return standard_height(p), ("from the standard atmosphere of the pressure (not every level from the lowest up, "
                                "or no t)")


def _native(ds, path, take):
    """NCEP native hybrid levels without coefficients: their own pressure and heights."""
    pres = _field(ds, "pres")
    found = _geopotential(ds)
    if pres is None and found is None:
        raise DataError("hybrid levels without pv coefficients need a pressure ('pres') or height ('gh') field on them",
                        path=path, field="level_type")
    p0 = ds._raw(pres, 0)[take] if pres is not None else None
    if found is not None:
        name, scale = found
        z = ds._raw(name, 0)[take] * scale
        level_index = _order(np.nanmean(z.reshape(z.shape[0], -1), axis=1), path, "level")
        heights, how = z[level_index], f"from {name!r}"
    else:
        level_index = _order(-np.nanmean(p0.reshape(p0.shape[0], -1), axis=1), path, "level")
        heights, how = standard_height(p0[level_index]), f"from the standard atmosphere of {pres!r}"
    pressure = None
    if pres is not None:
        def pressure(t):
            return ds._raw(pres, t)[take][level_index].astype(np.float32)

    return heights, level_index, pressure, f"native model levels (terrain following), heights {how}"


def _height_levels(ds, path, take):
    h = ds._levels.astype(np.float64)
    level_index = _order(h, path, "level")
    nj, ni = ds._geometry.shape
    heights = np.broadcast_to(h[level_index, None, None], (h.size, nj, ni))
    if ds.level_type == "heightAboveGround":
        zs, where = _surface_height(ds, take)
        if where:
            return heights + zs[None], level_index, None, f"heights above ground plus the surface height ({where!r})"
        ds._notes.append("levels: heights above ground read as heights above sea level (no z or orog in the file)")
    return heights, level_index, None, "height levels (flat)"


def _by_geopotential(ds, path, take):
    found = _geopotential(ds)
    if found is None:
        raise DataError(f"cannot place {ds.level_type} levels: no geopotential height ('gh' or 'z') on them; choose "
                        "another kind with level_type=", path=path, field="level_type")
    name, scale = found
    z = ds._raw(name, 0)[take] * scale
    holes = int((~np.isfinite(z)).any(axis=0).sum())
    if holes:
        raise DataError(f"cannot place {ds.level_type} levels: {name!r} is missing in {holes} column(s) (the levels "
                        "do not exist everywhere); choose another kind with level_type=", path=path, field="level_type")
    level_index = _order(np.nanmean(z.reshape(z.shape[0], -1), axis=1), path, "level")
    pres = _field(ds, "pres")
    pressure = None
    if pres is not None:
        def pressure(t):
            return ds._raw(pres, t)[take][level_index].astype(np.float32)

    return (z[level_index], level_index, pressure,
            f"{ds.level_type} levels at the heights of {name!r} (terrain following)")


__all__ = ["ISOBARIC", "vertical"]
