"""Real operational GRIB products (tests/data/fetch_grib_samples.py): NCEP GFS in GRIB2 and GRIB1,
the ERA5 ensemble; every value compared with what ecCodes decodes from the same message."""

import numpy as np
import pytest

from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError

eccodes = pytest.importorskip("eccodes")


def decoded(path, short, level, number=None, valid=None):
    """ecCodes' own values of one message, as a (lat, lon) array with rows south to north."""
    eccodes.codes_grib_multi_support_on()
    try:
        with open(path, "rb") as f:
            while (h := eccodes.codes_grib_new_from_file(f)) is not None:
                try:
                    ok = (eccodes.codes_get(h, "typeOfLevel") == "isobaricInhPa"
                          and eccodes.codes_get(h, "level") == level
                          and eccodes.codes_get(h, "shortName") == short)
                    if ok and number is not None:
                        ok = eccodes.codes_get(h, "number") == number
                    if ok and valid is not None:
                        ok = (eccodes.codes_get(h, "validityDate"), eccodes.codes_get(h, "validityTime")) == valid
                    if ok:
                        nj, ni = eccodes.codes_get(h, "Nj"), eccodes.codes_get(h, "Ni")
                        v = eccodes.codes_get_values(h).reshape(nj, ni)
                        return v if eccodes.codes_get(h, "jScansPositively") else v[::-1]
                finally:
                    eccodes.codes_release(h)
    finally:
        eccodes.codes_grib_multi_support_off()
    raise AssertionError(f"no {short} at {level} hPa")


@pytest.mark.parametrize("name", ["gfs.t12z.pgrbf120.2p5deg.grib2", "gfs.t12z.pgrbf120.2p5deg.grib1"])
def test_gfs_forecast_with_mixed_level_types_opens_on_its_isobaric_levels(grib_samples, name):
    path = grib_samples / name
    ds = open_dataset(path)
    assert ds.level_type == "isobaricInhPa" and ds.grid.shape == (26, 73, 144)
    assert {"temperature", "u", "v", "rh", "cloud_water", "omega", "gh"} <= set(ds.variables)
    assert ds.level_types["isobaricInhPa"]["3d"] == 10
    assert {"surface", "tropopause", "maxWind", "heightAboveGround"} <= set(ds.level_types)
    if name.endswith("grib2"):
        assert {"potentialVorticity", "sigma", "lowCloudLayer"} <= set(ds.level_types)
    assert ds.times[0] == np.datetime64("2011-01-15T12:00", "s")  # 2011-01-10 12 UTC + 120 h
    levels = ds.read("pressure", 0)[:, 0, 0] / 100.0
    assert levels[0] == 1000 and levels[-1] == 10
    # cloud water (NCEP GRIB1 table 2 number 153 in the GRIB1 file) on 21 of 26 levels, NaN above 100 hPa
    c = ds.read("clwmr", 0)
    np.testing.assert_array_equal(np.isnan(c).all(axis=(1, 2)), levels < 100)
    k = int(np.flatnonzero(levels == 700)[0])
    np.testing.assert_allclose(c[k], decoded(path, "clwmr" if name.endswith("2") else "unknown", 700), rtol=1e-6,
                               atol=1e-12)
    np.testing.assert_allclose(ds.read("u", 0)[k], decoded(path, "u", 700), rtol=1e-6)
    # the second field of multi-field messages
    np.testing.assert_allclose(ds.read("v", 0)[k], decoded(path, "v", 700), rtol=1e-6)
    rh = decoded(path, "r", 700) / 100.0
    np.testing.assert_allclose(ds.read("rh", 0)[k], np.clip(rh, 0, 1), rtol=1e-6, atol=1e-7)
    # every other level type stays out of the way; choosing one that cannot be placed says so in one line
    why = ("cannot place potentialVorticity levels: 'gh' is missing in" if name.endswith("2")
           else "has no field on two or more")
    with pytest.raises(DataError, match=r"field 'level_type': .*" + why) as err:  # (GRIB1 could keep only +2 PVU)
        open_dataset(path, level_type="potentialVorticity")
    assert "\n" not in str(err.value)


def test_era5_ensemble_members_and_times(grib_samples):
    path = grib_samples / "era5-levels-members.grib"
    ds = open_dataset(path)
    assert ds.members == list(range(10)) and ds.member == 0
    assert ds.times.size == 4 and ds.times[-1] == np.datetime64("2017-01-02T12:00", "s")
    assert ds.grid.shape == (2, 61, 120)
    np.testing.assert_allclose(ds.read("t", 3)[1], decoded(path, "t", 500, number=0, valid=(20170102, 1200)), rtol=1e-6)
    five = open_dataset(path, member=5)
    np.testing.assert_allclose(five.read("t", 2)[0], decoded(path, "t", 850, number=5, valid=(20170102, 0)), rtol=1e-6)
    assert not np.array_equal(five.read("t", 2), ds.read("t", 2))
