"""The Dataset panel with a GRIB product: level type and member reach the reader from the import operator
and survive in the source name; the variable boxes of the volume and splat panels offer cloud water by its
meaning and the contour layer draws it."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("eccodes")

from gribfiles import field, isobaric, regular_ll, write  # noqa: E402

from nephele.addon import contour_ops, data_ops  # noqa: E402
from nephele.core.climate.readers import open_dataset  # noqa: E402


def _ensemble(path):
    grid, lon, lat = regular_ll()
    msgs = [isobaric(short, p, grid, base + field(lon, lat, p) + 10 * m, number=m)
            for m in range(3) for p in (850, 700, 500) for short, base in (("t", 260.0), ("ciwc", 0.0))]
    return write(path, msgs)


def test_member_reaches_the_reader_and_the_variable_boxes_offer_fields_by_meaning(empty_scene, tmp_path, own_cache):
    scene = empty_scene
    path = _ensemble(tmp_path / "ens.grib2")
    group = scene.nephele_data
    group.read_member = 2
    assert bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path)) == {"FINISHED"}
    assert group.source.startswith(f"{path}?member=2&file=")
    ds = data_ops.dataset(scene=scene)
    assert ds.member == 2
    np.testing.assert_array_equal(open_dataset(group.source).read("t", 0), ds.read("t", 0))
    offered = dict(data_ops.variable_search(None, bpy.context, ""))
    assert "cloud_ice" in offered and "'ciwc' in the file" in offered["cloud_ice"]
    assert [n for n, _ in data_ops.variable_search(None, bpy.context, "ciw")] == ["cloud_ice"]
    obj = contour_ops.add_contour("ciwc", float(np.median(ds.read("cloud_ice", 0))), scene=scene)
    assert len(obj.data.polygons) > 0


def test_bad_level_type_is_one_error_line(empty_scene, tmp_path, own_cache):
    scene = empty_scene
    path = _ensemble(tmp_path / "ens.grib2")
    scene.nephele_data.read_level_type = "hybrid"
    with pytest.raises(RuntimeError,
                       match=r"ens.grib2: field 'level_type': no fields on level type 'hybrid' \(found: "
                             r"isobaricInhPa\)$"):
        bpy.ops.nephele.import_dataset(kind="FILE", filepath=str(path))  # the operator's ERROR report, one line
