"""Streak textures: seamless cycle, tileable, oriented along the projected wind, moving downwind."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.splats import (
    Camera,
    Splats,
    principal_axes,
    project_splats,
    render_splats,
    splat_kernel,
    streak_factor,
    streak_maps,
    streak_orientation,
)

K = splat_kernel()


def test_maps_are_a_seamless_downwind_cycle():
    maps = streak_maps(8, 128)
    assert maps.shape == (8, 128, 128) and maps.dtype == np.float32
    assert maps.min() >= 0 and maps.max() == pytest.approx(1.0)
    # Map k is map 0 advected by k/8 of the tile (16 texels) along +u (the columns).
    for k in range(8):
        assert np.allclose(maps[k], np.roll(maps[0], 16 * k, axis=1), atol=1e-6)
    steps = [np.abs(maps[(k + 1) % 8] - maps[k]).mean() for k in range(8)]
    assert steps[-1] <= max(steps[:-1]) * (1 + 1e-6)  # n-1 -> 0 is no larger than any other step
    # Tileable: the wrap-around column/row differences look like interior ones.
    m = maps[0].astype(np.float64)
    inner_u = np.abs(np.diff(m, axis=1)).mean()
    inner_v = np.abs(np.diff(m, axis=0)).mean()
    assert np.abs(m[:, 0] - m[:, -1]).mean() < 3 * inner_u and np.abs(m[0] - m[-1]).mean() < 3 * inner_v
    # Anisotropic along +u.
    angle, coherence = streak_orientation(m)
    assert min(angle, np.pi - angle) < np.deg2rad(2) and coherence > 0.7
    # A size not divisible by n: still exact shifts of a continuous pattern, still a loop.
    odd = streak_maps(5, 50, seed=3)
    s = [np.abs(odd[(k + 1) % 5] - odd[k]).mean() for k in range(5)]
    assert max(s) - min(s) < 0.2 * np.mean(s)


def test_bad_streak_arguments():
    for kw in (dict(n=0), dict(size=2), dict(length=0), dict(width=0.9), dict(count=1.5)):
        with pytest.raises(DataError):
            streak_maps(**kw)


def slab(wind, h=0.1):
    g = np.arange(-1.3, 1.3 + 1e-9, h)
    gz = np.arange(-0.1, 0.1 + 1e-9, h)
    c = np.stack(np.meshgrid(g, g, gz, indexing="ij"), -1).reshape(-1, 3)
    m = len(c)
    w = np.asarray(wind(c), dtype=np.float64)
    return Splats(c, principal_axes(np.broadcast_to(np.eye(3) * h, (m, 3, 3)), K.radius), np.ones((m, 3)), np.ones(m),
                  np.broadcast_to(w, (m, 3)).copy(), K.radius)


TOP = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), orthographic=True, ortho_scale=2.0)


def angle_error(measured, expected):
    return (measured - expected + np.pi / 2) % np.pi - np.pi / 2


def test_rendered_streaks_follow_a_uniform_wind_within_5_degrees():
    maps = streak_maps()
    errors = []
    for theta in np.deg2rad([0, 30, 75, 120, 160]):
        sp = slab(lambda c, theta=theta: 0.2 * np.array([np.cos(theta), np.sin(theta), 0.0]))
        img = render_splats(sp, K, TOP, 128, 128, streaks=maps, streak_contrast=1.0, extinction=10.0)
        angle, _ = streak_orientation(img[..., 3], sigma=3)
        expected = np.arctan2(-np.sin(theta), np.cos(theta)) % np.pi  # image y points down
        errors.append(angle_error(angle, expected))
    rms = np.rad2deg(np.sqrt(np.mean(np.square(errors))))
    print(f"uniform wind: streak orientation errors {np.round(np.rad2deg(errors), 1)} deg, RMS {rms:.2f} deg")
    assert rms < 5


def test_rendered_streaks_follow_a_rotating_wind_locally_within_5_degrees():
    # Solid-body rotation about the view axis (wind speed 0.25 |x|, at least 0.15): the streaks
    # turn with it; measured in 24x24-pixel windows against the wind at each window's centre.
    def wind(c):
        r = np.maximum(np.hypot(c[:, 0], c[:, 1]), 0.6)
        return np.column_stack([-c[:, 1], c[:, 0],
                                np.zeros(len(c))]) * (0.25 * r / np.hypot(c[:, 0], c[:, 1]).clip(1e-9))[:, None]

    sp = slab(wind, h=0.07)
    n = 192
    img = render_splats(sp, K, TOP, n, n, streaks=streak_maps(), streak_contrast=1.0, extinction=3.0)
    lum = img[..., 3]
    f = TOP.pixels_per_unit(n)
    errors = []
    for row in range(16, n - 39, 24):
        for col in range(16, n - 39, 24):
            x, y = (col + 12 - n / 2) / f, -(row + 12 - n / 2) / f
            if np.hypot(x, y) < 0.3:
                continue  # the centre of rotation has no direction
            mask = np.zeros((n, n), bool)
            mask[row : row + 24, col : col + 24] = True
            angle, _ = streak_orientation(lum, sigma=3, mask=mask)
            expected = np.arctan2(-x, -y) % np.pi  # wind (-y, x) in the scene; image y down
            errors.append(angle_error(angle, expected))
    rms = np.rad2deg(np.sqrt(np.mean(np.square(errors))))
    print(f"rotating wind: {len(errors)} windows, streak orientation RMS error {rms:.2f} deg")
    assert rms < 5


def test_streaks_move_downwind_at_the_projected_wind_speed():
    # One splat covering the image: the optical depth with streaks over the one without is
    # the streak factor itself; it equals streak_factor() on the plane through the centre,
    # and the next map (after tile/(n |wp|) hours) shows it shifted downwind by tile/n.
    maps = streak_maps()
    speed, theta, tile = 0.3, np.deg2rad(-30), 2.0  # scene units per hour; tile in scene units (107 px)
    wind = speed * np.array([np.cos(theta), np.sin(theta), 0.0])
    sp = Splats(np.zeros((1, 3)), principal_axes(np.eye(3)[None], K.radius), np.ones((1, 3)), np.ones(1), wind[None],
                K.radius)

    def optical_depth(**kw):
        img = render_splats(sp, K, TOP, 128, 128, extinction=0.5, streak_tile=tile, streak_contrast=1.0, prefilter=0.0,
                            **kw)
        return -np.log1p(-img[..., 3].astype(np.float64))

    plain = optical_depth()
    step = tile / (8 * speed)  # hours per map
    a, b = (optical_depth(streaks=maps, hours=h) / plain for h in (0.1 * step, 1.1 * step))
    f = TOP.pixels_per_unit(128)
    cols, rows = np.meshgrid(np.arange(128) + 0.5 - 64, np.arange(128) + 0.5 - 64)
    xyz = np.column_stack([cols.ravel() / f, -rows.ravel() / f, np.zeros(cols.size)])
    ref = streak_factor(sp, np.zeros(len(xyz), int), xyz, TOP, 0.1 * step, maps, tile, 1.0).reshape(128, 128)
    inner = (slice(24, 104), slice(24, 104))
    assert np.abs(a[inner] - ref[inner]).max() < 2e-3  # float32 alpha limits the ratio
    err = {(dx, dy): np.mean((a[24:104, 24:104] - b[24 + dy : 104 + dy, 24 + dx : 104 + dx]) ** 2)
           for dx in range(-20, 21) for dy in range(-20, 21)}
    dx, dy = min(err, key=err.get)
    expected = tile / 8 * f * np.array([np.cos(theta), -np.sin(theta)])  # image y down
    print(f"streak shift per map: ({dx}, {dy}) px; the wind moves ({expected[0]:.2f}, {expected[1]:.2f}) px in "
          f"{step:.3f} h")
    assert np.hypot(dx - expected[0], dy - expected[1]) <= 1.0
    scr = project_splats(sp, K, TOP, 128, 128, streak_tile=tile)
    assert scr.wind_speed[0] == pytest.approx(speed * f) and scr.rate[0] == pytest.approx(speed / tile)


def test_calm_wind_and_bad_streak_input():
    maps = streak_maps(4, 32)
    sp = Splats(np.zeros((1, 3)), principal_axes(np.eye(3)[None] * 0.3, K.radius), np.ones((1, 3)), np.ones(1),
                np.zeros((1, 3)), K.radius)
    # Calm: streaks lie along the camera's x axis and do not move with time.
    f0 = streak_factor(sp, [0, 0], [[0.1, 0.05, 0], [0.2, -0.1, 0]], TOP, 0.0, maps, 0.5)
    f1 = streak_factor(sp, [0, 0], [[0.1, 0.05, 0], [0.2, -0.1, 0]], TOP, 7.3, maps, 0.5)
    assert np.array_equal(f0, f1)
    for kw in (dict(streaks=np.zeros((2, 2))), dict(streaks=maps, hours=np.nan),
               dict(streaks=maps, streak_contrast=2.0), dict(streaks=maps, streak_tile=-1.0)):
        with pytest.raises(DataError):
            render_splats(sp, K, TOP, 16, 16, **kw)
