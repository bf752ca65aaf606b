"""GRIB files laid out as NCEP and ECMWF products are: many kinds of level, members, steps, reference times.

Every file is written here by ecCodes from its own samples (:mod:`gribfiles`), with values the
tests know; the reader must give those values back at the right level, time and member.
"""

import numpy as np
import pytest
from gribfiles import field, isobaric, other_level, regular_ll, write

from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError

pytest.importorskip("eccodes")

LEVELS = (1000, 850, 700, 500, 300)


def _product(path, *, centre="kwbc", clwmr_levels=(1000, 850, 700)):
    """An NCEP-like file: t, u, v, gh on five isobaric levels, clwmr on some, plus surface, tropopause,
    2 m and PV-level fields and a single-level field on an isobaric level."""
    grid, lon, lat = regular_ll()
    msgs = []
    for p in LEVELS:
        for short, k in (("t", 1.0), ("u", 2.0), ("v", 3.0)):
            msgs.append(isobaric(short, p, grid, 250 + 10 * field(lon, lat, p, k), centre=centre))
        msgs.append(isobaric("gh", p, grid, 44330.8 * (1 - (p / 1013.25) ** 0.1903) + field(lon, lat, p),
                             centre=centre))
        if p in clwmr_levels:
            msgs.append(isobaric("clwmr", p, grid, 1e-4 * (1 + field(lon, lat, p)), centre=centre))
    msgs.append(isobaric("r", 500, grid, 50 + field(lon, lat, 500), centre=centre))  # one level only: a 2-D field
    msgs.append(other_level("sp", "surface", 0, grid, 1e5 + field(lon, lat, 0)))
    msgs.append(other_level("t", "tropopause", 0, grid, 210 + field(lon, lat, 0)))
    for pv in (2, 3):  # two PV levels: a 3-D variable of another kind
        msgs.append(other_level("t", "potentialVorticity", pv, grid, 220 + field(lon, lat, pv)))
    return write(path, msgs), lon, lat


def test_many_level_types_open_on_the_isobaric_ones_and_list_the_rest(tmp_path):
    path, lon, lat = _product(tmp_path / "gfs-like.grib2")
    ds = open_dataset(path)
    assert ds.level_type == "isobaricInhPa"
    assert ds.level_types["isobaricInhPa"]["3d"] == 5  # t, u, v, gh, clwmr (r is on one level)
    assert ds.level_types["potentialVorticity"] == {"3d": 1, "fields": 2}
    assert ds.level_types["surface"] == {"3d": 0, "fields": 1} and "tropopause" in ds.level_types
    assert "r" in ds.skipped and "2-D field" in ds.skipped["r"]
    # Values at the right level: level 0 is the bottom (1000 hPa), rows south to north.
    t = ds.read("temperature", 0)
    for k, p in enumerate(LEVELS):
        np.testing.assert_array_equal(t[k], (250 + 10 * field(lon, lat, p))[::-1].astype(np.float32))
    np.testing.assert_array_equal(ds.read("pressure", 0)[:, 0, 0], np.array(LEVELS) * 100.0)
    # One level axis: clwmr has 3 of the 5 levels, NaN on the others.
    c = ds.read("cloud_water", 0)
    assert np.isnan(c[3:]).all() and np.isfinite(c[:3]).all()
    np.testing.assert_allclose(c[1], (1e-4 * (1 + field(lon, lat, 850)))[::-1], rtol=1e-6)
    assert any("shared by all variables" in n and "clwmr (3 of 5)" in n for n in ds.notes)
    # Heights: the mean of gh on each level (it rises with the level).
    np.testing.assert_allclose(ds.grid.height[:, 0, 0],
                               [np.mean(44330.8 * (1 - (p / 1013.25) ** 0.1903) + field(lon, lat, p))
                                                        for p in LEVELS], rtol=1e-6)  # fields are float32


def test_level_type_chooses_another_kind_and_refuses_an_unknown_one(tmp_path):
    path, lon, lat = _product(tmp_path / "gfs-like.grib2")
    with pytest.raises(DataError,
                       match=r"field 'level_type': no fields on level type 'hybrid' \(found: .*isobaricInhPa") as err:
        open_dataset(path, level_type="hybrid")
    assert "\n" not in str(err.value)
    with pytest.raises(DataError, match=r"level type 'surface' has no field on two or more levels"):
        open_dataset(path, level_type="surface")
    # PV levels hold t on two levels but no geopotential height to place them: one line naming the kind.
    with pytest.raises(DataError, match=r"cannot place potentialVorticity levels: no geopotential height"):
        open_dataset(path, level_type="potentialVorticity")


def test_variables_by_meaning_shortname_standard_and_cf_names(tmp_path):
    path, lon, lat = _product(tmp_path / "gfs-like.grib2")
    ds = open_dataset(path)
    assert (ds.resolve("clwmr") == ds.resolve("cloud_water") == ds.resolve("cloud_liquid_water_mixing_ratio")
            == "cloud_water")
    assert ds.read("clwmr", 0) is ds.read("cloud_water", 0)
    assert ds.resolve("t") == ds.resolve("air_temperature") == ds.resolve("TEMPERATURE") == "temperature"
    assert ds.variables["cloud_water"].units == "kg/kg"


def test_ensemble_members_and_steps(tmp_path):
    """ERA5-like ensemble: 5 members x 3 steps x 2 levels of t; control by default, member= for another."""
    grid, lon, lat = regular_ll()
    msgs = [isobaric("t", p, grid, 250 + field(lon, lat, p) + 10 * m + step, number=m, step=step)
            for step in (0, 6, 12) for m in range(5) for p in (850, 500)]
    path = write(tmp_path / "ens.grib2", msgs)
    ds = open_dataset(path)
    assert ds.members == [0, 1, 2, 3, 4] and ds.member == 0
    np.testing.assert_array_equal(ds.times,
                                  np.array(["2024-01-01T00", "2024-01-01T06", "2024-01-01T12"], dtype="datetime64[s]"))
    np.testing.assert_array_equal(ds.read("temperature", 2)[1],
                                  (250 + field(lon, lat, 500) + 12)[::-1].astype(np.float32))
    three = open_dataset(path, member=3)
    np.testing.assert_array_equal(three.read("temperature", 1)[0],
                                  (250 + field(lon, lat, 850) + 36)[::-1].astype(np.float32))
    with pytest.raises(DataError, match=r"field 'member': no member 7 \(members: 0\.\.4\)"):
        open_dataset(path, member=7)


def test_valid_time_from_many_reference_times_and_steps(tmp_path):
    """Two runs (00 and 06 UTC) of 0 and 6 h steps: valid times 00, 06, 12; at 06 the 06 UTC run's analysis wins."""
    grid, lon, lat = regular_ll()
    msgs = [isobaric("t", p, grid, 250 + field(lon, lat, p) + run + step / 100, time=run * 100, step=step)
            for run in (0, 6) for step in (0, 6) for p in (850, 500)]
    path = write(tmp_path / "runs.grib2", msgs)
    ds = open_dataset(path)
    np.testing.assert_array_equal(ds.times,
                                  np.array(["2024-01-01T00", "2024-01-01T06", "2024-01-01T12"], dtype="datetime64[s]"))
    # run 06, step 0
    np.testing.assert_array_equal(ds.read("t", 1)[0], (250 + field(lon, lat, 850) + 6)[::-1].astype(np.float32))
    np.testing.assert_array_equal(ds.read("t", 2)[0], (250 + field(lon, lat, 850) + 6.06)[::-1].astype(np.float32))
    assert any("later reference time" in n for n in ds.notes)


def test_grib_refuses_netcdf_overrides_in_one_line(tmp_path):
    path, _, _ = _product(tmp_path / "p.grib2")
    with pytest.raises(DataError, match=r"p.grib2: field 'p0': GRIB files state their levels and times"):
        open_dataset(path, p0=1e5)


def test_index_is_cached_outside_the_data_and_renewed_when_the_file_changes(tmp_path, own_cache, monkeypatch):
    from nephele.core.climate import gribscan

    data = tmp_path / "data"
    data.mkdir()
    path, lon, lat = _product(data / "p.grib2")
    data.chmod(0o555)  # the user's data may be read-only: nothing is written beside it
    try:
        first = open_dataset(path)
        assert sorted(p.name for p in data.iterdir()) == ["p.grib2"]
        index_files = list((own_cache / "grib-index").glob("*.npz"))
        assert len(index_files) == 1
        calls = []
        monkeypatch.setattr(gribscan, "scan", lambda p: calls.append(p) or pytest.fail("scanned again"))
        again = open_dataset(path)  # from the index: no scan
        np.testing.assert_array_equal(again.read("t", 0), first.read("t", 0))
    finally:
        data.chmod(0o755)
    monkeypatch.undo()
    monkeypatch.setenv("NEPHELE_CACHE", str(own_cache))
    write(path, [isobaric("t", p, regular_ll()[0], np.full((5, 8), 300.0 + p)) for p in (900, 800)])  # the file changes
    changed = open_dataset(path)
    assert changed.grid.shape[0] == 2 and changed.read("t", 0)[0, 0, 0] == 1200.0
    assert len(list((own_cache / "grib-index").glob("*.npz"))) == 1  # the old index went


def test_unwritable_cache_is_said_aloud_and_the_file_still_opens(tmp_path, monkeypatch):
    path, _, _ = _product(tmp_path / "p.grib2")
    blocked = tmp_path / "cache-is-a-file"
    blocked.write_text("")  # no folder can be made under it (even by root)
    monkeypatch.setenv("NEPHELE_CACHE", str(blocked))
    ds = open_dataset(path)
    assert any(n.startswith("index: not saved in the cache") for n in ds.notes)
    assert ds.read("t", 0).shape == (5, 5, 8)


def test_not_grib_and_cut_short_are_one_line(tmp_path):
    bad = tmp_path / "notes.grib2"
    bad.write_text("plain text, no messages\n" * 50)
    with pytest.raises(DataError, match=r"notes.grib2: cannot open as GRIB \(no GRIB message found: not GRIB\)"):
        open_dataset(bad)
    bad.write_text("GRIB is named here but no message follows\n" * 50)
    with pytest.raises(DataError,
                       match=r"notes.grib2: cannot open as GRIB \(no readable GRIB message; skipped 50 damaged") as err:
        open_dataset(bad)
    assert "\n" not in str(err.value)
    path, _, _ = _product(tmp_path / "p.grib2")
    cut = tmp_path / "cut.grib2"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size - 100])  # the last message cut short
    ds = open_dataset(cut)  # every whole message still reads
    assert ds.level_type == "isobaricInhPa" and any(n.startswith("scan: skipped 1 damaged message") for n in ds.notes)
