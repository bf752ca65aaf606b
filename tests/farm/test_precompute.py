"""Precompute: a scene's per-frame core tasks run on Dask into its content-addressed cache; renders read them."""

from pathlib import Path

import pytest

pytest.importorskip("bpy")

from nephele.core.pipeline import tasks  # noqa: E402
from nephele.core.pipeline.cache import Cache  # noqa: E402
from nephele.farm import cli  # noqa: E402
from nephele.farm.render import precompute_scene, render_sequence  # noqa: E402

SCENE = Path(__file__).with_name("contour_scene.py")
PARAMS = {"kind": "contour", "source": "demo:small", "var": "cloud", "level": 0.15, "hours_per_frame": 6.0,
          "frame_start": 1}


@pytest.fixture
def cluster(farm_cluster):
    return farm_cluster


def test_precompute_then_render_reads_cache(cluster, tmp_path, capsys):
    cache = Cache(tmp_path / "cache")
    frames = [1, 2, 3]
    expected = {f: tasks.plan(PARAMS, f) for f in frames}
    info = precompute_scene(SCENE, "1-3", scheduler=cluster.scheduler_address, cache_dir=cache.root, progress=False)
    assert info["objects"] == ["cloud"] and info["tasks"] == 3 and info["computed"] == 3
    entries = {}
    for f in frames:
        (kind, params), = expected[f]
        path = cache.file(kind, params)
        assert path.is_file()
        arrays = cache.load(kind, params)
        assert arrays["faces"].shape[0] > 100  # a real surface
        entries[f] = path.stat().st_mtime_ns

    # Again: everything is a hit, nothing recomputed.
    rc = cli.main(["precompute", str(SCENE), "--frames", "1-3", "--cache", str(cache.root),
                   "--scheduler", cluster.scheduler_address, "--quiet"])
    assert rc == 0 and "0 computed, 3 already cached" in capsys.readouterr().err

    # Render frames 1-4 with precompute: frame 4's task is computed, frames 1-3 are only read.
    res = render_sequence(SCENE, "1-4", tmp_path / "out", scheduler=cluster.scheduler_address, progress=False,
                          precompute=True, cache_dir=cache.root)
    assert res.ok and res.manifest["run"]["precompute"]["tasks"] == 4
    from nephele.farm.post import read_rgba

    px = read_rgba(res.paths[0])
    assert px[..., :3].std() > 0.05  # the cloud surface is in the picture
    for f in frames:
        (kind, params), = expected[f]
        assert cache.file(kind, params).stat().st_mtime_ns == entries[f]
    (kind, params), = tasks.plan(PARAMS, 4)
    assert cache.file(kind, params).is_file()
    files = sorted(p.name for p in (tmp_path / "cache" / "contour").rglob("*.npz"))
    assert len(files) == 4  # content-addressed: one entry per distinct task, no stray temporaries


def test_saved_blend_with_nephele_object_renders_without_addon(cluster, tmp_path):
    """A .blend saved with a contour object: workers open it, install the frame handler, the cloud moves."""
    import importlib.util

    import bpy
    import numpy as np

    from nephele.farm.post import read_rgba

    bpy.ops.wm.read_factory_settings(use_empty=True)
    spec = importlib.util.spec_from_file_location("contour_scene_blend", SCENE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.build(size=(48, 36))
    blend = tmp_path / "clouds.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_factory_settings(use_empty=True)

    res = render_sequence(blend, [1, 9], tmp_path / "out", scheduler=cluster.scheduler_address, progress=False)
    assert res.ok and res.rendered == [1, 9]
    a, b = (read_rgba(p) for p in res.paths)
    assert a.shape == (36, 48, 4) and a[..., :3].std() > 0.05
    assert np.abs(a - b).mean() > 0.01  # 48 model hours apart: the clouds moved
    # The updater cached its meshes beside the .blend, where the add-on looks.
    assert len(list((tmp_path / "clouds_nephele_cache" / "contour").rglob("*.npz"))) == 2
