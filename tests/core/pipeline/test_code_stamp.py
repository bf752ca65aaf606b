"""Cache keys cannot go stale: editing any core module a task depends on changes its key."""

import shutil
from pathlib import Path

import pytest

import nephele.core as core
from nephele.core.pipeline import cache, codehash, registry, tasks

CORE = Path(core.__file__).resolve().parent

# Task kind -> (its module, the dependencies edited in a copy of the package).
KINDS = {
    "contour": (
        "contour_task.py",
        ["climate/grid.py", "climate/readers.py", "climate/synthetic.py", "surface/contour.py", "surface/mesh.py"],
    ),
    "volume": (
        "volume_task.py",
        ["climate/grid.py", "climate/readers.py", "volume/sparse.py", "volume/volume_atlas.py", "volume/transfer.py"],
    ),
    "advect_contour": (
        "advect_task.py",
        ["climate/grid.py", "climate/readers.py", "flow/advect.py", "flow/flows.py", "surface/contour.py"],
    ),
    "scatter": (
        "scatter_task.py",
        ["light/scatter.py", "light/phase.py", "volume/cloud_density.py", "texture/noise.py"],
    ),
    "muscle_frame": ("film.py", ["muscle/brownian.py", "muscle/lattice.py", "muscle/blobby.py", "muscle/molecules.py"]),
}
# Task kind -> the subpackage holding its module.
HOME = {
    "contour": "surface",
    "volume": "volume",
    "advect_contour": "flow",
    "scatter": "light",
    "muscle_frame": "muscle",
}


@pytest.fixture(scope="module")
def copy_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("pkg") / "core"
    shutil.copytree(CORE, root, ignore=shutil.ignore_patterns("__pycache__"))
    return root


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_registered_task_module_matches(kind):
    tasks.load_all()
    assert Path(registry.TASKS[kind].__code__.co_filename).name == KINDS[kind][0]
    assert len(registry.code_stamp(kind)) == 16


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_editing_a_dependency_changes_the_stamp(kind, copy_root):
    module, deps = KINDS[kind]
    before = codehash.code_stamp.__wrapped__(copy_root / HOME[kind] / module, copy_root)
    for dep in deps:
        f = copy_root / dep
        original = f.read_bytes()
        try:
            f.write_bytes(original + b"\n# edited\n")
            after = codehash.code_stamp.__wrapped__(copy_root / HOME[kind] / module, copy_root)
        finally:
            f.write_bytes(original)
        assert after != before, f"{kind}: editing {dep} left the stamp unchanged"
    assert codehash.code_stamp.__wrapped__(copy_root / HOME[kind] / module, copy_root) == before


def test_unrelated_module_does_not_change_scatter_stamp(copy_root):
    before = codehash.code_stamp.__wrapped__(copy_root / "light" / "scatter_task.py", copy_root)
    f = copy_root / "flow" / "advect.py"
    original = f.read_bytes()
    try:
        f.write_bytes(original + b"\n# edited\n")
        assert codehash.code_stamp.__wrapped__(copy_root / "light" / "scatter_task.py", copy_root) == before
    finally:
        f.write_bytes(original)


def test_cache_key_includes_the_code_stamp(monkeypatch):
    key = cache.cache_key("contour", {"a": 1})
    monkeypatch.setattr(registry, "code_stamp", lambda kind: "different")
    assert cache.cache_key("contour", {"a": 1}) != key


def test_compiled_kernels_enter_the_key(monkeypatch):
    # the film's meshes depend on which kernels ran (compiled or their NumPy twins, or another build)
    from nephele.core import native

    film, scatter = CORE / "muscle" / "film.py", CORE / "light" / "scatter_task.py"
    contour = CORE / "surface" / "contour_task.py"
    stamps = {}
    for ident in ("numpy", "0123456789abcdef"):
        monkeypatch.setattr(native, "identity", lambda ident=ident: ident)
        codehash.code_stamp.cache_clear()
        stamps[ident] = tuple(codehash.code_stamp(p) for p in (film, scatter, contour))
    codehash.code_stamp.cache_clear()
    assert stamps["numpy"][0] != stamps["0123456789abcdef"][0]
    assert stamps["numpy"][1] != stamps["0123456789abcdef"][1]  # the scattering's sweeps are compiled too
    assert stamps["numpy"][2] == stamps["0123456789abcdef"][2]  # no kernel behind the contours
