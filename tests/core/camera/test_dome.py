"""Dome mappings and remapping against analytic geometry."""

import math

import numpy as np
import pytest

from nephele.core.camera import dome
from nephele.core.errors import DataError

CAMERAS = [
    dict(preset="domemaster"),
    dict(preset="domemaster", width=300, tilt=30.0),
    dict(preset="domemaster", width=256, lens="equisolid"),
    dict(preset="domemaster", width=200, fov=220.0),
    dict(preset="domemaster", width=200, fov=90.0, tilt=-15.0),
    dict(preset="domemaster", width=200, fov=360.0, lens="equisolid"),
    dict(preset="omnimax"),
    dict(preset="omnimax", width=128, height=94),
    dict(preset="omnimax", tilt=0.0, lens="equisolid"),
    dict(preset="omnimax", tilt=60.0, fov=200.0, lens_shift=0.3),
]


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("kw", CAMERAS)
def test_pixel_direction_pixel_round_trip(kw):
    cam = dome.dome_camera(**kw)
    rng = np.random.default_rng(1)
    col = rng.uniform(-0.5, cam.width - 0.5, 20000)
    row = rng.uniform(-0.5, cam.height - 0.5, 20000)
    # plus the lens centre itself and the exact corners/edges
    col = np.r_[col, cam.centre[0], -0.5, cam.width - 0.5]
    row = np.r_[row, cam.centre[1], cam.centre[1], cam.centre[1]]
    dirs, inside = cam.pixel_to_direction(col, row)
    # stay away from the antipode of a 360 deg lens, where every radius meets
    cx, cy = cam.centre
    keep = inside & (np.hypot(col - cx, row - cy) < 0.999 * cam.radius) if cam.fov == 360 else inside
    assert keep.sum() > 1000
    assert np.allclose(np.linalg.norm(dirs[keep], axis=-1), 1.0)
    c2, r2, vis = cam.direction_to_pixel(dirs[keep])
    err = np.hypot(c2 - col[keep], r2 - row[keep])
    assert err.max() < 0.01
    assert vis.all()
    assert np.isnan(dirs[~inside]).all()


@pytest.mark.parametrize("kw", CAMERAS)
def test_direction_pixel_direction_round_trip(kw):
    cam = dome.dome_camera(**kw)
    d = _unit(np.random.default_rng(2).normal(size=(20000, 3)))
    col, row, vis = cam.direction_to_pixel(d)
    assert vis.any()
    back, inside = cam.pixel_to_direction(col[vis], row[vis])
    assert inside.all()
    assert np.abs(back - d[vis]).max() < 1e-9


def test_domemaster_orientation():
    cam = dome.dome_camera("domemaster", width=1000)
    c = (1000 - 1) / 2
    # zenith at the centre, front at the bottom, right on the right, back on top
    for d, (col, row) in {
        (0, 0, 1): (c, c),
        (0, 1, 0): (c, 999.5),
        (1, 0, 0): (999.5, c),
        (-1, 0, 0): (-0.5, c),
        (0, -1, 0): (c, -0.5),
    }.items():
        got = cam.direction_to_pixel(np.array(d, float))
        assert got[0] == pytest.approx(col, abs=1e-9) and got[1] == pytest.approx(row, abs=1e-9)
    # equidistant: 45 deg elevation in front is halfway to the edge
    row, col = cam.elevation_row(45.0)
    assert row == pytest.approx(c + 500 / 2, abs=1e-9)


def test_omnimax_frame_geometry():
    cam = dome.dome_camera("omnimax")
    assert (cam.width, cam.height) == (2048, 1500)
    # 2048x1500 (the paper) is 2% wider
    assert cam.width / cam.height == pytest.approx(dome.OMNIMAX_FILM_MM[0] / dome.OMNIMAX_FILM_MM[1], rel=0.03)
    cx, cy = cam.centre
    assert cy > (cam.height - 1) / 2  # lens centre below the frame centre
    # the lens axis is the tilted dome zenith: 65 deg up in front
    col, row, _ = cam.direction_to_pixel(np.array([0, math.sin(math.radians(25)), math.cos(math.radians(25))]))
    assert (col, row) == pytest.approx((cx, cy), abs=1e-9)
    # front edge of the frame 22 deg below the horizon, 180 deg across at the lens centre row
    top, _ = cam.elevation_row(-22.0)
    assert top == pytest.approx(-0.5, abs=1.0)
    # the two ends of the dome's springline through the lens centre lie on the frame's side edges
    d = np.array([[-1.0, 0, 0], [1.0, 0, 0]])
    col, row, vis = cam.direction_to_pixel(d)
    assert col == pytest.approx([cam.width - 0.5, -0.5]) and row == pytest.approx([cy, cy])
    # most of the lower half of the circle falls off the film
    assert (cy + cam.radius) - (cam.height - 0.5) > 0.5 * cam.radius
    # the back edge: above the zenith, behind the audience
    dirs, inside = cam.pixel_to_direction(cx, cam.height - 0.5)
    el = math.degrees(math.atan2(dirs[2], dirs[1]))
    assert 100 <= el <= 115


@pytest.mark.parametrize("tilt", [0.0, 10.0, 25.0, 30.0, 45.0])
@pytest.mark.parametrize("preset", ["omnimax", "domemaster"])
def test_tilt_moves_the_horizon(preset, tilt):
    cam = dome.dome_camera(preset, tilt=tilt, width=2000, height=2000 if preset == "domemaster" else 1500)
    cx, cy = cam.centre
    # f-theta: the front horizon is (90 - tilt) deg from the lens axis, toward the front
    expect = (90.0 - tilt) / 90.0 * cam.radius
    row, col = cam.elevation_row(0.0)
    front = 1 if preset == "domemaster" else -1  # front at the bottom / at the top
    assert row == pytest.approx(cy + front * expect, abs=1e-6)
    assert col == pytest.approx(cx, abs=1e-6)
    # and the pixel there looks at the horizon straight ahead
    d, inside = cam.pixel_to_direction(col, row)
    assert inside and d == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
    # the back horizon is (90 + tilt) away, off the 180 deg circle once tilted
    _, _, vis = cam.direction_to_pixel(np.array([0.0, -1.0, 0.0]))
    assert bool(vis) == (tilt == 0.0 and preset == "domemaster")


def test_equisolid_radius():
    cam = dome.dome_camera("domemaster", width=1000, lens="equisolid")
    for theta in (10.0, 45.0, 80.0, 90.0):
        row, col = cam.elevation_row(90.0 - theta)
        r = 500 * math.sin(math.radians(theta) / 2) / math.sin(math.radians(45))
        assert row - cam.centre[1] == pytest.approx(r, abs=1e-9)


@pytest.mark.parametrize(
    "kw, field",
    [
        (dict(fov=0.0), "fov"),
        (dict(fov=-10.0), "fov"),
        (dict(fov=360.5), "fov"),
        (dict(fov=float("nan")), "fov"),
        (dict(width=0), "width"),
        (dict(height=0), "height"),
        (dict(width=12.5), "width"),
        (dict(width="wide"), "width"),
        (dict(height=-3), "height"),
        (dict(fov="x"), "fov"),
        (dict(tilt=95.0), "tilt"),
        (dict(preset="imax"), "preset"),
        (dict(lens="fisheye"), "lens"),
    ],
)
def test_bad_parameters(kw, field):
    preset = kw.pop("preset", "omnimax")
    with pytest.raises(DataError) as exc:
        dome.dome_camera(preset, **kw)
    assert isinstance(exc.value, ValueError)
    assert exc.value.field == field and field in str(exc.value)


def test_fov_360_is_allowed():
    cam = dome.dome_camera("domemaster", width=64, fov=360.0)
    assert cam.direction_to_pixel(np.array([0.0, 0.0, -1.0]))[2]


def test_domemaster_stays_square():
    assert (dome.dome_camera("domemaster", width=512).height,
            dome.dome_camera("domemaster", height=300).width) == (512, 300)


# --- sources ------------------------------------------------------------------------------------


def test_cube_faces_round_trip_and_axes():
    n = 16
    rng = np.random.default_rng(3)
    d = _unit(rng.normal(size=(5000, 3)))
    face, col, row = dome.direction_to_cube(d, n)
    assert (col >= -0.5).all() and (col <= n - 0.5).all() and (row >= -0.5).all() and (row <= n - 0.5).all()
    back = _unit(dome.cube_to_direction(face, col, row, n))
    assert np.abs(back - d).max() < 1e-12
    for i, name in enumerate(dome.CUBE_FACES):
        fwd, up = dome.CUBE_AXES[name]
        f, c, r = dome.direction_to_cube(np.array(fwd, float), n)
        assert (int(f), c, r) == (i, (n - 1) / 2, (n - 1) / 2)
        # image up is the face's up axis: a direction tipped toward it lands on an upper row
        _, _, r2 = dome.direction_to_cube(np.array(fwd, float) + 0.5 * np.array(up, float), n)
        assert r2 < r


def _field(d):
    """A smooth test image over the sphere (3 channels)."""
    d = _unit(d)
    return np.stack([0.5 + 0.5 * d[..., 0], 0.5 + 0.4 * d[..., 1] * d[..., 2], 0.5 + 0.5 * d[..., 2] ** 2], axis=-1)


def _cube_of(fn, n):
    c = np.arange(n)
    cc, rr = np.meshgrid(c, c)
    return np.stack([fn(dome.cube_to_direction(np.full(cc.shape, f), cc, rr, n)) for f in range(6)])


def _equirect_of(fn, w, h):
    lon = ((np.arange(w) + 0.5) / w - 0.5) * 2 * np.pi
    lat = (0.5 - (np.arange(h) + 0.5) / h) * np.pi
    lo, la = np.meshgrid(lon, lat)
    return fn(np.stack([np.cos(la) * np.sin(lo), np.cos(la) * np.cos(lo), np.sin(la)], axis=-1))


def _truth(cam, fn, ss=4):
    """The test field box-filtered over each pixel (ss x ss samples), black outside the circle."""
    k = (np.arange(ss) + 0.5) / ss - 0.5
    cc, rr = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
    acc = np.zeros((cam.height, cam.width, 3))
    for ox in k:
        for oy in k:
            d, inside = cam.pixel_to_direction(cc + ox, rr + oy)
            acc += np.where(inside[..., None], fn(np.nan_to_num(d, nan=1.0)), 0.0)
    return acc / ss**2, cam.pixel_to_direction(cc, rr)[1]


@pytest.mark.parametrize("preset", ["domemaster", "omnimax"])
def test_remap_cube_matches_field_and_seams(preset):
    cam = dome.dome_camera(preset, width=160, height=160 if preset == "domemaster" else 118, tilt=25.0)
    cube = _cube_of(_field, 64).astype(np.float32)
    out = dome.remap(cube, cam, "cube", supersample=2)
    truth, inside = _truth(cam, _field)
    # well inside the circle the remap follows the smooth field, seams included
    cx, cy = cam.centre
    cc, rr = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    core = np.hypot(cc - cx, rr - cy) < cam.radius - 2
    err = np.abs(out - truth)[core]
    assert err.max() < 4e-3
    # seam pixels (directions near a cube edge) are no worse than the others
    d, _ = cam.pixel_to_direction(cc, rr)
    a = np.sort(np.abs(np.nan_to_num(d)), axis=-1)
    seam = core & (a[..., 1] / np.maximum(a[..., 2], 1e-9) > 0.97)
    assert seam.sum() > 20
    assert np.abs(out - truth)[seam].max() < 4e-3


def test_remap_equirect_seam_and_pole():
    # a domemaster sees the zenith (equirect pole) at its centre and the +-180 deg seam above it
    cam = dome.dome_camera("domemaster", width=128)
    eq = _equirect_of(_field, 512, 256).astype(np.float32)
    out = dome.remap(eq, cam, "equirect", supersample=2)
    truth, inside = _truth(cam, _field)
    cx, cy = cam.centre
    cc, rr = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    core = np.hypot(cc - cx, rr - cy) < cam.radius - 2
    assert np.abs(out - truth)[core].max() < 4e-3
    seam = core & (np.abs(cc - cx) < 2) & (rr < cy)
    pole = np.hypot(cc - cx, rr - cy) < 3
    assert np.abs(out - truth)[seam].max() < 4e-3
    assert np.abs(out - truth)[pole].max() < 4e-3


def test_cube_and_equirect_routes_agree():
    cam = dome.dome_camera("omnimax", width=200, height=146)
    a = dome.remap(_cube_of(_field, 96), cam, "cube")
    b = dome.remap(_equirect_of(_field, 768, 384), cam, "equirect")
    assert np.abs(a - b).max() < 5e-3


def test_weights_sum_to_one_and_circle_edge_is_antialiased():
    cam = dome.dome_camera("domemaster", width=100)
    tab = dome.remap_table(cam, "cube", 40, supersample=4)
    ones = np.ones((6, 40, 40), np.float32)
    out = tab.apply(ones)
    cc, rr = np.meshgrid(np.arange(100), np.arange(100))
    r = np.hypot(cc - cam.centre[0], rr - cam.centre[1])
    assert np.allclose(out[r < 49], 1.0, atol=1e-5)
    assert np.all(out[r > 51] == 0.0)
    edge = out[(r > 49.3) & (r < 50.2)]
    assert ((edge > 0.05) & (edge < 0.95)).any()  # partial coverage, not a hard step
    # every output pixel's weights sum to its covered fraction: never more than 1
    assert out.max() <= 1.0 + 1e-6


def test_supersampling_antialiases_a_fine_checker():
    # a checker at the source's pixel scale averages to grey when supersampled
    cam = dome.dome_camera("domemaster", width=64)
    n = 256
    c = np.arange(n)
    checker = ((c[:, None] // 2 + c[None, :] // 2) % 2).astype(np.float32)
    cube = np.broadcast_to(checker, (6, n, n))
    cc, rr = np.meshgrid(np.arange(64), np.arange(64))
    core = np.hypot(cc - cam.centre[0], rr - cam.centre[1]) < 28
    sd1 = dome.remap(cube, cam, "cube", supersample=1)[core].std()
    sd4 = dome.remap(cube, cam, "cube", supersample=4)[core].std()
    assert sd4 < 0.5 * sd1


def test_remap_table_is_cached_and_stores_as_plain_arrays(tmp_path):
    from nephele.core.pipeline.cache import Cache

    cam = dome.dome_camera("omnimax", width=64, height=47)
    t1 = dome.remap_table(cam, "cube", (6, 32, 32))
    assert dome.remap_table(cam, "cube", 32) is t1
    cache = Cache(tmp_path)
    cache.store("dome_map", {"n": 32}, t1.arrays())
    t2 = dome.RemapTable.from_arrays(cache.load("dome_map", {"n": 32}))
    img = np.random.default_rng(0).random((6, 32, 32, 3))
    assert np.array_equal(t1.apply(img), t2.apply(img))


def test_stored_remap_table_builds_once(tmp_path):
    from nephele.core.pipeline.cache import Cache

    cam = dome.dome_camera("domemaster", width=40)
    cache = Cache(tmp_path)
    a = dome.stored_remap_table(cam, "equirect", (32, 64), 2, cache)
    dome._remap_table.cache_clear()
    b = dome.stored_remap_table(cam, "equirect", (32, 64), 2, cache)  # loaded, not rebuilt
    assert dome._remap_table.cache_info().misses == 0
    assert np.array_equal(a.indices, b.indices) and np.array_equal(a.weights, b.weights)
    other = dome.stored_remap_table(dome.dome_camera("domemaster", width=40, tilt=5.0), "equirect", (32, 64), 2, cache)
    assert not np.array_equal(other.indices, a.indices)


def test_remap_rejects_wrong_source():
    cam = dome.dome_camera("domemaster", width=32)
    with pytest.raises(DataError, match="source"):
        dome.remap_table(cam, "mirrorball", (32, 32))
    tab = dome.remap_table(cam, "cube", 16)
    with pytest.raises(DataError, match="shape"):
        tab.apply(np.zeros((6, 8, 8)))
    with pytest.raises(DataError, match="supersample"):
        dome.remap_table(cam, "cube", 16, supersample=0)


def test_stereo_eyes_fixed_baseline():
    eyes = dome.stereo_eyes(0.065, centre=(1.0, 2.0, 3.0))
    assert eyes["R"] - eyes["L"] == pytest.approx([0.065, 0.0, 0.0])
    assert (eyes["L"] + eyes["R"]) / 2 == pytest.approx([1.0, 2.0, 3.0])
    with pytest.raises(DataError, match="separation"):
        dome.stereo_eyes(0.0)
    # a point far ahead: horizontal disparity only, no vertical, in the Omnimax frame
    cam = dome.dome_camera("omnimax")
    p = np.array([0.0, 10.0, 3.0])
    eyes = dome.stereo_eyes(0.065)
    cl, rl, _ = cam.direction_to_pixel(p - eyes["L"])
    cr, rr, _ = cam.direction_to_pixel(p - eyes["R"])
    assert abs(cl - cr) > 1 and abs(rl - rr) < 1e-9
