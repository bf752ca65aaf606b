"""The model date and time a frame shows, in the dataset's own calendar.

A :class:`~nephele.core.climate.dataset.Dataset` keeps its times as
``datetime64`` counted from the file's reference date.  In the standard
calendar those are the dates themselves.  In a model calendar (``360_day``,
``noleap``, ``all_leap``, ``julian``) only the elapsed time from the
reference date (``ds.time_origin``) is right: the labels come from adding
that elapsed time to the reference date in the file's calendar
(``ds.calendar``), which :mod:`cftime` does.  A dataset without those
attributes (the synthetic demo, GRIB, GrADS) is in the standard calendar.

References
----------
.. [1] CF Conventions 1.11, section 4.4.1 "Calendar".
"""

import datetime

import numpy as np

from ..errors import DataError

STANDARD = ("standard", "gregorian", "proleptic_gregorian")
"""Calendars whose labels are numpy's (proleptic Gregorian) after 1582-10-15."""

CALENDARS = STANDARD + ("noleap", "365_day", "all_leap", "366_day", "360_day", "julian", "none")

_GREGORIAN_START = np.datetime64("1582-10-15T00:00:00", "s")


def dataset_calendar(ds):
    """``(calendar, origin)`` of a dataset: CF calendar name and the reference date (``datetime64[s]`` or None)."""
    cal = str(getattr(ds, "calendar", None) or "standard").strip().lower()
    if cal not in CALENDARS:
        raise DataError(f"calendar {cal!r} is not a CF calendar ({', '.join(CALENDARS)})",
                        path=getattr(ds, "source", None), field="time")
    origin = getattr(ds, "time_origin", None)
    return cal, (None if origin is None else np.datetime64(origin, "s"))


def _fields(t):
    """``(year, month, day, hour, minute, second)`` of a ``datetime64[s]`` read as a proleptic Gregorian date."""
    text = str(np.datetime64(t, "s"))
    date, _, clock = text.rpartition("T")
    sign = -1 if date.startswith("-") else 1
    y, mo, d = date.lstrip("-").split("-")
    hh, mi, ss = clock.split(":")
    return sign * int(y), int(mo), int(d), int(hh), int(mi), int(ss)


def model_datetime(ds, hours):
    """The date shown ``hours`` after the dataset's first step.

    Returns
    -------
    numpy.datetime64 or cftime.datetime
        ``datetime64[s]`` in the standard calendar (after 1582-10-15), else a
        :class:`cftime.datetime` in the dataset's calendar.  ``None`` for the
        calendar ``none`` (no dates, only elapsed time).
    """
    hours = float(hours)
    if not np.isfinite(hours):
        raise DataError(f"model time must be finite, got {hours}", path=getattr(ds, "source", None), field="time")
    cal, origin = dataset_calendar(ds)
    t = np.datetime64(ds.times[0], "s") + np.timedelta64(int(round(hours * 3600.0)), "s")
    if cal == "none":
        return None
    if cal == "proleptic_gregorian" or (cal in STANDARD and t >= _GREGORIAN_START):
        return t
    try:
        import cftime
    except ImportError:
        raise DataError(f"dates in the {cal!r} calendar need the cftime package ('pip install cftime')",
                        path=getattr(ds, "source", None), field="time") from None
    origin = np.datetime64(ds.times[0], "s") if origin is None else origin
    start = cftime.datetime(*_fields(origin), calendar=cal)
    return start + datetime.timedelta(seconds=int((t - origin) / np.timedelta64(1, "s")))


def time_label(ds, hours, seconds=False):
    """``"1987-01-02 06:00"``: the model date and time ``hours`` after the first step, in the dataset's calendar.

    The calendar ``none`` gives the elapsed time, ``"+30 h"``.  ``seconds``
    adds ``:SS``.
    """
    when = model_datetime(ds, hours)
    if when is None:
        return f"+{float(hours):g} h"
    if isinstance(when, np.datetime64):
        y, mo, d, hh, mi, ss = _fields(when)
    else:
        y, mo, d, hh, mi, ss = when.year, when.month, when.day, when.hour, when.minute, when.second
    text = f"{y:04d}-{mo:02d}-{d:02d} {hh:02d}:{mi:02d}"
    return text + (f":{ss:02d}" if seconds else "")


def calendar_note(ds):
    """A short note for a non-standard calendar (``"360-day calendar"``), ``""`` for the standard one."""
    cal, _ = dataset_calendar(ds)
    if cal in STANDARD:
        return ""
    names = {"noleap": "365-day", "365_day": "365-day", "all_leap": "366-day", "366_day": "366-day",
             "360_day": "360-day", "julian": "Julian", "none": "no"}
    return f"{names[cal]} calendar"


__all__ = ["CALENDARS", "STANDARD", "calendar_note", "dataset_calendar", "model_datetime", "time_label"]
