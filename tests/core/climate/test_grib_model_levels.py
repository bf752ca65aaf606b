"""Model levels in GRIB: ECMWF hybrid levels from the messages' pv with lnsp or sp, NCEP's numbering,
NCEP native levels, and heights by the hypsometric equation.

The truth is the closed form: p = a + b ps on half levels, full levels their mean; for an isothermal
dry atmosphere the IFS hypsometric integration (IFS documentation Part III, eqs. 2.20-2.23) is
z_{k+1/2} = R T / g ln(ps / p_{k+1/2}) and z_k = z_{k+1/2} + alpha_k R T / g, written here in one
vectorised line independent of the reader's loop.
"""

from pathlib import Path

import numpy as np
import pytest
from gribfiles import message, regular_ll, when, write

from nephele.core.climate.humidity import G0, R_DRY
from nephele.core.climate.readers import open_dataset
from nephele.core.errors import DataError

eccodes = pytest.importorskip("eccodes")
DATA = Path(__file__).resolve().parents[2] / "data" / "grib"
A = np.array([0.0, 2000.0, 8000.0, 15000.0, 10000.0, 3000.0, 0.0])  # half levels, top down (Pa)
B = np.array([0.0, 0.0, 0.05, 0.2, 0.5, 0.85, 1.0])


def _hybrid(short, level, grid, values, pv, centre="ecmf"):
    keys = [("centre", centre), *when(), *grid, ("typeOfFirstFixedSurface", 105), ("level", int(level)),
            ("shortName", short), ("PVPresent", 1), ("pv", pv)]
    return message("regular_ll_pl_grib2", keys, values)


def _surface(short, grid, values):
    return message("regular_ll_sfc_grib2",
                   [*when(), *grid, ("typeOfLevel", "surface"), ("level", 0), ("shortName", short)], values)


def _closed_form(ps, a=A, b=B, t=250.0, zs=0.0):
    """Full-level pressures and isothermal dry heights (top down) for surface pressure ``ps``."""
    half = a[:, None, None] + b[:, None, None] * ps[None]
    full = 0.5 * (half[:-1] + half[1:])
    upper, lower = half[:-1], half[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        dlog = np.log(lower / upper)
        alpha = np.where(upper > 0, 1.0 - upper / (lower - upper) * dlog, np.log(2.0))
    z_lower = zs + R_DRY * t / G0 * np.log(ps[None] / lower)
    return full, z_lower + alpha * R_DRY * t / G0


def _ps(lon, lat):
    lo, la = np.meshgrid(np.deg2rad(lon), np.deg2rad(lat))
    return 95000.0 + 6000.0 * np.cos(lo) * np.cos(la)


@pytest.mark.parametrize("surface", ["lnsp", "sp"])
def test_ecmwf_model_levels_pressure_and_hypsometric_heights(tmp_path, surface):
    grid, lon, lat = regular_ll()
    ps = _ps(lon, lat)
    pv = np.concatenate([A, B])
    msgs = [_hybrid("t", n, grid, np.full(ps.shape, 250.0), pv) for n in range(1, 7)]
    msgs += [_hybrid("q", n, grid, np.zeros(ps.shape), pv) for n in range(1, 7)]
    msgs.append(_hybrid("lnsp", 1, grid, np.log(ps), pv) if surface == "lnsp" else _surface("sp", grid, ps))
    msgs.append(_surface("z", grid, np.full(ps.shape, G0 * 300.0)))  # the surface 300 m up
    ds = open_dataset(write(tmp_path / "ml.grib2", msgs))
    assert ds.level_type == "hybrid" and "hybrid sigma-pressure" in ds.vertical
    full, z = _closed_form(ps, zs=300.0)
    # Level 0 is the bottom (model level 6); rows south to north.
    p = ds.read("pressure", 0)
    np.testing.assert_allclose(p, full[::-1, ::-1], rtol=1e-6)  # well within the 0.1 % asked
    np.testing.assert_allclose(ds.grid.height, z[::-1, ::-1], rtol=1e-6)  # ps, z, t pass through float32
    assert "hypsometric equation from t and q" in ds.vertical and "surface at 'z'" in ds.vertical
    np.testing.assert_array_equal(ds.read("temperature", 0), np.full((6, 5, 8), 250.0, np.float32))


def test_moist_air_is_higher_by_its_virtual_temperature(tmp_path):
    grid, lon, lat = regular_ll()
    ps = _ps(lon, lat)
    pv = np.concatenate([A, B])
    q = 0.01
    msgs = [_hybrid("t", n, grid, np.full(ps.shape, 280.0), pv) for n in range(1, 7)]
    msgs += [_hybrid("q", n, grid, np.full(ps.shape, q), pv) for n in range(1, 7)]
    msgs.append(_hybrid("lnsp", 1, grid, np.log(ps), pv))
    ds = open_dataset(write(tmp_path / "moist.grib2", msgs))
    _, z = _closed_form(ps, t=280.0 * (1 + (1 / 0.622 - 1) * q))  # T_v = T (1 + 0.6077 q)
    np.testing.assert_allclose(ds.grid.height, z[::-1, ::-1], rtol=1e-6)
    assert "surface at sea level" in ds.vertical


def test_ncep_numbering_from_the_surface_up(tmp_path):
    """NCEP lists pv from the surface up and numbers level 1 the lowest; the same atmosphere must come out."""
    grid, lon, lat = regular_ll()
    ps = _ps(lon, lat)
    pv = np.concatenate([A[::-1], B[::-1]])
    msgs = [_hybrid("t", n, grid, np.full(ps.shape, 250.0), pv, centre="kwbc") for n in range(1, 7)]
    msgs.append(_surface("sp", grid, ps))
    ds = open_dataset(write(tmp_path / "ncep-ml.grib2", msgs))
    full, z = _closed_form(ps)
    np.testing.assert_allclose(ds.read("pressure", 0), full[::-1, ::-1], rtol=1e-6)
    np.testing.assert_allclose(ds.grid.height, z[::-1, ::-1], rtol=1e-6)  # ps, z, t pass through float32
    assert "dry air: no q" in ds.vertical


def test_some_model_levels_only_fall_back_to_the_standard_atmosphere(tmp_path):
    from nephele.core.climate.humidity import standard_height

    grid, lon, lat = regular_ll()
    ps = _ps(lon, lat)
    pv = np.concatenate([A, B])
    msgs = [_hybrid("t", n, grid, np.full(ps.shape, 250.0), pv) for n in (2, 4, 6)]
    msgs.append(_hybrid("lnsp", 1, grid, np.log(ps), pv))
    ds = open_dataset(write(tmp_path / "some.grib2", msgs))
    full, _ = _closed_form(ps)
    np.testing.assert_allclose(ds.read("pressure", 0), full[[5, 3, 1], ::-1], rtol=1e-6)
    np.testing.assert_allclose(ds.grid.height, standard_height(full[[5, 3, 1], ::-1]), rtol=1e-6)
    assert "standard atmosphere" in ds.vertical


def test_model_levels_without_surface_pressure_are_one_line(tmp_path):
    grid, lon, lat = regular_ll()
    pv = np.concatenate([A, B])
    path = write(tmp_path / "nops.grib2", [_hybrid("t", n, grid, np.full((5, 8), 250.0), pv) for n in range(1, 4)])
    with pytest.raises(DataError,
                       match=r"nops.grib2: field 'pv': hybrid levels need the surface pressure \(lnsp") as err:
        open_dataset(path)
    assert "\n" not in str(err.value)


def test_ncep_native_levels_use_their_own_pressure_and_heights(tmp_path):
    """RAP/HRRR native output: hybrid levels without pv, with pres and gh on every level (level 1 lowest)."""
    grid, lon, lat = regular_ll()
    msgs = []
    for n in range(1, 5):
        h = 500.0 * n + 10.0 * np.add.outer(np.arange(5), np.arange(8))
        msgs.append(message("regular_ll_pl_grib2",
                            [("centre", "kwbc"), *when(), *grid, ("typeOfFirstFixedSurface", 105),
                                                    ("level", n), ("shortName", "gh")], h))
        msgs.append(message("regular_ll_pl_grib2",
                            [("centre", "kwbc"), *when(), *grid, ("typeOfFirstFixedSurface", 105),
                                                    ("level", n), ("shortName", "pres")], 1e5 * np.exp(-h / 8000.0)))
    ds = open_dataset(write(tmp_path / "native.grib2", msgs))
    want = 500.0 * np.arange(1, 5)[:, None, None] + 10.0 * np.add.outer(np.arange(5), np.arange(8))[None, ::-1]
    np.testing.assert_allclose(ds.grid.height, want, rtol=1e-6)
    np.testing.assert_allclose(ds.read("pressure", 0), 1e5 * np.exp(-want / 8000.0), rtol=1e-6)
    assert "native model levels" in ds.vertical


def test_real_ifs_l91_coefficients_give_the_closed_form_pressures(tmp_path):
    """The pv of ECMWF's regular_gg_ml.grib (IFS L91), with t on every level and lnsp: pressures within
    0.1 % of a + b ps (here to float32 precision), heights rising monotonically."""
    with open(DATA / "regular_gg_ml.grib", "rb") as f:
        src = eccodes.codes_grib_new_from_file(f)
    pv = eccodes.codes_get_array(src, "pv")
    nlev = pv.size // 2 - 1
    nj, ni = eccodes.codes_get(src, "Nj"), eccodes.codes_get(src, "Ni")
    lat = eccodes.codes_get_array(src, "distinctLatitudes")
    # rows as stored (north first)
    ps = np.broadcast_to(101325.0 - 3000.0 * np.cos(np.deg2rad(lat))[::-1, None] ** 2, (nj, ni))
    msgs = []
    for n in range(1, nlev + 1):
        h = eccodes.codes_clone(src)
        eccodes.codes_set(h, "level", n)
        eccodes.codes_set_values(h, np.full(nj * ni, 230.0 + 0.5 * n))
        msgs.append(h)
    lnsp = eccodes.codes_clone(src)
    eccodes.codes_set(lnsp, "shortName", "lnsp")
    eccodes.codes_set(lnsp, "level", 1)
    eccodes.codes_set(lnsp, "bitsPerValue", 24)
    eccodes.codes_set_values(lnsp, np.log(ps).ravel())
    msgs.append(lnsp)
    eccodes.codes_release(src)
    ds = open_dataset(write(tmp_path / "l91.grib", msgs))
    assert ds.grid.shape == (nlev, nj, ni)
    a, b = pv[: nlev + 1], pv[nlev + 1:]
    half = a[:, None, None] + b[:, None, None] * ps[None]
    full = 0.5 * (half[:-1] + half[1:])[::-1, ::-1]  # bottom first, rows south first
    got = ds.read("pressure", 0)
    assert np.max(np.abs(got / full - 1.0)) < 1e-3
    np.testing.assert_allclose(got, full, rtol=1e-5)  # lnsp packed in 24 bits
    assert np.all(np.diff(ds.grid.height, axis=0) > 0)
