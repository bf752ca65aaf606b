"""``months since`` / ``years since`` time units through cftime's calendars (360_day, noleap, standard)."""

import numpy as np
import pytest

xr = pytest.importorskip("xarray")
cftime = pytest.importorskip("cftime")

from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402


def _file(path, time, units, calendar):
    nt = len(time)
    values = np.broadcast_to(np.linspace(250, 300, 3)[None, :, None, None], (nt, 3, 4, 8)).astype(np.float32)
    coords = {
        "time": ("time", np.asarray(time, dtype=np.float64), {"units": units, "calendar": calendar}),
        "lev": ("lev", [1000.0, 850.0, 500.0], {"units": "hPa"}),
        "lat": ("lat", [-60.0, -20.0, 20.0, 60.0], {"units": "degrees_north"}),
        "lon": ("lon", np.arange(8) * 45.0, {"units": "degrees_east"}),
    }
    xr.Dataset({"T": (("time", "lev", "lat", "lon"), values, {"units": "K"})}, coords=coords).to_netcdf(path)
    return open_dataset(path)


def _elapsed_hours(dates):
    return np.array([(d - dates[0]).total_seconds() / 3600.0 for d in dates])


def test_360_day_months_match_cftime(tmp_path):
    t = [0.0, 1.0, 2.0, 12.0, 13.5]
    ds = _file(tmp_path / "m360.nc", t, "months since 2000-01-01", "360_day")
    truth = cftime.num2date(t, "months since 2000-01-01", "360_day")  # cftime's own 30-day months
    np.testing.assert_allclose(ds.hours, _elapsed_hours(truth))
    np.testing.assert_allclose(ds.hours, [0, 720, 1440, 8640, 9720])
    assert not any(n.startswith("time") for n in ds.notes)
    years = _file(tmp_path / "y360.nc", [0.0, 1.0, 2.5], "years since 1850-01-01", "360_day")
    np.testing.assert_allclose(years.hours, np.array([0.0, 360.0, 900.0]) * 24)


@pytest.mark.parametrize("calendar, lengths", [("noleap", [31, 28, 31, 30]), ("standard", [31, 29, 31, 30])])
def test_calendar_months_of_other_calendars(tmp_path, calendar, lengths):
    ds = _file(tmp_path / f"m_{calendar}.nc", [0.0, 1.0, 2.0, 3.0, 3.5], "months since 2000-01-01", calendar)
    # The first of each month, as cftime dates of that calendar (2000 is a leap year in 'standard' only).
    firsts = [cftime.datetime(2000, m, 1, calendar=calendar) for m in (1, 2, 3, 4)]
    expected = _elapsed_hours(firsts).tolist() + [_elapsed_hours(firsts)[-1] + 15 * 24]  # half of April (30 days)
    np.testing.assert_allclose(ds.hours, expected)
    np.testing.assert_allclose(np.diff(ds.hours)[:3] / 24, lengths[:3])
    assert any("calendar months" in n for n in ds.notes)


def test_month_units_errors(tmp_path):
    with pytest.raises(DataError, match="field 'time'.*calendar 'none' have no months"):
        _file(tmp_path / "none.nc", [0.0, 1.0], "months since 2000-01-01", "none")
