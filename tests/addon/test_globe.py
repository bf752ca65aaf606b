"""The relief globe, the sky and the haze: geometry against the relief data, one radius
and exaggeration for every layer, and what a small render shows."""

import bpy
import numpy as np
import pytest

from nephele.addon import data_ops, globe_ops
from nephele.addon.mesh import mesh_arrays, point_attribute
from nephele.core.climate.grid import DEFAULT_EXAGGERATION, globe_radius, xyz_to_lonlat


def test_sphere_is_closed_and_outward():
    trimesh = pytest.importorskip("trimesh")
    lon = np.arange(-177.0, 180.0, 6.0)
    lat = np.arange(-87.0, 90.0, 6.0)
    v, f, lonlat = globe_ops.sphere_arrays(lon, lat, np.ones((lat.size, lon.size)))
    tm = trimesh.Trimesh(v, f, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0  # outward winding
    assert len(v) - len(tm.edges_unique) + len(f) == 2
    assert tm.volume == pytest.approx(4 / 3 * np.pi, rel=0.02)
    assert lonlat.shape == (len(v), 2)


def test_shipped_relief():
    lon, lat, h = globe_ops.load_relief()
    assert lon.min() >= -180 and lon.max() < 180 and np.all(np.diff(lon) > 0)
    assert np.all(np.diff(lat) > 0) and h.shape == (lat.size, lon.size)

    def at(lo, la):
        return h[np.abs(lat - la).argmin(), np.abs(lon - lo).argmin()]
    assert at(86.5, 28.5) > 3000  # Himalaya
    assert at(-150.5, 0.5) < -3000  # central Pacific
    assert at(90.5, -80.5) > 2000  # East Antarctic ice sheet


def test_etopo_file_matches_shipped_relief(shared_data):
    lon, lat, h = globe_ops.load_relief(shared_data / "terrain" / "etopo60.cdf")
    lon0, lat0, h0 = globe_ops.load_relief()
    np.testing.assert_allclose(lon, lon0)
    np.testing.assert_allclose(lat, lat0)
    assert np.abs(h - h0).max() <= 1.0  # the shipped file is int16 metres


def test_globe_follows_relief_radius_and_exaggeration(empty_scene):
    lon, lat, h = globe_ops.load_relief()
    data_ops.set_settings(empty_scene, exaggeration=12.0, radius=2.0)
    obj = globe_ops.add_globe(scene=empty_scene)
    assert obj["nephele_globe"].to_dict() == {"radius": 2.0, "exaggeration": 12.0}
    v, f = mesh_arrays(obj.data)
    n = h.size
    r = np.linalg.norm(v[:n].astype(np.float64), axis=1)
    np.testing.assert_allclose(r, globe_radius(np.maximum(h, 0), 2.0, 12.0).ravel(), rtol=1e-6)
    glon, glat, _ = xyz_to_lonlat(v[:n])
    np.testing.assert_allclose(glat, np.broadcast_to(lat[:, None], h.shape).ravel(), atol=1e-3)
    np.testing.assert_allclose(point_attribute(obj.data, "height"), np.concatenate(
        [h.ravel(), [h[0].mean(), h[-1].mean()]]), atol=0.5)
    # The sea is flat at the radius; a second call rebuilds the same object.
    assert np.isclose(r[h.ravel() <= 0], 2.0).all()
    again = globe_ops.add_globe(exaggeration=0.0, scene=empty_scene)
    assert again == obj and len(bpy.data.objects) == 1
    assert np.allclose(np.linalg.norm(mesh_arrays(obj.data)[0], axis=1), 2.0, atol=1e-6)


def test_defaults_come_from_one_place(empty_scene):
    assert data_ops.settings(empty_scene)["exaggeration"] == DEFAULT_EXAGGERATION
    assert data_ops.settings(empty_scene)["radius"] == 1.0
    obj = globe_ops.add_globe("flat", scene=empty_scene)
    assert obj["nephele_globe"].to_dict() == {"radius": 1.0, "exaggeration": DEFAULT_EXAGGERATION}
    parts = globe_ops.add_sky_and_haze(empty_scene)
    top = np.linalg.norm(mesh_arrays(parts["haze"].data)[0], axis=1)
    assert np.allclose(top, globe_radius(60000.0, 1.0, DEFAULT_EXAGGERATION), rtol=1e-5)
    info = parts["haze"].active_material["nephele_haze"]
    assert info["scale_height_scene"] == pytest.approx(8000.0 * DEFAULT_EXAGGERATION / 6_371_000.0)


def test_bad_arguments(empty_scene):
    with pytest.raises(ValueError):
        globe_ops.add_globe("flat", radius=0.0, scene=empty_scene)
    with pytest.raises(ValueError, match="does not match"):
        globe_ops.load_relief((np.arange(3.0), np.arange(2.0), np.zeros((3, 3))))


def _render(scene, path, size=(96, 72), samples=8):
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(path))
    a = np.empty(size[0] * size[1] * 4, np.float32)
    img.pixels.foreach_get(a)
    bpy.data.images.remove(img)
    return a.reshape(size[1], size[0], 4)[..., :3]  # rows bottom to top


@pytest.mark.slow
def test_render_sea_land_space_and_haze(empty_scene, tmp_path):
    scene = empty_scene
    globe_ops.add_globe(scene=scene)
    parts = globe_ops.add_sky_and_haze(scene, sun_direction=(1.0, -0.6, 0.2))
    globe_ops.add_camera(scene, lon=-30.0, lat=0.0, distance=3.6)
    with_haze = _render(scene, tmp_path / "haze.png")
    parts["haze"].hide_render = True
    without = _render(scene, tmp_path / "clear.png")
    h, w = without.shape[:2]
    cy, cx = h // 2, w // 2

    def at(lon, lat):  # mean colour of 3x3 pixels around a place on the globe
        from bpy_extras.object_utils import world_to_camera_view
        from mathutils import Vector

        from nephele.core.climate.grid import lonlat_to_xyz

        p = world_to_camera_view(scene, scene.camera, Vector(lonlat_to_xyz(lon, lat, 1.0).tolist()))
        x, y = int(p.x * w), int(p.y * h)
        return without[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).mean(0)

    # Sea is blue, land (the Sahel, Amazonia) is not.
    for lon, lat in ((-25.0, -25.0), (-40.0, 25.0)):
        sea = at(lon, lat)
        assert sea[2] > sea[0] and sea[2] > sea[1]
    for lon, lat in ((5.0, 12.0), (-58.0, -8.0)):
        land = at(lon, lat)
        assert land[1] > land[2] and land[0] > land[2]
    # Corners: dark space.
    assert without[:3, :3].max() < 0.03 and with_haze[:3, :3].max() < 0.03
    # Just outside the limb the haze glows blue; without it there is only space.
    rows = slice(cy - 3, cy + 4)
    profile = without[rows].sum(-1).mean(0)
    right = cx + int(np.argmax(profile[cx:] < 0.08))  # first dark column east of the centre
    assert cx + 20 < right < w - 4
    halo, space = with_haze[rows, right:right + 3], without[rows, right:right + 3]
    hz, cl = halo.reshape(-1, 3).mean(0), space.reshape(-1, 3).mean(0)
    assert hz.sum() > cl.sum() + 0.02
    assert hz[2] > hz[0]
    # The closed-form shell gives a blue limb too, and leaves the centre's colour nearly alone.
    parts = globe_ops.add_sky_and_haze(scene, haze_mode="shell", sun_direction=(1.0, -0.6, 0.2))
    assert parts["haze"].active_material["nephele_haze"]["mode"] == "shell"
    shell = _render(scene, tmp_path / "shell.png")
    sh = shell[rows, right:right + 3].reshape(-1, 3).mean(0)
    assert sh.sum() > cl.sum() + 0.02 and sh[2] > sh[0]
    centre = (slice(cy - 2, cy + 3), slice(cx - 2, cx + 3))
    assert np.abs(shell[centre].mean((0, 1)) - without[centre].mean((0, 1))).max() < 0.1
