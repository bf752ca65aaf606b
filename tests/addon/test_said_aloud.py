"""Every fallback said aloud where the user looks (issue 41): a dataset that does not open, corrupt scene
settings, a refused transfer-function edit and missing compiled kernels show in the panels, not as a
silent default."""

import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import contour_ops, data_ops, layers, panel, volume_ops, volume_panel  # noqa: E402


class _Layout:
    """A panel's layout headless: records every call; ``panel()`` gives an open sub-panel."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.log.append((name, args, kwargs))
            return (_Layout(self.log), _Layout(self.log)) if name == "panel" else _Layout(self.log)

        return call


def _draw(panel_class, scene, obj):
    """The labels ``panel_class.draw`` writes, joined by " | "."""
    from types import SimpleNamespace

    log = []
    fake = SimpleNamespace(layout=_Layout(log), _draw_layer=layers.NEPHELE_PT_layers._draw_layer)
    panel_class.draw(fake, SimpleNamespace(scene=scene, active_object=obj, view_layer=bpy.context.view_layer))
    return " | ".join(k.get("text", "") for name, _, k in log if name == "label")


@pytest.fixture(autouse=True)
def no_problems():
    data_ops.PROBLEMS.clear()
    yield
    data_ops.PROBLEMS.clear()


def test_a_dataset_that_does_not_open_is_shown_not_replaced_by_cloud(empty_scene, tmp_path, capfd):
    scene = empty_scene
    bad = tmp_path / "broken.nc"
    bad.write_bytes(b"CDF\x01" + b"\x00" * 10)
    data_ops.set_settings(scene, source=str(bad))
    items = contour_ops._variables(None, bpy.context)
    assert [i[0] for i in items] == ["cloud"]  # still offered, so the menu is usable
    problem = data_ops.PROBLEMS[("dataset", str(bad))]
    assert problem.startswith(f"{bad}: cannot open as NetCDF (damaged NetCDF 3 header") and "\n" not in problem
    labels = _draw(contour_ops.NEPHELE_PT_contour, scene, None)
    assert problem in labels
    assert problem in _draw(data_ops.NEPHELE_PT_data, scene, None)
    assert capfd.readouterr().err.count(problem) == 1  # on the console once, not at every redraw
    contour_ops._variables(None, bpy.context)
    assert capfd.readouterr().err == ""


def test_a_layer_whose_dataset_is_gone_shows_why_not_nan_or_time_zero(empty_scene, tmp_path):
    from nephele.core.volume.transfer import TransferFunction

    scene = empty_scene
    scene.frame_start = scene.frame_end = 1
    obj, _ = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(0.3, 1.0), directory=str(tmp_path / "v"),
                                          scene=scene, frames=(1, 1), mode=volume_ops.EXACT)
    p = dict(layers.frame.params(obj))
    p["source"] = str(tmp_path / "moved.nc")  # the file was moved away
    layers.frame.set_params(obj, p)
    assert layers._hours_shown(p, scene) is None
    labels = _draw(layers.NEPHELE_PT_layers, scene, obj)
    assert f"{tmp_path / 'moved.nc'}: file not found" in labels and "nan" not in labels.lower()
    # A range that fails in its thread says why instead of "nan … nan".
    assert layers.range_line({"error": "x.nc: cannot read step 0"}) == ("data range: x.nc: cannot read step 0", "ERROR")


def test_a_refused_threshold_edit_is_shown_beside_the_threshold(empty_scene, tmp_path):
    from nephele.core.volume.transfer import TransferFunction

    scene = empty_scene
    scene.frame_start = scene.frame_end = 13
    obj, _ = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(0.3, 1.0), directory=str(tmp_path / "v"),
                                          scene=scene, frames=(13, 13), mode=volume_ops.EXACT)
    obj.nephele_layer.threshold = 1.5  # above the last point (1.0): no transfer function
    assert layers.frame.params(obj)["tf"]["points"][0] == pytest.approx([0.3, 0.0])  # not applied...
    labels = _draw(layers.NEPHELE_PT_layers, scene, obj)
    assert "threshold 1.5 not applied: it must lie below the transfer function's last point (1)" in labels  # ...said
    obj.nephele_layer.threshold = 0.5
    assert "not applied" not in _draw(layers.NEPHELE_PT_layers, scene, obj)


def test_typed_transfer_function_points_that_do_not_parse_are_shown(empty_scene):
    s = empty_scene.nephele_volume
    s.tf_edit = volume_panel.TF_POINTS
    s.tf_points = "[[0.3, 0], [oops"
    log = []
    volume_panel.draw_tf(_Layout(log), s)
    labels = [k.get("text", "") for name, _, k in log if name == "label"]
    assert any(t.startswith("Not applied: ") and "is not valid JSON" in t for t in labels), labels


@pytest.mark.parametrize("raw, words",
                         [("{not json", "cannot be read"), ('{"exaggeration": 1e6}', "exaggeration must be")])
def test_corrupt_scene_settings_are_reported_before_they_are_reset(empty_scene, raw, words, capfd):
    scene = empty_scene
    scene[data_ops.MIRROR_KEY] = raw
    cfg = data_ops.settings(scene)
    assert cfg["exaggeration"] == data_ops.DEFAULTS["exaggeration"]
    assert words in data_ops.PROBLEMS["settings"] and words in capfd.readouterr().err
    assert words in _draw(data_ops.NEPHELE_PT_data, scene, None)
    data_ops.set_settings(scene, hours_per_frame=2.0)  # the reset: the old text is kept
    assert scene["nephele_settings_bad"] == raw and "settings" not in data_ops.PROBLEMS
    assert data_ops.settings(scene)["hours_per_frame"] == 2.0


def test_missing_kernels_show_in_the_main_panel(empty_scene, monkeypatch):
    from nephele.core import native

    monkeypatch.setitem(native._FALLBACK, "reason", "No module named 'nephele_native'")
    labels = _draw(panel.NEPHELE_PT_main, empty_scene, None)
    assert "compiled kernels are not loaded (No module named 'nephele_native')" in labels
    monkeypatch.setitem(native._FALLBACK, "reason", None)
    assert "kernels" not in _draw(panel.NEPHELE_PT_main, empty_scene, None)


def test_a_full_disk_while_saving_leaves_no_half_copy(empty_scene, tmp_path, small_disk):
    from nephele.core.volume.transfer import TransferFunction

    scene = empty_scene
    scene.frame_start = scene.frame_end = 1
    monkey_cache = tmp_path / "cache"
    import os

    os.environ["NEPHELE_CACHE"] = str(monkey_cache)
    try:
        obj, _ = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(0.3, 1.0), scene=scene, frames=(1, 1),
                                              mode=volume_ops.EXACT)
        folder = data_ops.layer_dir(layers.frame.params(obj))
        (folder / "big.bin").write_bytes(b"x" * 300_000)  # more than the disk below holds
        disk = small_disk("128k")
        done = data_ops.adopt_files(str(disk / "scene.blend"))
    finally:
        os.environ.pop("NEPHELE_CACHE", None)
    assert done == [] and data_ops.layer_dir(layers.frame.params(obj)) == folder  # still its own, whole folder
    assert not [p for p in disk.rglob("*") if p.is_file()]  # no half copy
    problem = data_ops.PROBLEMS["save"]
    assert problem.startswith(f"{obj.name}: its files stay in {folder}") and "no space left on the disk" in problem
    assert problem in _draw(data_ops.NEPHELE_PT_data, scene, None)
