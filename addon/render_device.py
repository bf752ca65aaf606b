"""Which device Cycles renders on: the CPU or every GPU of one compute backend.

Shared by the farm's workers (``nephele render --device``), the scattering
references and any headless script; needs no add-on, only ``bpy``.
"""

import socket

from ..core.errors import DataError

DEVICES = ("CPU", "OPTIX", "CUDA", "HIP", "METAL", "ONEAPI")


def use_device(scene, device):
    """Render ``scene`` with Cycles on ``device``: "CPU", or a backend ("OPTIX", "CUDA", ...)
    with every GPU of that backend enabled and the CPU off.  Raises :class:`DataError` naming
    the host and what Cycles sees when the backend has no device here."""
    if device == "CPU":
        scene.cycles.device = "CPU"
        return
    if device not in DEVICES:
        raise DataError(f"unknown device {device!r}; expected one of {', '.join(DEVICES)}", field="--device")
    import bpy  # here, so that clients without bpy can check names against DEVICES

    prefs = bpy.context.preferences.addons["cycles"].preferences
    try:
        prefs.compute_device_type = device
    except TypeError:  # a backend this Blender build lacks: no device found below
        pass
    prefs.refresh_devices()
    found = [d for d in prefs.devices if d.type == device]
    if not found:
        have = sorted({d.type for d in prefs.devices})
        raise DataError(
            f"no {device} device on host {socket.gethostname()} (Cycles sees: {', '.join(have) or 'none'}); "
            "use --device CPU or run on GPU nodes",
            field="--device",
        )
    for d in prefs.devices:
        d.use = d.type == device
    scene.cycles.device = "GPU"
