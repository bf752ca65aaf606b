"""Reader overrides as one checked set (shared by the CLI's options and the Blender panel) and
source names that carry them (``path?radius=...``), so any process reopens a file the same way."""

from pathlib import Path

import pytest

from nephele.core.climate.readers import check_overrides, open_dataset, override_source, parse_var_map, split_source
from nephele.core.errors import DataError

DATA = Path(__file__).resolve().parents[2] / "data"
NCL = DATA / "ncl_nc4uvt_T.nc"


def test_check_overrides_keeps_only_what_is_given():
    assert check_overrides("f.nc") == {}
    assert check_overrides("f.nc", vertical="", p0=None, time_units=" ", radius=None, variables="") == {}
    kw = check_overrides("f.nc", vertical="ncar_hybrid", p0=95000, time_units=" days since 1988-01-01 ",
                         radius=6371229, variables="temperature = T2,\nrh=RH")
    assert check_overrides("f.nc", time_units="months since 1850-01-01") == {"time_units": "months since 1850-01-01"}
    assert kw == {"vertical": "ncar_hybrid", "p0": 95000.0, "time_units": "days since 1988-01-01", "radius": 6371229.0,
                  "variables": {"temperature": "T2", "rh": "RH"}}


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"vertical": "sigma"}, ["field 'vertical coordinate'", "'sigma'", "ncar_hybrid"]),
        ({"p0": 0.0}, ["field 'P0'", "> 0"]),
        ({"p0": float("nan")}, ["field 'P0'"]),
        ({"time_units": "Month"}, ["field 'time units'", "since"]),
        ({"time_units": "days since yesterday"}, ["field 'time units'"]),
        ({"time_units": "months since the flood"}, ["field 'time units'"]),
        ({"radius": 6371.0}, ["field 'earth radius'", "metres"]),
        ({"radius": float("inf")}, ["field 'earth radius'"]),
        ({"variables": "temperature"}, ["field 'variable map'", "STD=NAME"]),
        ({"variables": "=T"}, ["field 'variable map'"]),
    ],
)
def test_bad_overrides_are_one_line_naming_file_and_field(kw, words):
    with pytest.raises(DataError) as info:
        check_overrides("model.nc", **kw)
    msg = str(info.value)
    assert msg.startswith("model.nc: ") and "\n" not in msg and all(w in msg for w in words), msg


def test_parse_var_map_empty_and_spaces():
    assert parse_var_map("") == {} and parse_var_map(None) == {}
    assert parse_var_map(" cloud=CLDFRA , ,u=U10 ") == {"cloud": "CLDFRA", "u": "U10"}


def test_source_name_round_trip_and_the_cli_form():
    kw = check_overrides(str(NCL), time_units="days since 2000-01-01 00:00:00", radius=6371220,
                         variables="temperature=T")
    name = override_source(NCL, **kw)
    # The CLI's form: urlencode of the sorted overrides, variables as STD:NAME pairs, then &file=ID.
    assert name == f"{NCL}?radius=6371220.0&time_units=days+since+2000-01-01+00%3A00%3A00&variables=temperature%3AT"
    assert split_source(name + "&file=0123456789ab") == (str(NCL), kw)
    assert split_source(str(NCL)) == (str(NCL), {})
    assert override_source("x.nc") == "x.nc"


def test_open_dataset_reads_a_source_name_with_its_overrides():
    plain = open_dataset(NCL)
    ds = open_dataset(override_source(NCL, radius=6371220.0, time_units="days since 2000-01-01") + "&file=abc")
    assert plain.earth_radius == 6371000.0 and ds.earth_radius == 6371220.0
    assert str(ds.times[0]) == "2000-01-01T00:00:00" and str(plain.times[0]) != str(ds.times[0])


@pytest.mark.parametrize(
    "source, kw, words",
    [
        (f"{NCL}?radius=6371220.0", {"radius": 6371229.0}, ["ncl_nc4uvt_T.nc", "radius", "twice"]),
        (f"{NCL}?colour=red", {}, ["ncl_nc4uvt_T.nc", "unknown override 'colour'"]),
        (f"{NCL}?radius=big", {}, ["field 'earth radius'", "not a number"]),
        (f"{NCL}?radius=6371", {}, ["field 'earth radius'", "metres"]),
        ("demo:small", {"radius": 6371220.0}, ["demo:small", "no file overrides"]),
        ("{tmp}/model.ctl", {"p0": 1e5}, ["model.ctl", "GrADS", "p0"]),
    ],
)
def test_overrides_where_they_cannot_apply_are_one_line(source, kw, words, tmp_path):
    (tmp_path / "model.ctl").write_text("dset ^model.dat\n")  # refused before it is read
    with pytest.raises(DataError) as info:
        open_dataset(source.format(tmp=tmp_path), **kw)
    msg = str(info.value)
    assert "\n" not in msg and all(w in msg for w in words), msg
