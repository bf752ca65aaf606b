import numpy as np
import pytest

from nephele.core.climate.humidity import (
    EPSILON,
    mixing_ratio,
    relative_humidity,
    saturation_vapour_pressure,
    standard_height,
    standard_pressure,
    sundqvist_cloud,
    vapour_pressure,
)


def test_bolton_against_wmo_saturation_table():
    # WMO (Goff-Gratch over water) values in Pa.
    table = {-20.0: 125.63, 0.0: 611.21, 10.0: 1228.1, 20.0: 2339.3, 30.0: 4246.0}
    tc = np.array(list(table))
    np.testing.assert_allclose(saturation_vapour_pressure(tc + 273.15), list(table.values()), rtol=3e-3)


def test_relative_humidity_inverts_the_moisture_relations():
    t = np.array([300.0, 280.0, 250.0, 230.0])
    p = np.array([100000.0, 85000.0, 50000.0, 30000.0])
    rh = np.array([0.3, 0.75, 1.0, 0.5])
    e = rh * saturation_vapour_pressure(t)
    r = EPSILON * e / (p - e)  # mixing ratio from vapour pressure
    q = r / (1.0 + r)
    np.testing.assert_allclose(mixing_ratio(q), r, rtol=1e-12)
    np.testing.assert_allclose(vapour_pressure(q, p), e, rtol=1e-12)
    np.testing.assert_allclose(relative_humidity(t, q, p), rh, rtol=1e-12)
    assert np.isnan(relative_humidity(np.nan, 0.01, 1e5))


def test_sundqvist_scheme():
    rh = np.array([0.0, 0.5, 0.8, 0.95, 1.0, 1.26, -0.14, np.nan])
    c = sundqvist_cloud(rh, 0.8)
    np.testing.assert_allclose(c[:7], [0, 0, 0, 0.5, 1, 1, 0])  # 1 - sqrt(0.05/0.2) = 0.5
    assert np.isnan(c[7])
    fine = np.linspace(0, 1.2, 1001)
    cf = sundqvist_cloud(fine)
    assert np.all(np.diff(cf) >= 0) and cf.min() == 0 and cf.max() == 1
    # Per-level critical humidity broadcasts.
    crit = np.array([0.9, 0.7]).reshape(2, 1, 1)
    out = sundqvist_cloud(np.full((2, 1, 1), 0.8), crit)
    assert out[0, 0, 0] == 0 and out[1, 0, 0] == pytest.approx(1 - np.sqrt(0.2 / 0.3))
    with pytest.raises(ValueError):
        sundqvist_cloud(0.5, 1.0)


def test_standard_atmosphere_table_and_roundtrip():
    # ICAO standard atmosphere: pressure (hPa) -> geopotential height (m).
    table = {1013.25: 0.0, 850.0: 1457.3, 500.0: 5574.4, 250.0: 10363.0, 100.0: 16180.0, 10.0: 31055.0}
    np.testing.assert_allclose(standard_height(np.array(list(table)) * 100.0), list(table.values()), atol=1.0)
    h = np.linspace(-300.0, 47_000.0, 200)
    np.testing.assert_allclose(standard_height(standard_pressure(h)), h, atol=1e-6)
    assert np.all(np.diff(standard_height(np.linspace(105000.0, 200.0, 300))) > 0)
