import numpy as np

from nephele.core.pipeline import registry, tasks
from nephele.core.pipeline.cache import Cache, cache_key, default_cache_dir


def test_key_is_canonical_and_sensitive():
    assert cache_key("k", {"a": 1, "b": [1, 2]}) == cache_key("k", {"b": [1, 2], "a": 1})
    assert cache_key("k", {"a": 1}) != cache_key("k", {"a": 1.5})
    assert cache_key("k", {"a": np.float32(2.0)}) == cache_key("k", {"a": 2.0})


def test_store_load_roundtrip_and_corrupt_entry(tmp_path):
    c = Cache(tmp_path / "c")
    assert c.load("mesh", {"t": 1}) is None
    p = c.store("mesh", {"t": 1}, {"v": np.arange(6.0).reshape(2, 3)})
    assert ("mesh", {"t": 1}) in c
    np.testing.assert_array_equal(c.load("mesh", {"t": 1})["v"], np.arange(6.0).reshape(2, 3))
    assert not list(p.parent.glob(".tmp-*"))
    p.write_bytes(b"not a zip")
    assert c.load("mesh", {"t": 1}) is None
    assert not p.exists()


def test_run_cached_computes_once(tmp_path):
    calls = []

    @registry.task("_test_square")
    def square(params):
        calls.append(params)
        return {"y": np.array(params["x"]) ** 2}

    for _ in range(3):
        out = tasks.run_cached("_test_square", {"x": 3}, tmp_path)
    assert out["y"] == 9 and len(calls) == 1
    del registry.TASKS["_test_square"]


def test_default_cache_dir_beside_blend(tmp_path):
    assert default_cache_dir(tmp_path / "scene.blend") == tmp_path / "scene_nephele_cache"
