"""NetCDF as the archives deliver it (files built by tests/archives.py with netCDF4): ERA5 from the
current CDS (packed shorts, valid_time, pressure_level, number, expver, the zip), MERRA-2 model layers,
CMIP6 ``cl`` on hybrid sigma-pressure with 360-day and no-leap calendars, unstructured grids refused."""

import archives
import numpy as np
import pytest

from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError


def test_era5_cds_pressure_levels_packed_shorts(tmp_path):
    info = archives.era5_cds(tmp_path / "era5.nc")
    ds = open_dataset(tmp_path / "era5.nc")
    assert ds.grid.shape == (3, 13, 12) and ds.members == []
    np.testing.assert_array_equal(ds.times, info["times"])
    np.testing.assert_allclose(ds.read("pressure", 0)[:, 0, 0], [100000.0, 85000.0, 50000.0])
    # unpacked values (scale_factor/add_offset), latitude turned south to north, level 0 at 1000 hPa
    np.testing.assert_allclose(ds.read("temperature", 2), info["values"]["t"][2][:, ::-1], rtol=1e-6)
    np.testing.assert_allclose(ds.read("clwc", 1), info["values"]["clwc"][1][:, ::-1], rtol=1e-5, atol=1e-10)
    assert ds.resolve("clwc") == ds.resolve("cloud_water") == "cloud_water"
    assert "omega" in ds.variables and "w" not in ds.variables  # ERA5's w is in Pa/s
    np.testing.assert_allclose(ds.read("cloud", 0), info["values"]["cc"][0][:, ::-1], rtol=1e-5)
    # heights: the mean geopotential of each level over g
    np.testing.assert_allclose(ds.grid.height[:, 0, 0], info["values"]["z"][0].mean(axis=(1, 2)) / 9.80665, rtol=1e-5)


def test_era5_ensemble_member_dimension(tmp_path):
    info = archives.era5_cds(tmp_path / "ens.nc", members=3, packed=False)
    ds = open_dataset(tmp_path / "ens.nc")
    assert ds.members == [0, 1, 2] and ds.member == 0
    np.testing.assert_array_equal(ds.read("t", 1), info["values"]["t"][0, 1][:, ::-1])
    two = open_dataset(tmp_path / "ens.nc", member=2)
    np.testing.assert_array_equal(two.read("t", 1), info["values"]["t"][2, 1][:, ::-1])
    with pytest.raises(DataError, match=r"ens.nc: field 'member': no member 5 \(members: 0, 1, 2\)"):
        open_dataset(tmp_path / "ens.nc", member=5)
    with pytest.raises(DataError,
                       match=r"field 'member': member 1 asked for, but the file has no ensemble member dimension"):
        open_dataset(archives.era5_cds(tmp_path / "one.nc") and tmp_path / "one.nc", member=1)


def test_era5_cds_zip_reads_the_instant_fields_unpacked_into_the_cache(tmp_path, own_cache):
    data = tmp_path / "download"
    data.mkdir()
    info = archives.era5_zip(data / "data.zip")
    data.chmod(0o555)
    try:
        ds = open_dataset(data / "data.zip")
        assert sorted(p.name for p in data.iterdir()) == ["data.zip"]  # nothing unpacked beside the download
    finally:
        data.chmod(0o755)
    assert ds.source == str(data / "data.zip")
    assert any(n == "zip: read data_stream-oper_stepType-instant.nc; also in the zip: "
                    "data_stream-oper_stepType-accum.nc"
               for n in ds.notes)
    np.testing.assert_allclose(ds.read("t", 3), info["values"]["t"][3][:, ::-1], rtol=1e-6)
    assert list((own_cache / "zip").rglob("*.nc"))
    bad = tmp_path / "bad.zip"
    bad.write_bytes(b"PK not really a zip")
    with pytest.raises(DataError, match=r"bad.zip: cannot open as a zip of NetCDF files"):
        open_dataset(bad)


def test_merra2_model_layers(tmp_path):
    info = archives.merra2(tmp_path / "MERRA2_400.inst3_3d_asm_Nv.20170101.nc4")
    ds = open_dataset(tmp_path / "MERRA2_400.inst3_3d_asm_Nv.20170101.nc4")
    assert ds.grid.shape == (72, 11, 12) and "model layers 1..72" in ds.vertical
    # lev 1 is the top: level 0 is layer 72; longitudes -180..150 become 0..330
    lon_order = np.argsort(np.mod(info["lon"], 360.0))
    np.testing.assert_allclose(ds.grid.height, info["H"][0][::-1][:, :, lon_order], rtol=1e-6)
    np.testing.assert_allclose(ds.read("pressure", 1), info["PL"][1][::-1][:, :, lon_order], rtol=1e-6)
    np.testing.assert_allclose(ds.read("QL", 1), info["QL"][1][::-1][:, :, lon_order], rtol=1e-6)
    assert ds.resolve("clwmr") == ds.resolve("ql") == "cloud_water" and ds.resolve("cloud_ice") == "cloud_ice"
    np.testing.assert_array_equal(ds.times, np.array(["2017-01-01T00", "2017-01-01T03"], dtype="datetime64[s]"))


def test_merra2_without_heights_integrates_delp_and_t(tmp_path):
    netCDF4 = pytest.importorskip("netCDF4")
    path = tmp_path / "noH.nc4"
    info = archives.merra2(path)
    with netCDF4.Dataset(path, "a") as nc:
        nc.renameVariable("H", "H_unused")  # no mid-layer heights: integrate upward instead
    ds = open_dataset(path)
    assert "hypsometric equation from DELP and T" in ds.vertical
    np.testing.assert_allclose(ds.read("pressure", 0),
                               info["PL"][0][::-1][:, :, np.argsort(np.mod(info["lon"], 360.0))], rtol=1e-6)
    assert np.all(np.diff(ds.grid.height, axis=0) > 0)


@pytest.mark.parametrize("calendar, month_days", [("360_day", 30.0), ("noleap", 365.0 / 12.0)])
def test_cmip6_cl_on_hybrid_sigma_pressure(tmp_path, calendar, month_days):
    info = archives.cmip6_cl(tmp_path / "cl_Amon.nc", calendar)
    ds = open_dataset(tmp_path / "cl_Amon.nc")
    assert "hybrid sigma-pressure" in ds.vertical and ds.grid.shape == (5, 4, 6)
    # p = a p0 + b ps, bottom level first (lev is stored top down here: b grows along it)
    want = (info["a"][:, None, None] * 1e5 + info["b"][:, None, None] * info["ps"][2][None])[::-1]
    np.testing.assert_allclose(ds.read("pressure", 2), want, rtol=1e-6)
    np.testing.assert_allclose(ds.read("cloud", 1), info["cl"][1][::-1] / 100.0, rtol=1e-6)  # percent to a fraction
    np.testing.assert_allclose(np.diff(ds.hours), month_days * 24.0, atol=1.0)
    assert "time_bnds" not in ds.skipped and "lev_bnds" not in ds.skipped  # bounds describe coordinates


@pytest.mark.parametrize("make, words", [(archives.icon, "ICON/CDI: 20480 cells on dimension 'ncells'"),
                                         (archives.mpas, "MPAS: 2562 cells on dimension 'nCells'")])
def test_unstructured_grids_are_refused_in_one_line(tmp_path, make, words):
    path = make(tmp_path / "unstructured.nc")
    with pytest.raises(DataError, match=r"is on an unstructured grid") as err:
        open_dataset(path)
    assert words in str(err.value) and "remap it first" in str(err.value) and "\n" not in str(err.value)
