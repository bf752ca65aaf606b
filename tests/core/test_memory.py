"""Memory before it runs out (issue 41): one helper for what is available, and every operation whose
memory grows with its input refusing in one line, before allocating, when it would not fit.

The fast tests lower the limit with ``NEPHELE_MEMORY_LIMIT`` (the same path a user sharing a node takes);
the ``ulimit -v`` tests run a child process under a real address-space limit.
"""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.memory import available_memory, check_memory, format_bytes, parse_bytes


def test_available_memory_is_the_least_of_the_limits(monkeypatch):
    free = available_memory()
    assert free is not None and free > 0
    monkeypatch.setenv("NEPHELE_MEMORY_LIMIT", "300M")
    assert available_memory() == min(free, 300 << 20)
    assert parse_bytes("2G") == 2 << 30 and parse_bytes("512mb") == 512 << 20 and parse_bytes("1000") == 1000
    monkeypatch.setenv("NEPHELE_MEMORY_LIMIT", "lots")
    with pytest.raises(DataError, match="NEPHELE_MEMORY_LIMIT"):
        available_memory()


def test_check_memory_is_one_line_naming_the_size_and_what_to_change():
    assert check_memory(10, "x", available=100) == 10
    with pytest.raises(DataError) as err:
        check_memory(3e9, "contouring a 2000x1000x100 grid", hint="contour a coarser grid", available=1e9,
                     field="values")
    assert str(err.value) == ("field 'values': contouring a 2000x1000x100 grid needs about 3.0 GB of memory, more than "
                              "the 1.0 GB available; contour a coarser grid")
    assert format_bytes(1536) == "1.5 KB"


def _child(code, limit_kb):
    """Run ``code`` in a child Python under ``ulimit -v limit_kb``; its stdout and return code."""
    script = f"import resource; resource.setrlimit(resource.RLIMIT_AS, ({limit_kb * 1024}, {limit_kb * 1024}))\n"
    script += textwrap.dedent(code)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    return out.stdout + out.stderr, out.returncode


def test_ulimit_v_is_seen_and_a_contour_refused_before_allocating():
    """Under ``ulimit -v``, the limit is what is available, and a contour that would pass it is refused
    with a DataError, not a MemoryError half-way (or the kernel's OOM killer)."""
    out, code = _child("""
        import numpy as np
        from nephele.core.memory import available_memory
        from nephele.core.surface.contour import isosurface, regular_points
        from nephele.core.errors import DataError
        print("available", available_memory())
        values = np.zeros((60, 400, 400), np.float32)  # 9.6 M cells: about 4.3 GB at the worst
        try:
            isosurface(regular_points(values.shape), values, 0.5)
        except DataError as exc:
            print("refused:", exc)
    """, 1_500_000)
    assert code == 0, out
    have = int(out.split("available ")[1].split()[0])
    assert 0 < have < 1_500_000 * 1024
    assert "refused: field 'values': contouring a 400x400x60 grid (cubes) needs about 4.3 GB" in out


@pytest.fixture
def little(monkeypatch):
    monkeypatch.setenv("NEPHELE_MEMORY_LIMIT", "20M")


def test_contour_of_a_huge_grid(little):
    from nephele.core.surface.contour import isosurface, regular_points

    values = np.zeros((20, 60, 100), np.float32)
    with pytest.raises(DataError, match=r"contouring a 100x60x20 grid \(cubes\) needs about 54.0 MB.*coarser grid"):
        isosurface(regular_points(values.shape), values, 0.5)


def test_splats(little):
    from nephele.core.splats.camera import Camera
    from nephele.core.splats.kernel import splat_kernel
    from nephele.core.splats.render import render_splats
    from nephele.core.splats.samples import Splats

    k = splat_kernel()
    sp = Splats(np.zeros((10, 3)), np.broadcast_to(np.eye(3) * 0.1, (10, 3, 3)).copy(), np.ones((10, 3)),
                np.ones(10), np.zeros((10, 3)), k.radius)
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0))
    with pytest.raises(DataError, match="splatting 10 splats into 2000x2000 pixels needs about .*smaller image"):
        render_splats(sp, k, cam, 2000, 2000)


def test_blobby_surface(little):
    from nephele.core.muscle.blobby import blobby_surface

    n = 50
    with pytest.raises(DataError, match="a blobby surface of 50 Gaussians at spacing 0.002 needs .*raise the spacing"):
        blobby_surface(np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)), np.full((n, 3), 0.1), np.ones(n), 0.5,
                       0.002)


def test_flow_volume(little):
    from nephele.core.flowvol.volume import flow_volume

    with pytest.raises(DataError,
                       match=r"a flow volume of up to 200,000 points needs about 500.0 MB.*lower max_points"):
        flow_volume(lambda p, t: np.ones_like(p), [0, 0, 0], 0.5, 1.0)
    fv = flow_volume(lambda p, t: np.ones_like(p), [0, 0, 0], 0.5, 1.0, sides=8, max_points=5000)  # fits
    assert len(fv.vertices) > 0


def test_scattering_solve_task(little):
    from nephele.core.light.scatter_task import solve_task, task_params
    from nephele.core.volume.cloud_density import CloudParams

    params = task_params(CloudParams(shape=(48, 64, 64), size=(1.0, 1.0, 0.75)))
    with pytest.raises(DataError, match=r"the scattering solve on a 64x64x48 grid needs about 1.6 GB.*lower the grid"):
        solve_task(params)


def test_volume_resample(little):
    from nephele.core.climate import open_dataset
    from nephele.core.volume.sparse import resample
    from nephele.core.volume.transfer import TransferFunction

    ds = open_dataset("demo:small")
    with pytest.raises(DataError,
                       match=r"resampling .* blocks of 4\^3 voxels \(voxel size 0.002\).*raise the voxel size"):
        resample(ds.grid, ds.read("cloud", 0), TransferFunction.ramp(0.05, 1.0), voxel_size=0.002)


def test_the_scatter_cli_refuses_in_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "scatter"
    run = subprocess.run([sys.executable, "-m", "nephele.farm.cli", "scatter", "--grid", "256x256x192", "--out",
                          str(out)],
                         capture_output=True, text=True, timeout=300, env={**__import__("os").environ,
                                                                            "NEPHELE_MEMORY_LIMIT": "4G"})
    assert run.returncode == 2, run.stderr
    lines = [ln for ln in run.stderr.splitlines() if ln.strip() and "note:" not in ln]
    assert lines == ["nephele scatter: error: field 'grid': the scattering solve on a 256x256x192 grid needs about "
                     "100.7 GB of memory, more than the 4.3 GB available; lower the grid or the bins per face"], lines
    assert not out.exists()  # refused before anything was written
