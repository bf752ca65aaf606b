"""Small GRIB files written by ecCodes from its own samples, for the reader tests.

Each message is a sample (``codes_grib_new_from_samples``) with keys set and values written
(IEEE packing where the tests compare values exactly), so the tests know every value and
position independently of the reader.
"""

import numpy as np
import pytest

REAL = {"reduced_gg": "reduced_gg.grib", "ngm": "ngm.grb", "lambert": "lambert_grid.grib",
        "ml": "regular_gg_ml.grib", "level_types": "t_on_different_level_types.grib"}
"""Small real files committed under tests/data/grib (see tests/data/README.md)."""


def message(sample, keys=(), values=None, ieee=True):
    """A new ecCodes handle from ``sample`` with ``keys`` (pairs, set in order) and ``values``."""
    eccodes = pytest.importorskip("eccodes")
    h = eccodes.codes_grib_new_from_samples(sample)
    for key, value in keys:
        if isinstance(value, (list, tuple, np.ndarray)):
            eccodes.codes_set_array(h, key, np.asarray(value, dtype=np.float64))
        else:
            eccodes.codes_set(h, key, value)
    if ieee and eccodes.codes_get(h, "edition") == 2:
        eccodes.codes_set(h, "packingType", "grid_ieee")
        eccodes.codes_set(h, "precision", 2)  # 64-bit: values come back exactly
    if values is not None:
        eccodes.codes_set_values(h, np.asarray(values, dtype=np.float64).ravel())
    return h


def write(path, handles, mode="wb"):
    """Write ``handles`` to ``path`` (and release them)."""
    eccodes = pytest.importorskip("eccodes")
    with open(path, mode) as f:
        for h in handles:
            eccodes.codes_write(h, f)
            eccodes.codes_release(h)
    return path


def regular_ll(ni=8, nj=5, lon0=0.0, dlon=45.0, lat0=60.0, dlat=-30.0):
    """Grid keys of a regular latitude/longitude grid (first row north) and its axes."""
    lon = lon0 + dlon * np.arange(ni)
    lat = lat0 + dlat * np.arange(nj)
    keys = (("Ni", ni), ("Nj", nj), ("latitudeOfFirstGridPointInDegrees", float(lat[0])),
            ("longitudeOfFirstGridPointInDegrees", float(lon[0])), ("latitudeOfLastGridPointInDegrees", float(lat[-1])),
            ("longitudeOfLastGridPointInDegrees", float(lon[-1])), ("iDirectionIncrementInDegrees", abs(dlon)),
            ("jDirectionIncrementInDegrees", abs(dlat)), ("jScansPositively", int(dlat > 0)))
    return keys, lon, lat


def when(date=20240101, time=0, step=0):
    return (("dataDate", date), ("dataTime", time), ("stepUnits", 1), ("step", step))


def isobaric(short, level, grid, values, *, date=20240101, time=0, step=0, number=None, centre="ecmf",
             sample="regular_ll_pl_grib2"):
    """A message of ``short`` on ``level`` hPa (ECMWF or NCEP ``centre``), with an ensemble ``number`` if given."""
    keys = [("centre", centre), *when(date, time, step), *grid]
    if number is not None:  # PDT 1: individual ensemble forecast
        keys += [("productDefinitionTemplateNumber", 1), ("typeOfEnsembleForecast", 3 if number else 1),
                 ("perturbationNumber", number), ("numberOfForecastsInEnsemble", 10)]
    keys += [("shortName", short), ("typeOfFirstFixedSurface", 100), ("level", int(level))]
    return message(sample, keys, values)


def other_level(short, type_of_level, level, grid, values, **kw):
    """A message on another kind of level (``surface``, ``tropopause``, ``potentialVorticity``...)."""
    keys = [*when(**kw), *grid, ("typeOfLevel", type_of_level), ("level", level), ("shortName", short)]
    return message("regular_ll_sfc_grib2", keys, values)


def field(lon, lat, level, k=1.0):
    """A smooth test field of longitude, latitude and level (row = lat, column = lon)."""
    lo, la = np.meshgrid(np.deg2rad(lon), np.deg2rad(lat))
    return k * (np.cos(lo) * np.cos(la) + 0.01 * level + 0.1 * np.sin(2 * la))
