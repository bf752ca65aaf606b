"""Curvilinear field evaluation and sparse resampling against analytic truth."""

import numpy as np
import pytest

from nephele.core.climate.grid import GlobeGrid, globe_radius, lonlat_to_xyz
from nephele.core.errors import DataError
from nephele.core.volume.exact_ray import opacity, reference_optical_depth, volume_optical_depth
from nephele.core.volume.sparse import ALTITUDE, CurvilinearField, SparseVolume, resample
from nephele.core.volume.transfer import TransferFunction


def grid(ni=40, nj=20, nk=8, top=16000.0, terrain=True):
    lon = np.arange(ni) * 360.0 / ni
    lat = -90 + (np.arange(nj) + 0.5) * 180.0 / nj
    L, P = np.meshgrid(np.deg2rad(lon), np.deg2rad(lat))
    ter = np.maximum(0.0, 3000.0 * np.sin(2 * L) * np.cos(P) ** 2) if terrain else np.zeros_like(L)
    s = np.linspace(0.0, 1.0, nk) ** 1.3
    h = ter[None] + s[:, None, None] * (top - ter[None])
    return GlobeGrid(lon, lat, h, ter)


def points_at(lon, lat, h, exaggeration=30.0):
    return lonlat_to_xyz(lon, lat, globe_radius(h, 1.0, exaggeration))


def smooth_cloud(g):
    lon = np.deg2rad(g.lon)[None, None, :]
    lat = np.deg2rad(g.lat)[None, :, None]
    horiz = 0.5 + 0.5 * np.sin(2 * lon + np.sin(3 * lat)) * np.cos(lat)
    return (horiz * np.exp(-(((g.height - 6000.0) / 4000.0) ** 2))).astype(np.float32)


def test_trilinear_in_index_space_is_reproduced_exactly():
    # Flat levels, uniform spacing: a field linear in the three indices is
    # reproduced exactly, and the indices follow from lon, lat, h directly.
    g = grid(terrain=False)
    nk, nj, ni = g.shape
    g = GlobeGrid(g.lon, g.lat, np.linspace(0, 14000.0, nk)[:, None, None] + np.zeros(g.shape))
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    v = 2.0 * k + 3.0 * j + 0.5 * i
    field = CurvilinearField.from_grid(g, {"v": v})
    rng = np.random.default_rng(1)
    lon = rng.uniform(g.lon[0], g.lon[-1], 500)
    lat = rng.uniform(g.lat[0], g.lat[-1], 500)
    h = rng.uniform(0, 14000.0, 500)
    expect = 2.0 * h / 2000.0 + 3.0 * (lat - g.lat[0]) / 9.0 + 0.5 * (lon - g.lon[0]) / 9.0
    np.testing.assert_allclose(field.sample("v", points_at(lon, lat, h)), expect, atol=1e-9)


def test_terrain_following_levels_are_inverted_exactly():
    # The field "height of the vertex" interpolates to the point's own height.
    g = grid()
    field = CurvilinearField.from_grid(g, {"h": g.height})
    rng = np.random.default_rng(2)
    lon = rng.uniform(-180, 180, 2000)
    lat = rng.uniform(-89.9, 89.9, 2000)
    lam, phi = np.deg2rad(lon), np.deg2rad(lat)
    ground = np.maximum(0.0, 3000.0 * np.sin(2 * lam) * np.cos(phi) ** 2)
    h = rng.uniform(ground + 3500.0, 15000.0)  # well above the bilinear terrain
    np.testing.assert_allclose(field.sample("h", points_at(lon, lat, h)), h, rtol=1e-7, atol=1e-4)
    # Below the lowest level (under the terrain) and above the top: missing.
    assert np.isnan(field.sample("h", points_at([30.0, 30.0], [10.0, 10.0], [-100.0, 16001.0]))).all()


def test_seam_and_poles():
    g = grid(terrain=False)
    nk, nj, ni = g.shape
    v = np.broadcast_to(np.arange(ni, dtype=float), g.shape).copy()
    field = CurvilinearField.from_grid(g, {"v": v})
    # Between the last column (351°) and 360°: from ni-1 down to column 0's 0.
    lon = g.lon[-1] + np.array([0.0, 2.25, 4.5, 9.0])
    got = field.sample("v", points_at(lon, 0.0, 5000.0))
    np.testing.assert_allclose(got, (ni - 1) * (1 - np.array([0.0, 0.25, 0.5, 1.0])), atol=1e-9)
    # A field constant along each latitude row: the pole holds the last row's
    # value, the same from every longitude, and the cap interpolates to it.
    w = np.broadcast_to(np.arange(nj, dtype=float)[None, :, None], g.shape).copy()
    field = CurvilinearField.from_grid(g, {"w": w})
    pole = field.sample("w", points_at(np.array([0.0, 77.0, -150.0]), 90.0, 5000.0))
    np.testing.assert_allclose(pole, nj - 1)
    assert field.sample("w", points_at(0.0, -90.0, 5000.0)) == pytest.approx(0.0)
    cap = field.sample("w", points_at(10.0, 89.0, 5000.0))
    assert cap == pytest.approx(nj - 1)


def test_nan_corners_make_missing_and_nan_regions_stay_empty():
    g = grid()
    c = smooth_cloud(g)
    c[:, 8:12, 5:10] = np.nan
    tf = TransferFunction.ramp(0.2, 1.0)
    vol = resample(g, c, tf, voxel_size=0.02)
    assert not vol.empty
    # Centres of all active voxels: none inside cells touching the NaN box.
    b, x, y, z = np.nonzero(vol.density > 0)
    idx = vol.blocks[b] * vol.block + np.stack([x, y, z], axis=1)
    p = idx * vol.voxel_size
    lon = np.mod(np.degrees(np.arctan2(p[:, 1], p[:, 0])), 360.0)
    lat = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    in_nan = (lat > g.lat[7]) & (lat < g.lat[12]) & (lon > g.lon[4]) & (lon < g.lon[10])
    assert in_nan.sum() == 0
    # The same cloud without NaN does fill that region.
    full = resample(g, smooth_cloud(g), tf, voxel_size=0.02)
    b, x, y, z = np.nonzero(full.density > 0)
    p = (full.blocks[b] * full.block + np.stack([x, y, z], axis=1)) * full.voxel_size
    lon = np.mod(np.degrees(np.arctan2(p[:, 1], p[:, 0])), 360.0)
    lat = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    assert ((lat > g.lat[8]) & (lat < g.lat[11]) & (lon > g.lon[5]) & (lon < g.lon[9])).sum() > 0


def test_sparse_blocks_are_exactly_the_nonzero_ones():
    g = grid(ni=32, nj=16, nk=6)
    c = smooth_cloud(g)
    tf = TransferFunction.ramp(0.4, 1.0)
    vs = 0.025
    vol = resample(g, c, tf, voxel_size=vs, color_name=ALTITUDE)
    # No block is all zero.
    assert (vol.density.reshape(vol.blocks.shape[0], -1).max(axis=1) > 0).all()
    # Brute force over every voxel of the globe's bounding cube: every
    # non-zero voxel is in the sparse volume with the same value.
    field = CurvilinearField.from_grid(g, {"v": c})
    n = int(np.ceil(1.05 / vs))
    ax = np.arange(-n, n + 1)
    idx = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
    r = np.linalg.norm(idx * vs, axis=1)
    idx = idx[(r > 0.9) & (r < 1.08)]
    # The resampler extends the lowest level's values 1.75 voxels under the terrain.
    flat, f, _, ok = field.locate(idx * vs, clamp_below=1.75 * vs * 6_371_000.0 / 30.0)
    dense = np.nan_to_num(tf(field.interpolate("v", flat, f, ok)), nan=0.0)
    got = vol.sample(idx * vs)  # voxel centres: the sample is the stored value
    np.testing.assert_allclose(got, dense, atol=1e-6)
    assert np.count_nonzero(dense) == vol.stats["active_voxels"]
    # The colour grid holds the altitude of each voxel.
    b, x, y, z = np.nonzero(vol.density > 0)
    p = (vol.blocks[b] * vol.block + np.stack([x, y, z], axis=1)) * vs
    alt = (np.linalg.norm(p, axis=1) - 1.0) * 6_371_000.0 / 30.0
    np.testing.assert_allclose(vol.color[b, x, y, z], alt, rtol=1e-5, atol=0.5)


def test_fine_voxels_over_steep_regional_terrain_miss_nothing():
    # The block pre-tests (column height ranges, the level table) must never
    # drop a voxel: brute force every voxel of a regional grid's bounding box.
    lon, lat = np.linspace(0.0, 16.0, 33), np.linspace(40.0, 56.0, 33)
    L, P = np.meshgrid(np.deg2rad(lon), np.deg2rad(lat))
    ter = np.maximum(0.0, 4000.0 * np.sin(9 * L) * np.sin(7 * P))
    s = np.linspace(0.0, 1.0, 9) ** 1.6
    g = GlobeGrid(lon, lat, ter[None] + s[:, None, None] * (14000.0 - ter[None]), ter)
    c = smooth_cloud(g) + 0.3 * (g.height < ter[None] + 2500.0)
    tf = TransferFunction.ramp(0.45, 0.9)
    vs = 0.004
    vol = resample(g, c, tf, voxel_size=vs)
    assert not vol.empty
    field = CurvilinearField.from_grid(g, {"v": c})
    p = g.points(dtype=np.float64).reshape(-1, 3)
    lo, hi = np.floor(p.min(axis=0) / vs) - 2, np.ceil(p.max(axis=0) / vs) + 2
    idx = np.stack(np.meshgrid(*(np.arange(a, b + 1) for a, b in zip(lo, hi)), indexing="ij"), axis=-1).reshape(-1, 3)
    r = np.linalg.norm(idx * vs, axis=1)
    idx = idx[(r > 0.995) & (r < 1.07)]
    flat, f, _, ok = field.locate(idx * vs, clamp_below=1.75 * vs * 6_371_000.0 / 30.0)
    dense = np.nan_to_num(tf(field.interpolate("v", flat, f, ok)), nan=0.0)
    np.testing.assert_allclose(vol.sample(idx * vs), dense, atol=1e-6)
    assert np.count_nonzero(dense) == vol.stats["active_voxels"]
    assert vol.stats["candidate_blocks"] < vol.stats["boxed_blocks"]  # the pre-test did act
    assert vol.stats["active_voxels"] > 5000


@pytest.mark.parametrize("lon0", [-180.0, 200.0, 350.0])
def test_longitude_origin_and_threads_do_not_change_the_volume(lon0):
    # The same globe field on a grid whose longitudes start elsewhere (rolled
    # columns) gives the same voxels, and threads give the same voxels as one.
    g = grid(ni=32, nj=16, nk=6)
    c = smooth_cloud(g)
    tf = TransferFunction.ramp(0.4, 1.0)
    ref = resample(g, c, tf, voxel_size=0.03, color_name=ALTITUDE, workers=1)
    d = np.mod(g.lon - lon0 + 180.0, 360.0) - 180.0
    shift = int(np.argmin(np.abs(d)))
    first = lon0 + d[shift]  # the column nearest lon0, written near lon0
    rolled = GlobeGrid(first + np.arange(g.lon.size) * 360.0 / g.lon.size, g.lat,
                       np.roll(g.height, -shift, axis=2), np.roll(g.terrain, -shift, axis=1))
    got = resample(rolled, np.roll(c, -shift, axis=2), tf, voxel_size=0.03, color_name=ALTITUDE, workers=2,
                   chunk_blocks=8)
    assert got.stats["active_voxels"] == ref.stats["active_voxels"] > 1000
    np.testing.assert_array_equal(got.blocks, ref.blocks)
    np.testing.assert_allclose(got.density, ref.density, atol=1e-5)
    np.testing.assert_allclose(got.color, ref.color, atol=1e-3)


def test_threshold_above_maximum_gives_empty_volume():
    g = grid()
    c = smooth_cloud(g)
    vol = resample(g, c, TransferFunction.ramp(float(c.max()) + 0.01, 2.0), voxel_size=0.01)
    assert vol.empty and vol.stats["candidate_cells"] == 0 and vol.stats["bytes"] == 0
    assert vol.bounds() is None
    assert (vol.sample(np.zeros((3, 3))) == 0).all()
    # Exactly at the maximum: still nothing (opacity is zero at the threshold).
    vol = resample(g, c, TransferFunction.ramp(float(c.max()), 2.0), voxel_size=0.01)
    assert vol.empty


def test_resampling_error_bounds_on_an_analytic_field():
    # Identity opacity: the voxel grid's trilinear interpolation of the
    # curvilinear field.  That field is piecewise trilinear, Lipschitz with
    # constant G (largest slope along a cell edge), so the error is at most
    # G * |voxel diagonal| / 2 anywhere and, away from the cell faces' kinks,
    # second order: the rms error falls about fourfold per halving.
    # A regional (non-periodic) grid keeps the whole-field volume small.
    lon, lat = np.linspace(0.0, 40.0, 33), np.linspace(0.0, 30.0, 25)
    g = GlobeGrid(lon, lat, np.linspace(0.0, 16000.0, 10)[:, None, None] + np.zeros((10, 25, 33)))
    c = smooth_cloud(g)
    tf = TransferFunction(points=((0.0, 0.0), (1.0, 1.0)))
    field = CurvilinearField.from_grid(g, {"v": c})
    p = g.points(dtype=np.float64)
    slopes = [np.abs(np.diff(c, axis=a)) / np.linalg.norm(np.diff(p, axis=a), axis=-1) for a in range(3)]
    G = max(float(s.max()) for s in slopes)
    rng = np.random.default_rng(3)
    lon, lat, h = rng.uniform(1, 39, 4000), rng.uniform(1, 29, 4000), rng.uniform(1000, 15000, 4000)
    pts = points_at(lon, lat, h)
    truth = field.sample("v", pts)
    assert np.isfinite(truth).all()
    errs = []
    for vs in (0.008, 0.004):
        vol = resample(g, c, tf, voxel_size=vs)
        e = vol.sample(pts) - truth
        assert np.abs(e).max() <= G * vs * np.sqrt(3) / 2
        errs.append(np.sqrt(np.mean(e**2)))
    assert errs[1] < 0.4 * errs[0]


def test_ray_opacity_error_small_against_exact_reference():
    g = grid(ni=64, nj=32, nk=12)
    c = smooth_cloud(g)
    tf = TransferFunction.ramp(0.6, 1.0)
    field = CurvilinearField.from_grid(g, {"v": c})
    rng = np.random.default_rng(4)
    n = 120
    eye = np.array([2.5, -1.0, 1.2])
    target = rng.normal(size=(n, 3))
    target *= (rng.uniform(0, 1, (n, 1)) ** 0.5) / np.linalg.norm(target, axis=1)[:, None]
    d = target - eye
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.broadcast_to(eye, d.shape)
    tau, t0, t1 = reference_optical_depth(field, "v", tf, o, d, step=0.0005)
    vol = resample(g, c, tf, voxel_size=0.003)
    tv = volume_optical_depth(vol, o, d, t0, t1, step=0.0005)
    a, b = opacity(tau, 100.0), opacity(tv, 100.0)
    assert a.max() > 0.5  # the rays do see cloud
    assert np.abs(a - b).max() < 0.02


def test_arrays_roundtrip_and_bad_input():
    g = grid()
    c = smooth_cloud(g)
    vol = resample(g, c, TransferFunction.ramp(0.3, 1.0), voxel_size=0.03, color_name=ALTITUDE)
    back = SparseVolume.from_arrays(vol.arrays(), color_name=ALTITUDE)
    np.testing.assert_array_equal(back.density, vol.density)
    np.testing.assert_array_equal(back.blocks, vol.blocks)
    with pytest.raises(DataError, match="voxel_size"):
        resample(g, c, TransferFunction.ramp(0.3, 1.0), voxel_size=0.0)
    with pytest.raises(DataError, match="shape"):
        resample(g, c[:-1], TransferFunction.ramp(0.3, 1.0))
    with pytest.raises(DataError, match="color_values"):
        resample(g, c, TransferFunction.ramp(0.3, 1.0), color_name="temperature")
    with pytest.raises(DataError, match="TransferFunction"):
        resample(g, c, [(0.3, 0.0)])


def test_planner_feeds_the_cache_the_blender_bake_reads(tmp_path, monkeypatch):
    from nephele.core.pipeline import tasks
    from nephele.core.pipeline.sources import open_source
    from nephele.core.volume import volume_task as vmod

    obj = {"kind": "volume", "source": "demo:small", "var": "cloud", "tf": TransferFunction.ramp(0.3, 1.0).to_dict(),
           "color_var": "altitude", "voxel_size": 0.02, "frame_start": 1, "hours_per_frame": 1.5, "frames": [1, 3]}
    assert tasks.plan(obj, 4) == [] and tasks.plan(obj, 0) == []
    (kind, params), = tasks.plan(obj, 3)
    assert kind == "volume" and params["hours"] == 3.0 and params["voxel_size"] == 0.02
    out = tasks.run_cached(kind, params, tmp_path)
    ds = open_source("demo:small")
    direct = resample(ds.grid, ds.read_at("cloud", 3.0), TransferFunction.ramp(0.3, 1.0), voxel_size=0.02,
                      color_name=ALTITUDE)
    assert not direct.empty
    np.testing.assert_array_equal(out["blocks"], direct.blocks)
    np.testing.assert_array_equal(out["density"], direct.density)
    # A second run is served from the cache: nothing is resampled.
    monkeypatch.setattr(vmod, "resample", lambda *a, **k: pytest.fail("resampled again"))
    again = tasks.run_cached(kind, params, tmp_path)
    np.testing.assert_array_equal(again["density"], direct.density)


def test_default_threads_follow_omp_num_threads(monkeypatch):
    from nephele.core.threads import default_threads

    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert default_threads() == 3
    monkeypatch.setenv("OMP_NUM_THREADS", "")
    assert 1 <= default_threads() <= 8
