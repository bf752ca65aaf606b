"""Exact volume shading (core/volume/volume_atlas.py) against the curvilinear reference.

Truth: :class:`CurvilinearField` located with ``clamp_below`` and interpolated in
float64 (trilinear in the curvilinear cell), ``np.interp``, analytic fields and
``TransferFunction.__call__``.  The shader emulation works in float32, so values
agree to ~1e-5 and the tolerance is 1e-4 (fields of order 1).
"""

import numpy as np
import pytest

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid, globe_radius, lonlat_to_xyz
from nephele.core.errors import DataError
from nephele.core.pipeline import tasks
from nephele.core.pipeline.sources import register_source
from nephele.core.volume.sparse import EXACT, CurvilinearField
from nephele.core.volume.transfer import TransferFunction
from nephele.core.volume.volume_atlas import (
    DEFAULT_BELOW,
    atlas_layout,
    axis_runs,
    exact_volume,
    map_runs,
    tf_eval32,
)
from nephele.core.volume.volume_task import frame_params

TF = TransferFunction.ramp(0.3, 0.7)
TOL = 1e-4  # value agreement, float32 shader against float64 reference


def analytic(lon, lat, h):
    """A smooth field in 0..1 crossing the threshold often (degrees, metres)."""
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    return (0.5 + 0.45 * np.sin(3 * lam + 1.0) * np.cos(2 * phi) * np.cos(h / 4000.0)
            + 0.05 * np.sin(5 * phi)).astype(np.float32)


def terrain_grid(lon, lat, nk=6, top=16000.0, seed=0):
    """Terrain-following levels whose spacing varies per column (not a hybrid
    ``a_k + b_k * terrain`` form): ``h_k = g + (top - g) * s_k ** p`` with a
    random exponent ``p`` per column."""
    rng = np.random.default_rng(seed)
    L, P = np.meshgrid(lon, lat)
    ground = np.maximum(0.0, 2500.0 * np.sin(np.deg2rad(2 * L)) * np.cos(np.deg2rad(P)) ** 2)
    p = rng.uniform(0.8, 1.6, ground.shape)
    s = np.linspace(0.0, 1.0, nk)[:, None, None]
    h = ground[None] + (top - ground[None]) * s ** p[None]
    return GlobeGrid(np.asarray(lon, float), np.asarray(lat, float), h)


def flat_grid(nk=5):
    """A 10° periodic grid stopping 5° short of the poles, flat levels 0-16 km."""
    lon = np.arange(36) * 10.0
    lat = -85.0 + 10.0 * np.arange(18)
    h = np.linspace(0.0, 16000.0, nk)[:, None, None] + np.zeros((nk, 18, 36))
    return GlobeGrid(lon, lat, h)


def field_values(grid):
    L, P = np.meshgrid(grid.lon, grid.lat)
    return analytic(L[None], P[None], grid.height)


def setup(grid, values):
    field = CurvilinearField.from_grid(grid, {"value": values})
    layout = atlas_layout(grid)
    return field, layout, layout.values_atlas(field)


def reference(field, xyz, below=DEFAULT_BELOW):
    flat, f, _, ok = field.locate(xyz, clamp_below=below)
    return field.interpolate("value", flat, f, ok)


def random_points(rng, n, lon=(-180.0, 180.0), lat=(-90.0, 90.0), h=(-1500.0, 17000.0)):
    """Uniform on the sphere's area within the lon/lat box, uniform in height."""
    lo = rng.uniform(*lon, n)
    sl = rng.uniform(np.sin(np.deg2rad(lat[0])), np.sin(np.deg2rad(lat[1])), n)
    la = np.rad2deg(np.arcsin(sl))
    hh = rng.uniform(*h, n)
    return lonlat_to_xyz(lo, la, globe_radius(hh))


def assert_agrees(field, layout, atlas, xyz, below=DEFAULT_BELOW):
    """Same inside/outside decision, values within TOL, opacities within the ramp's slope × TOL."""
    value, _, ok = layout.shade(atlas, xyz, below=below)
    ref = reference(field, xyz, below)
    rok = np.isfinite(ref)
    np.testing.assert_array_equal(ok, rok)
    np.testing.assert_allclose(value[ok], ref[ok], atol=TOL, rtol=0)
    a32 = np.where(ok, tf_eval32(TF, value), 0.0)
    np.testing.assert_allclose(a32, np.nan_to_num(TF(ref)), atol=2.5 * TOL, rtol=0)
    return ok


# --- axis maps ------------------------------------------------------------------------------


def test_axis_runs_counts_runs_of_equal_spacing():
    assert len(axis_runs(np.arange(65) * 5.625)) == 1
    lat = np.concatenate([[-90.0], -87.1875 + 5.625 * np.arange(32), [90.0]])
    assert len(axis_runs(lat)) == 3
    x, _ = np.polynomial.legendre.leggauss(48)
    gauss = np.concatenate([[-90.0], np.rad2deg(np.arcsin(x)), [90.0]])
    assert len(axis_runs(gauss)) >= 40


@pytest.mark.parametrize("kind", ["uniform", "poles", "gauss"])
def test_axis_map_is_np_interp_to_float32_precision(kind):
    if kind == "uniform":
        knots = np.arange(65) * 5.625
    elif kind == "poles":
        knots = np.concatenate([[-90.0], -87.1875 + 5.625 * np.arange(32), [90.0]])
    else:
        x, _ = np.polynomial.legendre.leggauss(48)
        knots = np.concatenate([[-90.0], np.rad2deg(np.arcsin(x)), [90.0]])
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.uniform(knots[0], knots[-1], 20000), knots])
    got = map_runs(x, axis_runs(knots))
    want = np.interp(x, knots, np.arange(knots.size))
    # Each ramp adds a few float32 roundings of the running index (< n).
    assert np.abs(got - want).max() <= 8 * np.finfo(np.float32).eps * knots.size
    # Beyond the ends the map clamps.
    np.testing.assert_array_equal(map_runs([knots[0] - 10, knots[-1] + 10], axis_runs(knots)),
                                  [0, knots.size - 1])


@pytest.mark.parametrize("bad", [[0.0, 2.0, 1.0], [0.0, 1.0, 1.0, 2.0], [3.0], [[0.0, 1.0], [2.0, 3.0]]])
def test_axis_runs_rejects_bad_axes(bad):
    with pytest.raises(DataError):
        axis_runs(bad)


# --- shading against the reference -----------------------------------------------------------


def test_periodic_grid_with_pole_rows_matches_reference():
    lon = np.arange(36) * 10.0 + 5.0
    lat = -85.0 + 10.0 * np.arange(18)  # stops 5° short of both poles: pole rows added
    grid = terrain_grid(lon, lat)
    field, layout, atlas = setup(grid, field_values(grid))
    assert layout.periodic and len(layout.lat_runs) == 3 and len(layout.lon_runs) == 1
    ok = assert_agrees(field, layout, atlas, random_points(np.random.default_rng(2), 60000))
    assert ok.mean() > 0.8


def test_regional_grid_matches_reference_and_is_empty_outside():
    lon = np.linspace(-30.0, 60.0, 31)  # not periodic, stops short of 360°
    lat = np.linspace(-50.0, 70.0, 25)  # stops short of both poles: no pole rows
    grid = terrain_grid(lon, lat, seed=3)
    field, layout, atlas = setup(grid, field_values(grid))
    assert not layout.periodic
    rng = np.random.default_rng(4)
    pts = np.concatenate([random_points(rng, 30000), random_points(rng, 30000, (-30, 60), (-50, 70))])
    ok = assert_agrees(field, layout, atlas, pts)
    lon_p, lat_p = np.rad2deg(np.arctan2(pts[:, 1],
                                         pts[:, 0])), np.rad2deg(np.arcsin(pts[:, 2] / np.linalg.norm(pts, axis=1)))
    outside = (lon_p < -30.0) | (lon_p > 60.0) | (lat_p < -50.0) | (lat_p > 70.0)
    assert outside.sum() > 20000 and not ok[outside].any()
    assert ok[~outside].mean() > 0.8


@pytest.mark.parametrize("lon0", [150.0, 250.0])
def test_regional_grid_beyond_180_east_matches_reference(lon0):
    """A regional grid in 0..360 convention (lon0 + span > 180): atan2's
    longitudes in (-180, 180] must be wrapped before the range test."""
    lon = lon0 + np.linspace(0.0, 80.0, 17)
    lat = np.linspace(-40.0, 40.0, 17)
    grid = terrain_grid(lon, lat, seed=5)
    field, layout, atlas = setup(grid, field_values(grid))
    pts = random_points(np.random.default_rng(6), 20000, (lon0, lon0 + 80.0), (-40.0, 40.0))
    ok = assert_agrees(field, layout, atlas, pts)
    assert ok.mean() > 0.8


def test_gaussian_latitudes_match_reference():
    x, _ = np.polynomial.legendre.leggauss(24)
    lat = np.rad2deg(np.arcsin(x))
    lon = np.arange(48) * 7.5
    grid = terrain_grid(lon, lat, seed=7)
    field, layout, atlas = setup(grid, field_values(grid))
    assert len(layout.lat_runs) > 20
    assert_agrees(field, layout, atlas, random_points(np.random.default_rng(8), 50000))


def test_demo_small_terrain_following_matches_reference():
    from nephele.core.climate.readers import open_dataset

    ds = open_dataset("demo:small")
    grid = ds.grid
    # Heights vary per column, and not as a hybrid a_k + b_k * ground.
    dz = np.diff(grid.height, axis=0)
    assert np.ptp(dz[0]) > 100.0
    values = ds.read("cloud", 5)
    field, layout, atlas = setup(grid, values)
    ok = assert_agrees(field, layout, atlas, random_points(np.random.default_rng(9), 60000, h=(-1500, 21000)))
    assert ok.mean() > 0.5


# --- hard cases -----------------------------------------------------------------------------


@pytest.mark.parametrize("lon0", [0.0, -177.5, 42.5])
def test_longitude_seam(lon0):
    lon = lon0 + np.arange(36) * 10.0
    lat = -85.0 + 10.0 * np.arange(18)
    grid = terrain_grid(lon, lat, seed=10)
    field, layout, atlas = setup(grid, field_values(grid))
    rng = np.random.default_rng(11)
    n = 2000
    la = rng.uniform(-80, 80, n)
    h = rng.uniform(3000, 15000, n)
    for lo in (lon0, lon0 + 360.0 - 1e-6, lon0 + 360.0 - 1e-3, lon0 + 1e-3):
        pts = lonlat_to_xyz(np.full(n, lo), la, globe_radius(h))
        ok = assert_agrees(field, layout, atlas, pts)
        assert ok.all()
    # Across the seam the field is continuous: both sides give the first column.
    a = layout.shade(atlas, lonlat_to_xyz(np.full(n, lon0 + 360.0 - 1e-6), la, globe_radius(h)))[0]
    b = layout.shade(atlas, lonlat_to_xyz(np.full(n, lon0), la, globe_radius(h)))[0]
    np.testing.assert_allclose(a, b, atol=TOL)


def test_poles_take_the_ring_mean():
    grid = flat_grid()
    values = field_values(grid)
    field, layout, atlas = setup(grid, values)
    hh = np.linspace(100.0, 15900.0, 40)
    r = globe_radius(hh)
    for sign, row in ((1.0, -1), (-1.0, 0)):
        pts = np.stack([np.zeros_like(r), np.zeros_like(r), sign * r], axis=1)  # x = y = 0 exactly
        value, _, ok = layout.shade(atlas, pts)
        assert ok.all()
        # Independent truth: the row's mean per level, linear in height (flat levels).
        ring = values[:, row, :].astype(np.float64).mean(axis=1)
        np.testing.assert_allclose(value, np.interp(hh, grid.height[:, 0, 0], ring), atol=TOL)
        np.testing.assert_allclose(value, reference(field, pts), atol=TOL)


def test_values_exactly_at_the_threshold_are_transparent():
    grid = terrain_grid(np.arange(36) * 10.0, -85.0 + 10.0 * np.arange(18), seed=12)
    tf = TransferFunction.ramp(0.375, 0.75)  # exact in float32 and float64 alike
    values = np.full(grid.shape, 0.375, np.float32)
    values[:, :, 20:] = 0.9  # some cloud elsewhere
    field, layout, atlas = setup(grid, values)
    pts = random_points(np.random.default_rng(13), 20000, lon=(5.0, 185.0), lat=(-80, 80), h=(2600.0, 15900.0))
    value, _, ok = layout.shade(atlas, pts)
    assert ok.all()
    assert np.all(value == np.float32(0.375))  # constant cells stay exactly at the threshold
    assert np.all(tf_eval32(tf, value) == 0.0)
    assert np.abs(tf(reference(field, pts))).max() < 1e-12  # float64 weights sum to 1 ± ulp
    # Everything at the threshold: nothing to render, no support, no crash.
    ev = exact_volume(grid, np.full(grid.shape, 0.375, np.float32), tf)
    assert ev.empty and not ev.shade(pts)[2].any()


def test_nan_regions_hide_their_cells_only():
    lon = np.arange(36) * 10.0
    lat = -85.0 + 10.0 * np.arange(18)
    grid = terrain_grid(lon, lat, seed=14)
    clean = field_values(grid)
    holed = clean.copy()
    holed[1:4, 6:9, 10:14] = np.nan
    holed[:, :, 30] = np.nan  # a whole missing column line
    field, layout, atlas = setup(grid, holed)
    _, _, atlas_clean = setup(grid, clean)
    pts = random_points(np.random.default_rng(15), 80000)
    value, _, ok = layout.shade(atlas, pts)
    value_c, _, ok_c = layout.shade(atlas_clean, pts)
    ref = reference(field, pts)
    ref_clean = reference(CurvilinearField.from_grid(grid, {"value": clean}), pts)
    touches = np.isnan(ref) & np.isfinite(ref_clean)  # cells with a missing corner
    assert touches.sum() > 2000
    assert not ok[touches].any(), f"{ok[touches].sum()} points of cells with a NaN corner shaded"
    # Elsewhere the value is the one of the field without holes, bit for bit.
    rest = np.isfinite(ref)
    np.testing.assert_array_equal(ok[rest], ok_c[rest])
    np.testing.assert_array_equal(value[rest & ok], value_c[rest & ok])
    np.testing.assert_allclose(value[rest & ok], ref[rest & ok], atol=TOL)


def test_nan_corner_with_a_tiny_weight_still_hides_the_cell():
    """A point very close to a present vertex of a cell whose far corner is
    missing: the reference gives NaN (no opacity) for the whole cell."""
    lon = np.arange(36) * 10.0
    lat = -85.0 + 10.0 * np.arange(18)
    nk = 4
    h = np.linspace(0.0, 12000.0, nk)[:, None, None] + np.zeros((nk, 18, 36))
    grid = GlobeGrid(lon, lat, h)
    values = np.full(grid.shape, 0.9, np.float32)
    values[:, 10, 11] = np.nan  # vertex at lon 110, lat 15
    field, layout, atlas = setup(grid, values)
    # Inside the cell lon 100..110, lat 5..15, near its (100, 5) corner.
    pts = lonlat_to_xyz(np.array([100.05, 100.01, 100.1]), np.array([5.05, 5.01, 5.1]), globe_radius(6000.0))
    assert np.isnan(reference(field, pts)).all()
    _, _, ok = layout.shade(atlas, pts)
    assert not ok.any(), "opacity 0.9-field shaded in a cell with a missing corner"


def test_vertical_range_top_ground_and_below():
    grid = flat_grid()
    values = field_values(grid)
    field, layout, atlas = setup(grid, values)
    rng = np.random.default_rng(16)
    n = 3000
    lo, la = rng.uniform(-180, 180, n), rng.uniform(-80, 80, n)

    def at(height):
        return lonlat_to_xyz(lo, la, globe_radius(np.full(n, height)))

    below = 1000.0
    for height in (16010.0, 18000.0, -below - 10.0, -3000.0):
        assert not layout.shade(atlas, at(height), below=below)[2].any(), height
        assert np.isnan(reference(field, at(height), below)).all()
    # Between the ground and `below` under it: the lowest level's values.
    ground = reference(field, at(1e-3), 0.0)  # on level 0 (a millimetre up: round trip through the radius)
    assert np.isfinite(ground).all()
    for height in (-5.0, -500.0, -below + 10.0):
        value, _, ok = layout.shade(atlas, at(height), below=below)
        assert ok.all()
        np.testing.assert_allclose(value, ground, atol=TOL)
    # below=0: nothing under the ground.
    assert not layout.shade(atlas, at(-5.0), below=0.0)[2].any()


# --- support --------------------------------------------------------------------------------


def cloudy_points(field, rng, n):
    """Points clustered in cells with some non-zero opacity (plus their corners)."""
    pts = field.cell_corner_points()
    v = field.values["value"]
    k, j, i = np.nonzero(v[:-1, :-1, :-1] > 0.3)
    pick = rng.integers(0, k.size, n)
    f = rng.uniform(0, 1, (n, 3))
    # Trilinear mix of the cell's corners (near the curvilinear cell; the
    # reference decides where each point really lies).
    out = np.zeros((n, 3))
    for dk in (0, 1):
        for dj in (0, 1):
            for di in (0, 1):
                w = (f[:, 0] if dk else 1 - f[:, 0]) * (f[:, 1] if dj else 1
                                                        - f[:, 1]) * (f[:, 2] if di else 1 - f[:, 2])
                out += w[:, None] * pts[k[pick] + dk, j[pick] + dj, i[pick] + di]
    return out


@pytest.mark.parametrize("size", [0.02, 0.01])
def test_support_covers_every_cloudy_point(size):
    grid = terrain_grid(np.arange(36) * 10.0, -85.0 + 10.0 * np.arange(18), seed=17)
    values = field_values(grid)
    ev = exact_volume(grid, values, TF, support_size=size)
    field = CurvilinearField.from_grid(grid, {"value": values})
    rng = np.random.default_rng(18)
    pts = np.concatenate([random_points(rng, 40000), cloudy_points(field, rng, 40000)])
    a = np.nan_to_num(TF(reference(field, pts, ev.below)))
    assert (a > 0).sum() > 20000
    assert ev.in_support(pts[a > 0]).all()
    # The emulated shader agrees with the reference, support included.
    s = ev.sample(pts)
    a32 = np.where(np.isfinite(s), tf_eval32(TF, s), 0.0)
    np.testing.assert_allclose(a32, a, atol=2.5 * TOL)


def test_support_of_the_demo_covers_every_cloudy_point():
    from nephele.core.climate.readers import open_dataset

    ds = open_dataset("demo:small")
    values = ds.read("cloud", 10)
    ev = exact_volume(ds.grid, values, TF, support_size=0.02)
    field = CurvilinearField.from_grid(ds.grid, {"value": values})
    rng = np.random.default_rng(19)
    pts = np.concatenate([random_points(rng, 40000, h=(-1500, 21000)), cloudy_points(field, rng, 40000)])
    a = np.nan_to_num(TF(reference(field, pts, ev.below)))
    assert (a > 0).sum() > 10000
    assert ev.in_support(pts[a > 0]).all()


def test_rotated_pole_grid_is_shaded_in_its_frame_and_lands_at_its_true_place():
    # The UM file's pole (37.5 N, 177.5 E) on a regional grid around grid (0, 0):
    # the reference locates scene points through the rotation itself.
    from nephele.core.climate.grid import rotated_pole_matrix

    base = terrain_grid(np.linspace(-20.0, 20.0, 21), np.linspace(-15.0, 15.0, 16), seed=23)
    R = rotated_pole_matrix(177.5, 37.5)
    grid = GlobeGrid(base.lon, base.lat, base.height, rotation=R)
    values = field_values(grid)
    ev = exact_volume(grid, values, TF, support_size=0.01)
    np.testing.assert_array_equal(ev.rotation, R)
    field = CurvilinearField.from_grid(grid, {"value": values})
    rng = np.random.default_rng(24)
    # Points over the true region (grid points turned by R) and around it.
    local = np.concatenate([random_points(rng, 30000, (-25, 25), (-20, 20)), cloudy_points(field, rng, 30000) @ R])
    pts = local @ R.T
    ref = reference(field, pts, ev.below)
    a = np.nan_to_num(TF(ref))
    assert (a > 0).sum() > 10000
    assert ev.in_support(pts[a > 0]).all()
    s = ev.sample(pts)
    a32 = np.where(np.isfinite(s), tf_eval32(TF, s), 0.0)
    np.testing.assert_allclose(a32, a, atol=2.5 * TOL)
    # Shaded at the grid's own coordinates, the field would be somewhere else entirely.
    assert np.isfinite(ev.sample(local)).mean() < 0.05 < np.isfinite(s).mean()


def test_um_rotated_pole_file_exact_volume_lies_over_wales():
    pytest.importorskip("xarray")
    from pathlib import Path

    from nephele.core.climate.grid import xyz_to_lonlat
    from nephele.core.climate.readers import open_dataset

    ds = open_dataset(Path(__file__).resolve().parents[2] / "data" / "um_hybrid_height.nc")
    values = ds.read("air_potential_temperature", 0)
    tf = TransferFunction.ramp(float(np.percentile(values, 50)), float(values.max()))
    ev = exact_volume(ds.grid, values, tf, support_size=0.0005)
    assert not ev.empty and ev.rotation is not None
    centres = ((ev.support.astype(np.float64) + 0.5) * ev.support_size) @ ev.rotation.T  # object → scene
    lon, lat, _ = xyz_to_lonlat(centres)
    assert 51.5 < lat.mean() < 53.5 and -4.5 < lon.mean() < -2.0, (lon.mean(), lat.mean())
    field = CurvilinearField.from_grid(ds.grid, {"value": values})
    pts = cloudy_points(field, np.random.default_rng(25), 20000)
    a = np.nan_to_num(tf(reference(field, pts, ev.below)))
    assert (a > 0).sum() > 2000 and ev.in_support(pts[a > 0]).all()


def test_empty_when_threshold_above_the_maximum():
    grid = terrain_grid(np.arange(36) * 10.0, -85.0 + 10.0 * np.arange(18), seed=20)
    values = field_values(grid)
    tf = TransferFunction.ramp(float(values.max()) + 0.01, float(values.max()) + 0.5)
    ev = exact_volume(grid, values, tf)
    assert ev.empty and ev.support.shape == (0, 3)
    pts = random_points(np.random.default_rng(21), 1000)
    assert not ev.in_support(pts).any()
    assert np.isnan(ev.sample(pts)).all()
    arrays = ev.arrays()
    assert arrays["support"].shape == (0, 3) and arrays["values"].dtype == np.float32


def test_support_grows_with_the_cloudy_volume():
    grid = terrain_grid(np.arange(36) * 10.0, -85.0 + 10.0 * np.arange(18), seed=22)
    values = field_values(grid)
    layout = atlas_layout(grid)
    counts, cloudy = [], []  # support voxels, fraction of grid points above the threshold
    for thr in (0.1, 0.3, 0.5, 0.7, 0.85):
        ev = exact_volume(grid, values, TransferFunction.ramp(thr, 1.0), support_size=0.01, layout=layout)
        counts.append(ev.support.shape[0])
        cloudy.append(np.mean(values > thr))
    assert all(a > b for a, b in zip(cloudy, cloudy[1:]))
    assert all(a >= b for a, b in zip(counts, counts[1:])), counts
    assert counts[-1] < 0.3 * counts[0], counts


# --- transfer function ----------------------------------------------------------------------


@pytest.mark.parametrize("points", [
    ((0.3, 0.0), (0.7, 1.0)),
    ((0.1, 0.0), (0.3, 2.0), (0.45, 0.2), (0.7, 0.2), (0.9, 3.0)),
    ((0.2, 0.0), (0.5, 0.0), (0.5, 1.0), (0.8, 0.4)),  # a step
    ((0.2, 0.5), (0.6, 1.0)),  # non-zero beyond both ends
    ((0.4, 0.7),),  # one point: constant
])
def test_tf_eval32_is_the_transfer_function(points):
    tf = TransferFunction(points=points)
    rng = np.random.default_rng(23)
    s = np.concatenate([rng.uniform(-1.0, 2.0, 20000), [-50.0, 50.0]])
    s = s[np.abs(s[:, None] - np.asarray([p[0] for p in points])[None]).min(axis=1) > 1e-6]
    np.testing.assert_allclose(tf_eval32(tf, s), tf(s), atol=5e-7 * max(1.0, max(p[1] for p in points)), rtol=0)
    if points[0][1] == 0.0:  # NaN below every point (the shader masks missing values before it)
        assert tf_eval32(tf, [np.nan])[0] == 0.0
    # Constant beyond the end points.
    assert tf_eval32(tf, [-1e6])[0] == pytest.approx(points[0][1])
    assert tf_eval32(tf, [1e6])[0] == pytest.approx(points[-1][1])


def test_tf_eval32_at_a_step_takes_the_upper_value():
    """At exactly the step value ``TransferFunction`` (np.interp) gives the upper opacity."""
    tf = TransferFunction(points=((0.2, 0.0), (0.5, 0.0), (0.5, 1.0), (0.8, 0.4)))
    assert tf(0.5) == 1.0
    assert tf_eval32(tf, [0.5])[0] == pytest.approx(1.0)


# --- frame parameters and the task ----------------------------------------------------------

SOURCE = "test:volume-atlas"


def small_dataset():
    lon = np.arange(24) * 15.0
    lat = -82.5 + 15.0 * np.arange(12)
    grid = terrain_grid(lon, lat, nk=5, seed=24)
    nt = 3
    v = np.stack([field_values(grid) * (0.8 + 0.1 * t) for t in range(nt)])
    ds = ArrayDataset(grid, hourly("2000-01-01", nt), {"cloud": v, "temperature": 230 + 40 * v})
    register_source(SOURCE, ds)
    return ds


def test_frame_params_exact_mode():
    small_dataset()
    obj = {"source": SOURCE, "var": "cloud", "tf": TF.to_dict(), "mode": EXACT, "support_size": 0.02}
    p = frame_params(obj, 2)
    assert p["mode"] == EXACT and p["support_size"] == 0.02 and p["below"] == DEFAULT_BELOW
    assert "voxel_size" not in p
    p2 = frame_params({**obj, "below": 250.0}, 2)
    assert p2["below"] == 250.0
    with pytest.raises(DataError):
        frame_params({**obj, "mode": "splats"}, 2)


def test_volume_task_exact_mode_arrays():
    ds = small_dataset()
    obj = {"source": SOURCE, "var": "cloud", "tf": TF.to_dict(), "mode": EXACT, "support_size": 0.02,
           "frame_start": 1, "hours_per_frame": 0.5}
    params = frame_params(obj, 4)  # 1.5 h: halfway between steps 1 and 2
    out = tasks.run("volume", params)
    assert {"values", "support", "support_size", "below", "value_max"} <= set(out)
    values = 0.5 * (ds.read("cloud", 1) + ds.read("cloud", 2))
    assert float(out["value_max"]) == pytest.approx(float(values.max()), rel=1e-6)
    assert float(out["support_size"]) == 0.02 and float(out["below"]) == DEFAULT_BELOW
    ev = exact_volume(ds.grid, values, TF, support_size=0.02)
    np.testing.assert_allclose(out["values"], ev.values, atol=1e-6)
    def rows(a):
        a = np.asarray(a, np.int64)
        return a[np.lexsort(a.T[::-1])]

    np.testing.assert_array_equal(rows(out["support"]), rows(ev.support))
    # Plain arrays only: a cache can store them without pickle.
    for a in out.values():
        assert np.asarray(a).dtype != object
    # The atlas rows hold the data's values (tile of level 2, first data row, first column).
    layout = atlas_layout(ds.grid)
    tile = out["values"].reshape(layout.nk, layout.tile, layout.width, 4)
    field = CurvilinearField.from_grid(ds.grid, {"value": values})
    np.testing.assert_allclose(tile[2, 1:-1, :, 0], field.values["value"][2][:, :-1], atol=1e-6)


# --- curvilinear grids (2-D longitude/latitude) ---------------------------------------------


def curvilinear_grid(kind, ni=40, nj=30, nk=6):
    """Sheared, curved columns over Africa and Europe, or a cap about the North Pole (the pole inside);
    terrain-following levels as :func:`terrain_grid`."""
    if kind == "sheared":
        P, L = np.meshgrid(np.linspace(-10.0, 50.0, nj), np.linspace(-25.0, 65.0, ni), indexing="ij")
        L = L + 0.3 * (P - 20.0) + 0.004 * (P - 20.0) ** 2
    else:  # a polar stereographic-like cap, 25 degrees from the pole at the corners
        x, y = np.meshgrid(np.linspace(-1.0, 1.0, ni), np.linspace(-1.0, 1.0, nj) * 0.8)
        L, P = np.rad2deg(np.arctan2(x, -y)), 90.0 - 17.0 * np.hypot(x, y)
    base = terrain_grid(np.arange(ni, dtype=float), np.arange(nj, dtype=float), nk=nk, seed=31)
    ground = np.maximum(0.0, 2500.0 * np.sin(np.deg2rad(2 * L)) * np.cos(np.deg2rad(P)) ** 2)
    h = ground[None] + (base.height - base.height[:1]) * (16000.0 - ground[None]) / 16000.0
    return GlobeGrid(base.lon, base.lat, h, lon2d=L, lat2d=P)


@pytest.mark.parametrize("kind", ["sheared", "polar"])
def test_curvilinear_grid_through_its_index_map_matches_the_column_reference(kind):
    # The shader locates a point's column by the index map (bilinear texels, 4 per cell); the reference by
    # ColumnLocator in float64.  Within the grid they differ by the map's own error only; at the edge a
    # sliver of points changes sides.
    grid = curvilinear_grid(kind)
    L, P = grid.lon2d, grid.lat2d
    values = analytic(L[None], P[None], grid.height)
    ev = exact_volume(grid, values, TF, support_size=0.01)
    assert ev.layout.index is not None and ev.rotation is None
    field = CurvilinearField.from_grid(grid, {"value": values})
    rng = np.random.default_rng(32)
    box = (dict(lon=(-60.0, 110.0), lat=(-25.0, 65.0)) if kind == "sheared"
           else dict(lon=(-180.0, 180.0), lat=(55.0, 90.0)))
    pts = np.concatenate([random_points(rng, 100000, **box), cloudy_points(field, rng, 50000)])
    ref = reference(field, pts, ev.below)
    value, _, ok = ev.layout.shade(ev.layout.values_atlas(field), pts, below=ev.below)
    rok = np.isfinite(ref)
    assert rok.sum() > 50000 and (~rok).sum() > 10000
    assert np.mean(ok != rok) < 1e-3  # measured 5e-5 (sheared), 7e-6 (polar)
    both = ok & rok
    err = np.abs(value[both] - ref[both])
    print(f"{kind}: inside disagree {np.mean(ok != rok):.1e}, value max {err.max():.1e}, p99.9 "
          f"{np.percentile(err, 99.9):.1e}")
    # Measured max 5.8e-4 / p99.9 1.4e-4 (sheared), 4.4e-5 / 1.7e-5 (polar); the field varies by ~0.1 per cell.
    assert err.max() < 2e-3 and np.percentile(err, 99.9) < 3e-4
    # The index map itself: fractional column indices against ColumnLocator, inside the grid.
    inside = pts[rok]
    ci, cj, front = ev.layout.index.lookup(inside.astype(np.float32))
    fi, fj = field.columns(inside)
    # Bilinear texels on curving columns: measured 0.020 cells (sheared, largest at the edge cells), less on the cap.
    assert front.all() and max(np.abs(ci - fi).max(), np.abs(cj - fj).max()) < 0.03
    # The support holds every point the reference finds cloudy.
    a = np.nan_to_num(TF(ref))
    assert (a > 0).sum() > 10000 and ev.in_support(pts[a > 0]).all()


def test_curvilinear_index_map_is_empty_behind_the_globe():
    grid = curvilinear_grid("sheared")
    layout = atlas_layout(grid)
    centre = lonlat_to_xyz(np.array([20.0]), np.array([20.0]))
    _, _, front = layout.index.lookup(np.concatenate([centre, -centre]).astype(np.float32))
    assert front.tolist() == [True, False]
    values = analytic(grid.lon2d[None], grid.lat2d[None], grid.height)
    ev = exact_volume(grid, values, TF, support_size=0.01)
    assert not np.isfinite(ev.sample(-centre * globe_radius(5000.0))).any()
