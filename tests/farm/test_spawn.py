"""The farm with its workers started by ``spawn``, the only start method Windows has (and macOS's
default): a worker may need nothing it could only have inherited from a forked parent."""

import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
dask = pytest.importorskip("dask")

from nephele.farm import worker  # noqa: E402
from nephele.farm.cluster import local_cluster  # noqa: E402
from nephele.farm.render import render_sequence  # noqa: E402

SCENE = Path(__file__).with_name("cube_scene.py")


def _inherited():
    return hasattr(sys.modules.get("nephele.farm.worker"), "_parent_only")


def test_spawned_workers_render(tmp_path, monkeypatch):
    monkeypatch.setattr(worker, "_parent_only", True, raising=False)  # a forked worker would have it
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn"}):
        cluster = local_cluster(workers=1)
    try:
        res = render_sequence(SCENE, "1-2", tmp_path / "out", scheduler=cluster.scheduler_address, progress=False)
        from distributed import Client

        with Client(cluster.scheduler_address) as client:
            seen = client.run(_inherited)
    finally:
        cluster.close()
    assert res.ok and res.rendered == [1, 2]
    assert sorted(p.name for p in (tmp_path / "out").glob("*.png")) == ["frame_0001.png", "frame_0002.png"]
    assert seen and not any(seen.values())  # started clean: spawned, not forked
