"""The fast parts of the streamed advection: padded stencils, the shared gather of restart copies,
the band's extension, dilation across the poles and reading the wind at grid vertices."""

import numpy as np
import pytest
from scipy import ndimage

from nephele.core.climate.grid import GlobeGrid, lonlat_to_xyz
from nephele.core.climate.synthetic import demo_dataset
from nephele.core.flow import _grid_index, advect, flows


def sphere_grid(ni=16, nj=8, nk=3, periodic=True):
    lon = np.arange(ni) * (360.0 / ni) if periodic else np.linspace(-40.0, 40.0, ni)
    lat = -90 + (np.arange(nj) + 0.5) * 180.0 / nj
    h = np.linspace(0, 10_000.0, nk)[:, None, None] + np.zeros((nk, nj, ni))
    return GlobeGrid(lon, lat, h)


def random_points(n, rng, lat_max=90.0, lon=(-180.0, 180.0)):
    lat = np.rad2deg(np.arcsin(rng.uniform(-1, 1, n) * np.sin(np.deg2rad(lat_max))))
    return lonlat_to_xyz(rng.uniform(*lon, n), lat)


@pytest.mark.parametrize("periodic", [True, False])
def test_padded_field_layout(periodic):
    g = sphere_grid(periodic=periodic)
    ix = _grid_index._GridIndex(g, pad=2)
    nk, nj, ni = g.shape
    f = np.random.default_rng(0).normal(size=g.shape + (2,)).astype(np.float32)
    p = ix.padded(f)
    assert p.shape == (nk, nj + 2 * ix.pad, ni + 3, 2)
    np.testing.assert_array_equal(p.reshape(-1, 2)[ix.rows(np.arange(f[..., 0].size))], f.reshape(-1, 2))
    inner = p[:, ix.pad : ix.pad + nj]
    if periodic:
        np.testing.assert_array_equal(inner[:, :, 0], f[:, :, -1])
        np.testing.assert_array_equal(inner[:, :, ni + 1 :], f[:, :, :2])
        np.testing.assert_array_equal(p[:, 1, 1 : ni + 1], np.roll(f[:, 0], ni // 2, axis=1))  # across the south pole
        np.testing.assert_array_equal(p[:, -1, 1 : ni + 1], np.roll(f[:, -2], ni // 2, axis=1))
    else:
        assert ix.pad == 0
        np.testing.assert_array_equal(inner[:, :, 0], f[:, :, 0])
        np.testing.assert_array_equal(inner[:, :, ni + 1], f[:, :, -1])
        np.testing.assert_array_equal(inner[:, :, ni + 2], f[:, :, -1])


def test_stencils_reproduce_linear_fields_and_wrap_the_seam():
    g = sphere_grid(ni=32, nj=16, nk=4)
    ix = _grid_index._GridIndex(g, pad=2)
    nk, nj, ni = g.shape
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    lin = (3.0 + 0.25 * i - 0.5 * j + 2.0 * k)[..., None]
    rng = np.random.default_rng(1)
    x = random_points(500, rng, lat_max=60.0, lon=(15.0, 320.0))  # stencils clear of the seam and the poles
    s = rng.uniform(0, nk - 1, 500)
    fk, fj, fi = ix.fractional(x, s)
    want = 3.0 + 0.25 * fi - 0.5 * (fj - ix.pad) + 2.0 * fk
    # Both reproduce a linear function of the indices, to float32 rounding of the field's scale (a
    # value near zero keeps the absolute error of its larger neighbours: 2.1e-6 at 0.09 on NumPy 1.26).
    atol = 4 * np.finfo(np.float32).eps * np.abs(lin).max()
    for gather in (ix.trilinear, ix.cubic):
        np.testing.assert_allclose(gather(ix.padded(lin.astype(np.float32)), fk, fj, fi)[:, 0], want, rtol=1e-5,
                                   atol=atol)
    # Across the seam: rolling the field by r columns is the same as moving the points by r columns.
    smooth = np.cos(np.deg2rad(g.lon))[None, None, :] * np.sin(np.deg2rad(g.lat))[None, :, None] + 0 * lin[..., 0]
    lon_seam = rng.uniform(-6.0, 6.0, 200)
    lat_seam = rng.uniform(-60.0, 60.0, 200)
    r = 5
    a = ix.cubic(
        ix.padded(smooth[..., None].astype(np.float32)), *ix.fractional(lonlat_to_xyz(lon_seam, lat_seam), np.ones(200))
    )
    b = ix.cubic(ix.padded(np.roll(smooth, r, axis=2)[..., None].astype(np.float32)),
                 *ix.fractional(lonlat_to_xyz(lon_seam + r * 360.0 / ni, lat_seam), np.ones(200)))
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_stencils_cross_the_pole_and_propagate_nan():
    g = sphere_grid(ni=64, nj=32, nk=2)
    ix = _grid_index._GridIndex(g, pad=2)
    f = advect.grid_vertices(g)[: 32 * 64, 0].reshape(g.shape[1:])  # x of the unit vector: smooth over the poles
    field = np.broadcast_to(f, g.shape)[..., None].astype(np.float32)
    rng = np.random.default_rng(2)
    lat = rng.uniform(86.0, 90.0, 300) * rng.choice([-1, 1], 300)  # beyond the last rows, both poles
    x = lonlat_to_xyz(rng.uniform(-180, 180, 300), lat)
    got = ix.cubic(ix.padded(field), *ix.fractional(x, np.zeros(300)))[:, 0]
    np.testing.assert_allclose(got, x[:, 0], atol=2e-3)  # 5.6° cells: Catmull-Rom error
    holed = field.copy()
    holed[0, 10, 20] = np.nan
    xh = lonlat_to_xyz(g.lon[20] + 1.0, g.lat[10] + 1.0)[None]
    assert np.isnan(ix.cubic(ix.padded(holed), *ix.fractional(xh, np.zeros(1)))).all()


def test_one_gather_of_stacked_maps_equals_separate_gathers():
    g = sphere_grid(ni=32, nj=16, nk=4)
    ix = _grid_index._GridIndex(g, pad=2)
    rng = np.random.default_rng(3)
    a, b = (rng.normal(size=g.shape + (4,)).astype(np.float32) for _ in range(2))
    fr = ix.fractional(random_points(1000, rng), rng.uniform(0, 3, 1000))
    both = ix.cubic(ix.padded(np.concatenate([a, b], axis=-1)), *fr)
    np.testing.assert_allclose(both[:, :4], ix.cubic(ix.padded(a), *fr), atol=1e-6)
    np.testing.assert_allclose(both[:, 4:], ix.cubic(ix.padded(b), *fr), atol=1e-6)


def test_restart_copies_sharing_a_gather_equal_a_single_stream():
    # While both restart copies start at frame 0 they hold the same map as a lone composed stream.
    flow = flows.SolidBodyRotation(np.pi / 2 - 0.05)
    grid = flows.sample_grid(64, 32)
    wind = advect.WindField(flows.FlowDataset(flow, hours=9, grid=grid))
    fh = np.arange(9.0)
    idx = np.arange(0, 64 * 32, 3)
    restart = advect.RestartTrace(wind, fh, grid, period=16)
    single = advect.ComposedTrace(wind, fh, grid)
    for n in range(8):
        cs = restart.copies(n, idx)
        c = single.copies(n, idx)[0]
    for cp in cs:
        np.testing.assert_allclose(cp.xyz, c.xyz, atol=1e-6)
        np.testing.assert_allclose(cp.s, c.s, atol=1e-6)
    assert advect.great_circle_km(c.xyz, flow.exact_start(advect.grid_vertices(grid, idx), 7.0)).max() < 30


def test_extension_takes_a_nearest_stored_value_as_the_3d_distance_transform():
    rng = np.random.default_rng(4)
    shape = (5, 40, 60)
    stored = ndimage.binary_dilation(rng.random(shape) < 0.004, iterations=2) & (rng.random(shape) < 0.9)
    m = np.full(shape + (8,), np.nan, dtype=np.float32)
    ids = np.arange(stored.size, dtype=np.float32).reshape(shape)
    m[stored, 0] = ids[stored]  # each stored vertex holds its own index: the filled value names its source
    m[stored, 1:] = 1.0
    m[stored, 4] = ids[stored]
    m[stored, 5:] = 2.0
    cells = 6
    out = advect._extend(m.copy(), cells)
    dist = ndimage.distance_transform_edt(~stored, sampling=(advect.LEVEL_CELLS, 1.0, 1.0))
    filled = ~np.isnan(out[..., 0])
    np.testing.assert_array_equal(filled, stored | (dist <= cells))
    np.testing.assert_array_equal(out[stored], m[stored])
    src = out[filled & ~stored, 0].astype(np.int64)
    k, j, i = np.unravel_index(src, shape)
    k0, j0, i0 = np.nonzero(filled & ~stored)
    d = np.sqrt((advect.LEVEL_CELLS * (k - k0)) ** 2 + (j - j0) ** 2 + (i - i0) ** 2)
    np.testing.assert_allclose(d, dist[filled & ~stored], atol=1e-9)  # a nearest stored vertex
    np.testing.assert_array_equal(out[filled & ~stored, 4], out[filled & ~stored, 0])  # both copies from it
    assert np.all(out[filled, 5:] == 2.0)


def test_extension_keeps_each_copys_own_values():
    m = np.full((2, 10, 12, 8), np.nan, dtype=np.float32)
    m[:, 4:6, 4:6, :4] = 1.0
    m[:, 4:6, 4:6, 4:] = 2.0
    m[0, 4, 4, 4:] = np.nan  # not stored for copy b only: filled from a neighbour, copy a keeps its own
    out = advect._extend(m, 3)
    assert out[0, 4, 4, 0] == 1.0 and out[0, 4, 4, 4] == 2.0
    assert out[0, 2, 4, 0] == 1.0 and np.isnan(out[0, 0, 0, 0])  # 2 cells away is filled, 5.7 is not
    only_nan = np.full((1, 3, 3, 4), np.nan, dtype=np.float32)
    assert np.isnan(advect._extend(only_nan, 2)).all()


def test_dilate_across_the_poles():
    mask = np.zeros((3, 8, 16), dtype=bool)
    mask[1, 7, 2] = True  # last row, next to the north pole
    one = advect.dilate(mask, 1, periodic_lon=True, poles=True)
    assert one[1, 7, 10] and one[0, 7, 10] and one[2, 7, 10]  # half way round, and a level up and down
    assert not advect.dilate(mask, 1, periodic_lon=True)[1, 7, 10]
    two = advect.dilate(mask, 2, periodic_lon=True, poles=True)
    assert two[1, 6, 10] and two[1, 7, 9] and two[1, 7, 11] and not two[1, 5, 10]
    south = np.zeros_like(mask)
    south[0, 0, 15] = True
    assert advect.dilate(south, 1, periodic_lon=True, poles=True)[0, 0, 7]
    # without the option the mask grows exactly as before: a diamond of `cells` in lat/lon, one level
    plain = advect.dilate(mask, 3, periodic_lon=True)
    k, j, i = np.nonzero(plain)
    assert plain.sum() == 3 * (7 + 5 + 3 + 1) and np.all(
        np.abs(j - 7) + np.minimum(np.abs(i - 2), 16 - np.abs(i - 2)) <= 3
    )


def test_wind_read_at_vertices_equals_the_interpolated_wind():
    ds = demo_dataset("small")
    wind = advect.WindField(ds)
    g = ds.grid
    idx = np.arange(0, int(np.prod(g.shape)), 7)
    xyz, s = advect.grid_vertices(g, idx), advect.vertex_levels(g, idx)
    for hours in (3.0, 3.4):  # at a step, and between steps
        v1, d1 = wind.vertex_velocity(hours, idx, xyz)
        v2, d2 = wind.velocity(hours, xyz, s)
        np.testing.assert_allclose(v1, v2, atol=1e-6 * np.abs(v2).max())
        np.testing.assert_allclose(d1, d2, atol=1e-6 * max(np.abs(d2).max(), 1e-9))
    x1, s1 = advect.trace(wind, xyz, s, 5.0, 2.0, vertices=idx)
    x2, s2 = advect.trace(wind, xyz, s, 5.0, 2.0)
    assert advect.great_circle_km(x1, x2).max() < 1e-3
    np.testing.assert_allclose(s1, s2, atol=1e-6)


def test_small_and_large_point_sets_blend_steps_alike():
    ds = demo_dataset("small")
    wind = advect.WindField(ds)
    rng = np.random.default_rng(5)
    x = random_points(20_000, rng)
    s = rng.uniform(0, ds.grid.shape[0] - 1, 20_000)
    big, dbig = wind.velocity(6.3, x, s)  # one blended field
    small, dsmall = wind.velocity(6.3, x[:50], s[:50])  # both steps at the points, then blended
    np.testing.assert_allclose(small, big[:50], atol=1e-6 * np.abs(big).max())
    np.testing.assert_allclose(dsmall, dbig[:50], atol=1e-6 * np.abs(dbig).max())


def test_demo_band_needs_no_fallback_traces_near_the_poles():
    ds = demo_dataset("small")
    st = advect.RestartTrace(advect.WindField(ds, vertical="levels"), ds.hours, ds.grid, period=8, cfl=2.0)
    for n in range(1, 7):
        idx = advect.active_vertices(ds.read("cloud", n), 0.15, True)
        cs = st.copies(n, idx)
    assert st.stream.fallbacks == 0
    k = np.unravel_index(idx, ds.grid.shape)[0]
    jet, storm = ds.level_factors(k)
    exact = np.stack(ds.inverse(tuple(advect.grid_vertices(ds.grid, idx).T), ds.hours[6] * 3600.0, jet, storm), axis=1)
    assert advect.great_circle_km(cs[0].xyz, exact).max() < 60  # 625 km cells
