"""The vertical coordinate of a CF NetCDF file: level heights and the pressure on the levels.

A mixin of :class:`~nephele.core.climate.netcdf.NetCDFDataset` (see its module
docstring for the table of vertical coordinates): pressure levels, CF
parametric coordinates (hybrid sigma-pressure, sigma, hybrid height) and
NCAR's hybrid convention, height levels.

References
----------
.. [1] CF Conventions 1.11, Appendix D (parametric vertical coordinates).
"""

import re

import numpy as np

from ..errors import DataError
from .gridfile import pressure_scale
from .humidity import G0, standard_height

_HEIGHT_NAMES = ("zg", "z", "hgt", "geopotential_height", "gh", "geopot", "phi")
_PARAMETRIC = ("atmosphere_hybrid_sigma_pressure_coordinate", "atmosphere_sigma_coordinate",
               "atmosphere_hybrid_height_coordinate")
CAM_P0 = 100000.0
"""CAM's reference pressure (Pa), used when a file names ``P0`` but does not store it."""
VERTICAL_KINDS = {
    "pressure_hpa": ("air_pressure", "hpa"),
    "pressure_pa": ("air_pressure", "pa"),
    "height_m": ("height", "m"),
    "height_km": ("height", "km"),
    "ncar_hybrid": ("", "hybrid_sigma_pressure"),
}
"""What ``vertical=`` may say the level coordinate is (standard name and units it stands for)."""


def _attr(var, key):
    return str(var.attrs.get(key, "")).strip()


def _formula_terms(var, path, field):
    text = _attr(var, "formula_terms")
    terms = dict(re.findall(r"(\w+):\s*(\w+)", text))
    if not terms:
        raise DataError(f"has standard_name {_attr(var, 'standard_name')} but no formula_terms", path=path, field=field)
    return terms


def _values(ds, name, path, field):
    if name not in ds.variables:
        raise DataError(f"formula term variable {name!r} is missing", path=path, field=field)
    a = np.asarray(ds[name].values, dtype=np.float64)
    if np.isnan(a).any():
        raise DataError(f"has NaN values in {name!r}", path=path, field=field)
    return a


def _parametric_coordinate(ds, zdim):
    """The level coordinate, or an auxiliary coordinate along ``zdim`` carrying the parametric formula."""
    zvar = ds[zdim]
    if _attr(zvar, "standard_name").lower() in _PARAMETRIC or _attr(zvar, "formula_terms"):
        return zvar
    for var in ds.variables.values():
        if var.dims == (zdim,) and _attr(var, "standard_name").lower() in _PARAMETRIC and _attr(var, "formula_terms"):
            return var
    return zvar


def _surface_only(ds, name, dims):
    """Whether ``name`` lies on the horizontal dimensions only (besides time)."""
    return set(dims[1:]) <= set(ds[name].dims) and dims[0] not in ds[name].dims


class VerticalCoordinates:
    """Reading a file's levels; the host class provides ``_ds``, ``_dims``, ``_time_dim``, ``_p0``,
    ``_vertical_kind``, ``_notes`` and ``_raw``."""

    def _vertical(self, ds, path, zdim, names, lat_index, lon_index, nj, ni):
        if zdim not in ds.variables:
            raise DataError("level dimension has no coordinate variable", path=path, field=zdim)
        zvar = _parametric_coordinate(ds, zdim)
        z = np.asarray(zvar.values, dtype=np.float64)
        if z.ndim != 1 or z.size < 2:
            raise DataError(f"needs at least 2 levels, got {z.size}", path=path, field=zdim)
        if not np.all(np.isfinite(z)):
            raise DataError("has NaN level coordinates", path=path, field=zdim)
        std = _attr(zvar, "standard_name").lower()
        units = _attr(zvar, "units").lower()
        if self._vertical_kind is not None:
            if self._vertical_kind not in VERTICAL_KINDS:
                raise DataError(f"vertical={self._vertical_kind!r} is not one of {', '.join(VERTICAL_KINDS)}",
                                path=path, field=zdim)
            std, units = VERTICAL_KINDS[self._vertical_kind]
        take = np.ix_(lat_index, lon_index)

        def surface(name, t):
            a = ds[name]
            if self._time_dim in a.dims:
                a = a.isel({self._time_dim: t})
            a = np.asarray(a.transpose(*self._dims[1:]).values, dtype=np.float64)
            return a[take]

        if not std and (units == "hybrid_sigma_pressure" or "A_var" in zvar.attrs):
            return self._ncar_hybrid(ds, zvar, path, zdim, surface)
        if std in ("atmosphere_hybrid_sigma_pressure_coordinate", "atmosphere_sigma_coordinate"):
            terms = _formula_terms(zvar, path, zdim)
            ps_name = terms.get("ps")
            if not ps_name or ps_name not in ds.variables:
                raise DataError(f"surface pressure {ps_name!r} from formula_terms is missing", path=path, field=zdim)
            ps_scale = pressure_scale(_attr(ds[ps_name], "units") or "Pa", path, ps_name)
            if std == "atmosphere_sigma_coordinate":
                sigma = _values(ds, terms.get("sigma", zdim), path, zdim)
                ptop = (float(_values(ds, terms["ptop"], path, zdim))
                        * pressure_scale(_attr(ds[terms["ptop"]], "units") or "Pa", path, terms["ptop"])
                        if "ptop" in terms
                        else 0.0)
                a_pa, b = ptop * (1.0 - sigma), sigma
            else:
                b = _values(ds, terms.get("b", ""), path, zdim)
                if "ap" in terms:
                    a_pa = _values(ds, terms["ap"], path,
                                   zdim) * pressure_scale(_attr(ds[terms["ap"]], "units") or "Pa", path, terms["ap"])
                elif "a" in terms:
                    p0 = self._reference_pressure(ds, terms.get("p0"), path, zdim)
                    a_pa = _values(ds, terms["a"], path, zdim) * p0
                else:
                    raise DataError(f"formula_terms {terms} need 'ap' or 'a' and 'p0'", path=path, field=zdim)
            return self._hybrid_pressure(a_pa, b, ps_name, ps_scale, surface, path, zdim)
        if std == "atmosphere_hybrid_height_coordinate":
            terms = _formula_terms(zvar, path, zdim)
            a = _values(ds, terms.get("a", zdim), path, zdim)
            b = _values(ds, terms.get("b", ""), path, zdim)
            orog_name = terms.get("orog")
            if not orog_name or orog_name not in ds.variables:
                raise DataError(f"orography {orog_name!r} from formula_terms is missing", path=path, field=zdim)
            level_index = self._level_order(a + b * 1000.0, path, zdim)
            heights = a[level_index, None, None] + b[level_index, None, None] * surface(orog_name, 0)[None]
            return heights, level_index, None, "hybrid height (terrain following)"
        is_pressure = std in ("air_pressure", "pressure") or units in ("pa", "hpa", "mb", "mbar", "millibar",
                                                                       "millibars", "hectopascal", "hectopascals")
        if is_pressure:
            p = z * pressure_scale(units, path, zdim)
            level_index = self._level_order(-p, path, zdim)
            p = p[level_index]
            heights = self._geopotential_heights(ds, path, names, level_index, take)
            if heights is None:
                heights = standard_height(p)
                source = "standard atmosphere"
            else:
                source = "mean geopotential height"
            p3 = np.broadcast_to(p[:, None, None], (p.size, nj, ni)).astype(np.float32)
            return (
                np.broadcast_to(heights[:, None, None], (p.size, nj, ni)),
                level_index,
                lambda t: p3,
                f"pressure levels, heights from the {source} (not terrain following)",
            )
        if std in ("height", "altitude",
                   "height_above_mean_sea_level") or units in ("m", "km", "meter", "meters", "metre", "metres"):
            scale = 1000.0 if units == "km" else 1.0
            if _attr(zvar, "positive").lower() == "down":
                raise DataError("heights with positive='down' (depth) are not supported", path=path, field=zdim)
            level_index = self._level_order(z * scale, path, zdim)
            heights = (z * scale)[level_index]
            return np.broadcast_to(heights[:, None, None],
                                   (heights.size, nj, ni)), level_index, None, "height levels (flat)"
        if std == "model_layers" or units in ("layer",
                                              "layers") or (units in ("level", "levels") and self._layer_fields(ds)):
            return self._model_layers(ds, path, zdim, take)
        raise DataError(
            f"cannot tell what the vertical coordinate is (standard_name {std or 'none'!r}, units "
            f"{units or 'none'!r}); expected pressure, hybrid sigma-pressure, hybrid height or height (say which with "
            "vertical=...)",
            path=path,
            field=zdim,
        )

    def _model_layers(self, ds, path, zdim, take):
        """Levels numbered 1..n (GEOS/MERRA-2 ``lev`` in units ``layer``, 1 at the top): heights from the mid-layer
        heights ``H``, else by the hypsometric equation from the layer thicknesses ``DELP`` (top at GEOS's 1 Pa),
        ``T`` (and ``QV``) up from the surface (``PHIS`` / g), else from the standard atmosphere of ``PL``;
        pressure ``PL``, else the middle of each ``DELP`` layer."""
        dims = self._dims

        def field(name, t):
            a = ds[name]
            if self._time_dim in a.dims:
                a = a.isel({self._time_dim: t})
            return np.asarray(a.transpose(*dims).values, dtype=np.float64)[(slice(None), *take)]

        have = self._layer_fields(ds, ("H", "PL", "DELP", "T", "QV"))
        if not have & {"H", "PL", "DELP"}:
            raise DataError(f"levels numbered 1..{ds.sizes[zdim]} (model layers) need mid-layer heights 'H', pressure "
                            "'PL' or thickness 'DELP' in the file (as MERRA-2/GEOS write them)", path=path, field=zdim)

        def half_levels(t):  # top (1 Pa, GEOS's model top) down to the surface
            delp = field("DELP", t)
            return np.concatenate([np.ones((1,) + delp.shape[1:]), 1.0 + np.cumsum(delp, axis=0)])

        if "PL" in have:
            def pressure_file(t):
                return field("PL", t)
        elif "DELP" in have:
            def pressure_file(t):
                half = half_levels(t)
                return 0.5 * (half[:-1] + half[1:])
        else:
            pressure_file = None
        if "H" in have:
            z, how = field("H", 0), "mid-layer heights 'H'"
        elif "DELP" in have and "T" in have:
            from .modellevels import hypsometric_heights

            phis = (field("PHIS", 0)[0] / G0
                    if "PHIS" in ds.variables and ds["PHIS"].ndim >= 2 and _surface_only(ds, "PHIS", dims)
                    else 0.0)
            z = hypsometric_heights(half_levels(0), field("T", 0), field("QV", 0) if "QV" in have else None, phis)
            how = "the hypsometric equation from DELP and T" + (" and QV" if "QV" in have else "")
        else:
            z, how = standard_height(pressure_file(0)), "the standard atmosphere of 'PL'"
        level_index = self._level_order(z.reshape(z.shape[0], -1).mean(axis=1), path, zdim)
        pressure = None if pressure_file is None else (lambda t: pressure_file(t)[level_index].astype(np.float32))
        return (z[level_index], level_index, pressure,
                f"model layers 1..{ds.sizes[zdim]} (terrain following), heights from {how}")

    def _layer_fields(self, ds, names=("H", "PL", "DELP")):
        """Those of ``names`` that are fields on the level dimension (GEOS's mid-layer heights, pressure, thickness)."""
        return {n for n in names if n in ds.variables
                and [d for d in ds[n].dims if d != self._time_dim] == list(self._dims)}

    def _reference_pressure(self, ds, name, path, field):
        """``P0`` in Pa: the ``p0=`` argument, the file's variable, else CAM's 100000 Pa with a note."""
        if self._p0 is not None:
            return float(self._p0)
        if name and name in ds.variables:
            return float(_values(ds, name, path, field)) * pressure_scale(_attr(ds[name], "units") or "Pa", path, name)
        self._notes.append(f"{field}: reference pressure {name or 'P0'!r} is not in the file; used CAM's P0 = "
                           f"{CAM_P0:g} Pa")
        return CAM_P0

    def _ncar_hybrid(self, ds, zvar, path, zdim, surface):
        """NCAR/CAM hybrid sigma-pressure levels named by ``A_var``/``B_var``/``P0_var``/``PS_var`` (or CAM's names)."""
        a_name = str(zvar.attrs.get("A_var", "hyam" if zdim != "ilev" else "hyai"))
        b_name = str(zvar.attrs.get("B_var", "hybm" if zdim != "ilev" else "hybi"))
        ps_name = str(zvar.attrs.get("PS_var", "PS"))
        if ps_name not in ds.variables:
            raise DataError(f"hybrid levels need surface pressure {ps_name!r}, which is not in the file", path=path,
                            field=zdim)
        p0 = self._reference_pressure(ds, str(zvar.attrs.get("P0_var", "P0")), path, zdim)
        a_pa = _values(ds, a_name, path, zdim) * p0
        b = _values(ds, b_name, path, zdim)
        ps_scale = pressure_scale(_attr(ds[ps_name], "units") or "Pa", path, ps_name)
        heights, level_index, pressure, _ = self._hybrid_pressure(a_pa, b, ps_name, ps_scale, surface, path, zdim)
        return heights, level_index, pressure, "hybrid sigma-pressure (terrain following, NCAR A_var/B_var)"

    def _hybrid_pressure(self, a_pa, b, ps_name, ps_scale, surface, path, zdim):
        ref = a_pa + b * 101325.0
        level_index = self._level_order(-ref, path, zdim)
        a_pa, b = a_pa[level_index, None, None], b[level_index, None, None]

        def pressure(t):
            return (a_pa + b * surface(ps_name, t) * ps_scale).astype(np.float32)

        return standard_height(pressure(0)), level_index, pressure, "hybrid sigma-pressure (terrain following)"

    @staticmethod
    def _level_order(upward, path, field):
        """Indices putting levels bottom→top given a quantity that grows upward; non-monotonic → DataError."""
        d = np.diff(upward)
        if np.all(d > 0):
            return np.arange(upward.size)
        if np.all(d < 0):
            return np.arange(upward.size)[::-1]
        raise DataError("levels are not monotonic (non-monotonic levels)", path=path, field=field)

    def _geopotential_heights(self, ds, path, names, level_index, take):
        for name in names:
            var = ds[name]
            std = _attr(var, "standard_name").lower()
            units = _attr(var, "units").lower().replace(" ", "")
            if std == "geopotential_height" or (name.lower() in _HEIGHT_NAMES
                                                and units in ("m", "gpm", "meters", "metres")):
                scale = 1.0
            elif std == "geopotential" or (name.lower() in _HEIGHT_NAMES
                                           and units in ("m2s-2", "m**2s**-2", "m^2/s^2", "m2/s2")):
                scale = 1.0 / G0
            else:
                continue
            a = self._raw(name, 0)[level_index][(slice(None),) + take] * scale
            with np.errstate(invalid="ignore"):
                mean = np.nanmean(a.reshape(a.shape[0], -1), axis=1)
            if np.all(np.isfinite(mean)) and np.all(np.diff(mean) > 0):
                return mean
        return None


__all__ = ["CAM_P0", "VERTICAL_KINDS", "VerticalCoordinates"]
