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


def test_source_stamp_of_an_override_name_follows_the_file(tmp_path):
    """A file read with overrides is named path?key=value&file=ID (the ID taken at import): its cache
    identity must still change when the file does, or a saved scene or a farm worker would be served
    results made from the old file."""
    import os

    from nephele.core.pipeline.cache import source_stamp

    f = tmp_path / "data.nc"
    f.write_bytes(b"one")
    name = f"{f}?radius=6371220.0&file=abc123"
    before = source_stamp(name)
    assert before.startswith(source_stamp(f)) and "radius=6371220.0" in before and "abc123" not in before
    assert source_stamp(f"{f}?radius=6371229.0&file=abc123") != before  # other overrides, other results
    f.write_bytes(b"two!")
    os.utime(f, ns=(1, 2))
    assert source_stamp(name) != before
    assert source_stamp("demo:small") == "demo:small"
