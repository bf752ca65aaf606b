"""The Dataset panel's "File overrides": the CLI's reader options (vertical coordinate, P0, time units,
earth radius, variable map) reach the reader from the import operator, survive in the scene's source
name, and a bad one is one ERROR line naming the file and the field."""

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
xr = pytest.importorskip("xarray")

from nephele.addon import contour_ops, data_ops  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402
from nephele.core.pipeline.sources import open_source  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"
NCL, CAM = DATA / "ncl_nc4uvt_T.nc", DATA / "cam_vinth2p.nc"


def _unnamed_field_file(path):
    """A CF file whose only 3-D field has a name no reader knows ('XYZ'), linear in height:
    XYZ = z / 10 km on flat height levels, so its 0.5 contour lies at 5 km."""
    z = np.array([0.0, 2500.0, 5000.0, 7500.0, 10000.0])
    lat, lon = np.linspace(-60.0, 60.0, 9), np.arange(0.0, 360.0, 30.0)
    xyz = np.broadcast_to((z / 1e4)[:, None, None], (z.size, lat.size, lon.size)).astype(np.float32)
    xr.Dataset(
        {"XYZ": (("height", "lat", "lon"), xyz, {"units": "1"})},
        coords={"height": ("height", z, {"units": "m", "positive": "up"}),
                "lat": ("lat", lat, {"units": "degrees_north"}), "lon": ("lon", lon, {"units": "degrees_east"})},
    ).to_netcdf(path)
    return path


def _set(scene, **values):
    group = scene.nephele_data
    for key, value in values.items():
        setattr(group, key, value)


def test_earth_radius_and_time_units_reach_the_reader_and_survive_in_the_source(empty_scene):
    scene = empty_scene
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(NCL)) == {"FINISHED"}
    plain = data_ops.dataset(scene=scene)
    assert scene.nephele_data.source == str(NCL) and plain.earth_radius == 6371000.0
    assert any(n.startswith("time: time units 'Month'") for n in plain.notes)

    _set(scene, read_earth_radius=6371220.0, read_time_units="days since 2000-01-01")
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(NCL)) == {"FINISHED"}
    source = scene.nephele_data.source
    assert source.startswith(f"{NCL}?radius=6371220.0&time_units=days+since+2000-01-01&file=")
    ds = data_ops.dataset(scene=scene)
    assert ds.earth_radius == 6371220.0 and str(ds.times[0]) == "2000-01-01T00:00:00"
    assert not any(n.startswith("time:") for n in ds.notes)
    # The name alone reopens the file with the same overrides (a saved scene, a farm worker).
    again = open_dataset(source)
    assert again is not ds and again.earth_radius == 6371220.0 and str(again.times[0]) == "2000-01-01T00:00:00"
    np.testing.assert_array_equal(again.read("temperature", 0), ds.read("temperature", 0))


def test_var_map_makes_a_field_usable_by_a_layer(empty_scene, tmp_path):
    scene = empty_scene
    path = _unnamed_field_file(tmp_path / "unnamed.nc")
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path)) == {"FINISHED"}
    assert "cloud" not in data_ops.dataset(scene=scene).variables
    _set(scene, read_var_map="cloud=XYZ")
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path)) == {"FINISHED"}
    ds = data_ops.dataset(scene=scene)
    assert "cloud" in ds.variables and "variables=cloud%3AXYZ" in scene.nephele_data.source
    # A contour layer opens the scene's source by name and draws the mapped field (the 0.5 surface:
    # the shell at 5 km over the 9 x 12 grid).
    obj = contour_ops.add_contour("cloud", 0.5, scene=scene)
    assert len(obj.data.polygons) > 50
    assert np.array_equal(open_source(scene.nephele_data.source).read("cloud", 0), ds.read("cloud", 0))


@pytest.mark.parametrize(
    "values, words",
    [
        ({"read_earth_radius": 6371.0}, ["ncl_nc4uvt_T.nc", "field 'earth radius'", "metres"]),
        ({"read_var_map": "temperature"}, ["ncl_nc4uvt_T.nc", "field 'variable map'", "STD=NAME"]),
        ({"read_var_map": "temperature=Q"}, ["ncl_nc4uvt_T.nc", "field 'Q'", "not a 3-D field"]),
        ({"read_time_units": "Month"}, ["ncl_nc4uvt_T.nc", "field 'time units'", "since"]),
    ],
)
def test_a_bad_override_is_one_error_line_and_changes_nothing(empty_scene, values, words):
    scene = empty_scene
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    _set(scene, **values)
    with pytest.raises(RuntimeError) as info:  # bpy.ops turns an ERROR report into RuntimeError
        bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(NCL))
    lines = [ln for ln in str(info.value).strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), lines
    assert all(w in lines[0] for w in words), lines[0]
    assert scene.nephele_data.source == "demo:small"


def test_p0_and_vertical_coordinate_reach_the_reader(empty_scene):
    scene = empty_scene
    _set(scene, read_p0=90000.0)
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(CAM)) == {"FINISHED"}
    ds = data_ops.dataset(scene=scene)
    base = open_dataset(CAM)
    assert "p0=90000.0" in scene.nephele_data.source
    # p = hyam p0 + hybm ps: the top level (hybm = 0) scales with p0, so its pressure is 0.9 times CAM's.
    p_base = base.read("pressure", 0)
    top = int(np.argmin(p_base.mean(axis=(1, 2))))
    np.testing.assert_allclose(ds.read("pressure", 0)[top], 0.9 * p_base[top], rtol=1e-5)
    assert np.all(ds.read("pressure", 0)[top] < p_base[top])
    assert not any("100000" in n for n in ds.notes) and any("100000" in n for n in base.notes)
    # The NCL file's levels are hPa; told they are heights in km, they become flat levels lev * 1000 m.
    _set(scene, read_p0=0.0, read_vertical="height_km")
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(NCL)) == {"FINISHED"}
    lev = np.sort(xr.open_dataset(NCL)["lev"].values.astype(np.float64))
    height = data_ops.dataset(scene=scene).grid.height  # broadcast to (level, lat, lon): flat levels
    np.testing.assert_allclose(height.reshape(lev.size, -1), np.repeat(lev[:, None] * 1000.0, 64 * 128, axis=1),
                               rtol=1e-12)


def test_panel_draws_the_overrides_in_a_collapsible_section(empty_scene):
    drawn, panels = [], []

    class Layout:
        """Records ``prop`` and ``panel`` calls; every other layout call returns another recorder."""

        def prop(self, data, name, **kw):
            drawn.append(name)

        def panel(self, idname, default_closed=False):
            panels.append((idname, default_closed))
            return Layout(), Layout()

        def __getattr__(self, name):
            return lambda *a, **kw: Layout()

    data_ops.NEPHELE_PT_data.draw(type("Panel", (), {"layout": Layout()})(), bpy.context)
    assert panels == [("NEPHELE_PT_data_overrides", True)]
    assert drawn[-7:] == ["read_vertical", "read_p0", "read_time_units", "read_earth_radius", "read_var_map",
                          "read_level_type", "read_member"]
