"""Cycles' device choice shared by the farm's workers and the scattering references."""

import pytest

bpy = pytest.importorskip("bpy")

from nephele.addon import scatter_scene as ss  # noqa: E402
from nephele.addon.render_device import DEVICES, use_device  # noqa: E402
from nephele.core.errors import DataError  # noqa: E402


def _gpus(kind):
    prefs = bpy.context.preferences.addons["cycles"].preferences
    try:
        prefs.compute_device_type = kind
    except TypeError:
        return []
    prefs.refresh_devices()
    return [d for d in prefs.devices if d.type == kind]


def test_cpu_and_unknown(empty_scene):
    empty_scene.render.engine = "CYCLES"
    empty_scene.cycles.device = "GPU"
    use_device(empty_scene, "CPU")
    assert empty_scene.cycles.device == "CPU"
    with pytest.raises(DataError, match="unknown device 'TPU'"):
        use_device(empty_scene, "TPU")


@pytest.mark.gpu  # skips where the host has that GPU
@pytest.mark.parametrize("kind", ["OPTIX", "CUDA"])
def test_missing_backend_names_host_and_what_cycles_sees(empty_scene, kind):
    if _gpus(kind):
        pytest.skip(f"this host has a {kind} device")
    empty_scene.render.engine = "CYCLES"
    with pytest.raises(DataError, match=f"no {kind} device on host .*Cycles sees: .*CPU"):
        use_device(empty_scene, kind)
    assert empty_scene.cycles.device == "CPU"  # left as it was


@pytest.mark.gpu
def test_gpu_backend_enables_only_its_devices(empty_scene):
    kind = next((k for k in DEVICES[1:] if _gpus(k)), None)
    if kind is None:
        pytest.skip("no GPU backend on this host (checked on a lent GPU by benchmarks/bench_scatter.py --ref-device)")
    ss.cycles_settings(empty_scene, 4, device=kind)
    prefs = bpy.context.preferences.addons["cycles"].preferences
    assert empty_scene.cycles.device == "GPU"
    assert all(d.use == (d.type == kind) for d in prefs.devices)
