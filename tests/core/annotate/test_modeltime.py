"""The model date and time a frame shows, against the dataset's own time axis and cftime's calendars."""

import numpy as np
import pytest

from nephele.core.annotate import calendar_note, dataset_calendar, model_datetime, time_label
from nephele.core.climate.synthetic import demo_dataset
from nephele.core.errors import DataError
from nephele.core.pipeline.sources import frame_hours


def _iso(t):
    return str(np.datetime64(t, "m")).replace("T", " ")


def test_demo_labels_are_its_own_times():
    ds = demo_dataset("small")
    assert dataset_calendar(ds) == ("standard", None)
    for step in (0, 1, 13, 24, 47):
        assert time_label(ds, ds.hours[step]) == _iso(ds.times[step])
    # frame 9 at 3 h a frame from frame 1 shows hour 24: the second day at midnight
    assert time_label(ds, frame_hours(9, 1, 3.0)) == "1987-01-02 00:00"
    assert time_label(ds, 1.5, seconds=True) == "1987-01-01 01:30:00"
    assert calendar_note(ds) == ""


class _Axis:
    """A time axis as readers leave it: datetime64 elapsed from ``time_origin``, and a calendar name."""

    def __init__(self, times, calendar, origin):
        self.times = np.asarray(times, "datetime64[s]")
        self.calendar, self.time_origin, self.source = calendar, origin, "axis"


def test_calendar_none_and_bad_calendar():
    ax = _Axis(["2000-01-01T00"], "none", None)
    assert time_label(ax, 30) == "+30 h"
    assert calendar_note(ax) == "no calendar"
    with pytest.raises(DataError, match="not a CF calendar"):
        time_label(_Axis(["2000-01-01T00"], "lunar", None), 0)
    with pytest.raises(DataError, match="finite"):
        time_label(demo_dataset("small"), float("nan"))


xr = pytest.importorskip("xarray")
cftime = pytest.importorskip("cftime")


def _nc(path, values, units, calendar):
    """A CF file with a temperature field on a tiny grid and the given time axis."""
    from nephele.core.climate.readers import open_dataset

    nt = len(values)
    t = np.broadcast_to(np.linspace(250, 300, 3)[None, :, None, None], (nt, 3, 4, 8)).astype(np.float32)
    coords = {
        "time": ("time", np.asarray(values, np.float64), {"units": units, "calendar": calendar}),
        "lev": ("lev", [1000.0, 850.0, 500.0], {"units": "hPa"}),
        "lat": ("lat", [-60.0, -20.0, 20.0, 60.0], {"units": "degrees_north"}),
        "lon": ("lon", np.arange(8) * 45.0, {"units": "degrees_east"}),
    }
    xr.Dataset({"T": (("time", "lev", "lat", "lon"), t, {"units": "K"})}, coords=coords).to_netcdf(path)
    return open_dataset(path)


def _truth(values, units, calendar):
    return [d.strftime("%Y-%m-%d %H:%M") for d in cftime.num2date(values, units, calendar)]


@pytest.mark.parametrize("calendar", ["360_day", "noleap", "all_leap", "julian", "standard"])
def test_file_steps_match_cftime(tmp_path, calendar):
    """Every step of a 6-hourly file from 2000-02-25 (past 29, 30 February) reads as cftime dates it."""
    units = "hours since 2000-02-25 00:00:00"
    values = np.arange(0, 8 * 24, 6.0)
    ds = _nc(tmp_path / f"{calendar}.nc", values, units, calendar)
    assert dataset_calendar(ds)[0] == calendar
    labels = [time_label(ds, h) for h in ds.hours]
    assert labels == _truth(values, units, calendar)
    if calendar == "360_day":
        assert "2000-02-30 18:00" in labels and calendar_note(ds) == "360-day calendar"
    if calendar == "noleap":
        assert "2000-03-01 00:00" == labels[16] and calendar_note(ds) == "365-day calendar"


def test_frames_between_steps_in_360_day(tmp_path):
    """A frame's hours between the file's steps (0.5 h a frame, daily data) still land on cftime's date."""
    units = "days since 1850-01-01"
    values = np.arange(0.0, 70.0)  # past the 30th of February of 1850
    ds = _nc(tmp_path / "daily360.nc", values, units, "360_day")
    for frame in (1, 2, 37, 121, 1500, 1681):
        hours = frame_hours(frame, 1, 0.5, last_hour=float(ds.hours[-1]))
        truth = cftime.num2date(hours / 24.0, units, "360_day").strftime("%Y-%m-%d %H:%M")
        assert time_label(ds, hours) == truth
    assert time_label(ds, 59 * 24 + 12) == "1850-02-30 12:00"
    assert isinstance(model_datetime(ds, 0), cftime.datetime)


def test_month_units_keep_the_calendar(tmp_path):
    ds = _nc(tmp_path / "m360.nc", [0.0, 1.0, 2.0], "months since 2000-01-01", "360_day")
    assert [time_label(ds, h) for h in ds.hours] == ["2000-01-01 00:00", "2000-02-01 00:00", "2000-03-01 00:00"]
