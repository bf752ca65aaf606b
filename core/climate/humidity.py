"""Moist thermodynamics for readers: relative humidity, diagnostic cloud fraction, standard atmosphere.

* Saturation vapour pressure over liquid water: Bolton (1980),
  ``e_s(T) = 611.2 Pa · exp(17.67 (T − 273.15) / (T − 29.65))``, within 0.3 %
  of the Wexler/Goff–Gratch values for −35…35 °C.
* Relative humidity ``RH = e / e_s(T)`` with the vapour pressure from specific
  humidity ``q`` and pressure ``p``: ``e = p q / (ε + (1 − ε) q)``,
  ``ε = R_d / R_v = 0.622``.  (Over ice, below −20 °C, this is the usual
  liquid-water convention of models, as in ERA and ECHAM output.)
* Cloud fraction from relative humidity, Sundqvist et al. (1989):
  ``C = 1 − sqrt((1 − RH) / (1 − RH_c))`` for ``RH > RH_c``, else 0, with RH
  clipped to at most 1 (so ``C`` ∈ [0, 1]).  The critical humidity defaults to
  ``RH_c = 0.8`` at every height (the value the scheme was presented with;
  ECHAM lowers it with height from ~0.9 to ~0.7, pass an array per level for
  that).
* Heights of pressure levels: the ICAO/ISO 2533 standard atmosphere
  (hypsometric equation layer by layer, 288.15 K and 1013.25 hPa at sea level,
  lapse rates −6.5, 0, +1, +2.8 K/km up to 47 km).

References
----------
.. [1] D. Bolton, "The computation of equivalent potential temperature",
   Mon. Wea. Rev. 108 (1980) 1046–1053, eq. (10).
.. [2] H. Sundqvist, E. Berge and J. E. Kristjánsson, "Condensation and cloud
   parameterization studies with a mesoscale numerical weather prediction
   model", Mon. Wea. Rev. 117 (1989) 1641–1657.
.. [3] ISO 2533:1975, Standard Atmosphere.
.. [4] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (cloudiness as the fraction of sky covered, the field of Fig. 1).
"""

import numpy as np

EPSILON = 0.622
"""Ratio of the gas constants of dry air and water vapour."""

RH_CRIT = 0.8
"""Default critical relative humidity of the Sundqvist scheme."""

G0 = 9.80665
R_DRY = 287.05287
# Standard atmosphere layers: base height (m), base temperature (K), lapse rate (K/m), base pressure (Pa).
_ISA = []
_h, _t, _p = 0.0, 288.15, 101325.0
for _top, _lapse in ((11_000.0, -0.0065), (20_000.0, 0.0), (32_000.0, 0.001), (47_000.0, 0.0028), (51_000.0, 0.0)):
    _ISA.append((_h, _t, _lapse, _p))
    _dt = _lapse * (_top - _h)
    if _lapse == 0.0:
        _p = _p * np.exp(-G0 * (_top - _h) / (R_DRY * _t))
    else:
        _p = _p * ((_t + _dt) / _t) ** (-G0 / (R_DRY * _lapse))
    _h, _t = _top, _t + _dt


def saturation_vapour_pressure(temperature):
    """Bolton's (1980) saturation vapour pressure over water (Pa) at ``temperature`` (K)."""
    tc = np.asarray(temperature, dtype=np.float64) - 273.15
    return 611.2 * np.exp(17.67 * tc / (tc + 243.5))


def vapour_pressure(q, pressure):
    """Water vapour partial pressure (Pa) from specific humidity ``q`` (kg/kg) and pressure (Pa)."""
    q = np.asarray(q, dtype=np.float64)
    return np.asarray(pressure, dtype=np.float64) * q / (EPSILON + (1.0 - EPSILON) * q)


def mixing_ratio(q):
    """Water vapour mixing ratio (kg/kg of dry air) from specific humidity."""
    q = np.asarray(q, dtype=np.float64)
    return q / (1.0 - q)


def relative_humidity(temperature, q, pressure):
    """Relative humidity (fraction, not clipped) from T (K), q (kg/kg) and p (Pa); NaN stays NaN."""
    return vapour_pressure(q, pressure) / saturation_vapour_pressure(temperature)


def sundqvist_cloud(rh, rh_crit=RH_CRIT):
    """Sundqvist et al. (1989) cloud fraction from relative humidity (fraction).

    ``C = 1 − sqrt((1 − RH) / (1 − RH_c))`` where ``RH > RH_c``, else 0; RH
    above 1 counts as 1.  ``rh_crit`` may be an array broadcasting with
    ``rh`` (e.g. one value per level, shape ``(nk, 1, 1)``).  NaN stays NaN.
    """
    rh = np.asarray(rh, dtype=np.float64)
    rh_crit = np.asarray(rh_crit, dtype=np.float64)
    if np.any((rh_crit < 0.0) | (rh_crit >= 1.0)):
        raise ValueError(f"rh_crit must lie in [0, 1), got {rh_crit}")
    excess = np.clip((1.0 - np.minimum(rh, 1.0)) / (1.0 - rh_crit), 0.0, None)
    with np.errstate(invalid="ignore"):
        return np.where(rh > rh_crit, 1.0 - np.sqrt(np.minimum(excess, 1.0)), np.where(np.isnan(rh), np.nan, 0.0))


def standard_height(pressure):
    """Height (m) of a pressure (Pa) in the ISO standard atmosphere (up to ~51 km)."""
    p = np.asarray(pressure, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    for i, (h0, t0, lapse, p0) in enumerate(_ISA):
        upper = _ISA[i + 1][3] if i + 1 < len(_ISA) else 0.0
        sel = (p <= p0) & (p > upper) if i else (p > upper)
        if lapse == 0.0:
            out[sel] = h0 + R_DRY * t0 / G0 * np.log(p0 / p[sel])
        else:
            out[sel] = h0 + t0 / lapse * ((p[sel] / p0) ** (-R_DRY * lapse / G0) - 1.0)
    return out


def standard_pressure(height):
    """Inverse of :func:`standard_height`: pressure (Pa) at a height (m)."""
    h = np.asarray(height, dtype=np.float64)
    out = np.empty(h.shape)
    for i, (h0, t0, lapse, p0) in enumerate(_ISA):
        top = _ISA[i + 1][0] if i + 1 < len(_ISA) else np.inf
        sel = (h < top) & (h >= h0) if i else (h < top)
        if lapse == 0.0:
            out[sel] = p0 * np.exp(-G0 * (h[sel] - h0) / (R_DRY * t0))
        else:
            out[sel] = p0 * (1.0 + lapse * (h[sel] - h0) / t0) ** (-G0 / (R_DRY * lapse))
    return out


__all__ = [
    "EPSILON",
    "RH_CRIT",
    "mixing_ratio",
    "relative_humidity",
    "saturation_vapour_pressure",
    "standard_height",
    "standard_pressure",
    "sundqvist_cloud",
    "vapour_pressure",
]
