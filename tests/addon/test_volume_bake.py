"""Volume frames baked in the background (issue 20, "never freeze": volume baking)."""

import time

import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import data_ops, frame, volume_bake, volume_ops  # noqa: E402
from nephele.core.pipeline.cache import cache_key  # noqa: E402
from nephele.core.volume.transfer import TransferFunction  # noqa: E402
from nephele.core.volume.volume_task import frame_params  # noqa: E402
from nephele.volume_files import file_key, frame_path  # noqa: E402


@pytest.fixture
def lazy(empty_scene, tmp_path, monkeypatch):
    monkeypatch.setenv("NEPHELE_CACHE", str(tmp_path / "user_cache"))
    assert bpy.ops.nephele.import_dataset(kind="DEMO_SMALL") == {"FINISHED"}
    obj, infos = volume_ops.add_volume_clouds("cloud", TransferFunction.ramp(0.3, 1.0), scene=empty_scene,
                                              directory=str(tmp_path / "vol"), frames=(1, 3), mode=volume_ops.VOXELS,
                                              voxel_size=0.02, bake="lazy")
    assert infos == []
    return empty_scene, obj


def _baked(obj):
    """Frames whose file exists and holds exactly that frame's volume."""
    p = frame.params(obj)
    out = []
    for f in range(p["frames"][0], p["frames"][1] + 1):
        path = frame_path(data_ops.layer_dir(p), volume_ops.PREFIX, f - p["frames"][0] + 1)
        if path.is_file():
            assert file_key(path) == cache_key("volume", frame_params(p, f)), path
            out.append(f)
    return out


def test_background_bake_writes_every_frame_shown_frame_first(lazy):
    scene, obj = lazy
    scene.frame_set(2)
    job = volume_bake.BakeJob(obj, scene)
    assert job.frames == [2, 1, 3]
    assert _baked(obj) in ([], [2])  # frame_set itself writes the shown frame of a lazy layer
    job.start()
    t_end = time.time() + 300
    while not job.done and time.time() < t_end:  # the interface stays free meanwhile
        time.sleep(0.05)
    assert job.done and job.error is None and job.fraction == 1.0
    job.finish(obj)
    assert _baked(obj) == [1, 2, 3]
    p = frame.params(obj)
    assert p["value_max"] > 0.3 and p["empty"] is False


def test_a_stopped_bake_leaves_only_whole_files(lazy, tmp_path):
    scene, obj = lazy
    scene.frame_current = 1
    job = volume_bake.BakeJob(obj, scene)
    job.start()
    while not job.infos and not job.done:
        time.sleep(0.01)
    job.cancel()  # returns once the frame being written is finished
    assert 1 <= len(job.infos) < 3 or job.done
    job.finish(obj)
    assert _baked(obj) == sorted(i["frame"] for i in job.infos)
    leftovers = [f.name for f in data_ops.layer_dir(frame.params(obj)).iterdir()
                 if f.name.startswith(".") or ".tmp" in f.name or not f.name.endswith(".vdb")]
    assert leftovers == []  # no temporary or half-written file


def test_operator_bakes_headless_and_reports(lazy):
    scene, obj = lazy
    assert bpy.ops.nephele.bake_volume(name=obj.name) == {"FINISHED"}
    assert _baked(obj) == [1, 2, 3]
    # A second run finds every file current: it reuses them (one metadata read each).
    job = volume_bake.BakeJob(obj, scene)
    job.run()
    assert all(i["reused"] for i in job.infos)


def test_operator_without_a_volume_layer_says_so(empty_scene):
    with pytest.raises(RuntimeError, match="no volume layer"):
        bpy.ops.nephele.bake_volume()
