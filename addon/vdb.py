"""Sparse volumes into OpenVDB files: one ``.vdb`` per frame, a sequence Blender loads natively.

Uses the ``openvdb`` module bundled with Blender (exposed by
``bpy.utils.expose_bundled_modules()`` in the ``bpy`` wheel), so the farm
can write sequences without the add-on installed.  Each file is written to a
temporary name in the same directory and renamed: a crash never leaves a
half-written frame.

Files are named ``<prefix>_0001.vdb``, ``<prefix>_0002.vdb``, … numbered
from 1 at the sequence's first frame, which is what a Blender volume with
``is_sequence``, ``frame_start`` = that frame and ``frame_offset`` = 0 reads.

References
----------
.. [1] K. Museth, "VDB: High-resolution sparse volumes with dynamic
   topology", ACM Trans. Graph. 32(3), 2013.
"""

from pathlib import Path

import numpy as np

from ..fileio import block_grid, vdb_metadata, write_vdb

DENSITY = "density"
"""Name of the opacity grid (Principled Volume's default density attribute)."""


def frame_path(directory, prefix, number, digits=4):
    """Path of sequence file ``number`` (1-based)."""
    return Path(directory) / f"{prefix}_{int(number):0{digits}d}.vdb"


def write_volume(path, volume, *, metadata=None):
    """Write a :class:`~nephele.core.volume.sparse.SparseVolume` to ``path`` atomically.

    Grids: ``density`` (the transfer function's opacity) and, when the volume
    has one, the colour variable under its own name (e.g. ``altitude``),
    whose background is the mean stored value so that interpolation at the
    cloud's edge does not pull the colour toward zero.

    Returns the path.
    """
    grids = [block_grid(DENSITY, volume.blocks, volume.density, volume.block, volume.voxel_size)]
    if volume.color is not None and volume.color_name:
        bg = float(volume.color[volume.density > 0].mean()) if volume.density.size and (volume.density > 0).any() else 0.0
        grids.append(block_grid(volume.color_name, volume.blocks, volume.color, volume.block, volume.voxel_size, bg))
    return write_vdb(path, grids, metadata or {})


def file_key(path):
    """The ``nephele_key`` metadata of a ``.vdb`` file (None if absent or unreadable)."""
    try:
        return vdb_metadata(path).get("nephele_key")
    except (OSError, RuntimeError, ValueError, KeyError):
        return None


def bake_frame(obj_params, frame, number, directory, prefix="clouds", *, cache=None, reuse=True):
    """Write sequence file ``number`` (1-based) holding the volume at ``frame``.

    In the exact mode (``obj_params["mode"] == "exact"``) the ``.vdb`` holds
    the support grid and an ``.exr`` of the same name the values atlas
    (:mod:`.volume_exact`).

    ``obj_params`` as for :func:`nephele.core.volume.volume_task.frame_params`.  The file
    records the cache key of its exact inputs; with ``reuse`` an existing
    file with that key is kept (one metadata read).  ``cache``: a
    :class:`~nephele.core.pipeline.cache.Cache` or directory holding resampled volumes,
    e.g. filled by ``nephele precompute`` on Dask workers; an entry there is
    used instead of resampling.  Interactive bakes do not add entries (the
    .vdb files are the lasting result; a cache copy would double the disk use).

    Returns a dict: ``frame``, ``path``, ``hours``, ``blocks``,
    ``active_voxels``, ``value_max``, ``seconds``, ``reused``, ``cached``.
    """
    import time

    from ..core.pipeline.cache import Cache, cache_key
    from ..core.pipeline.tasks import run
    from ..core.volume.sparse import EXACT, SparseVolume
    from ..core.volume.volume_task import frame_params

    t0 = time.perf_counter()
    params = frame_params(obj_params, frame)
    key = cache_key("volume", params)
    path = frame_path(directory, prefix, number)
    exact = params.get("mode") == EXACT
    if exact:
        from .volume_exact import exr_key

        exr = path.with_suffix(".exr")
        reuse = reuse and exr_key(exr) == key
    if reuse and path.is_file() and file_key(path) == key:
        meta = vdb_metadata(path)
        return {"frame": frame, "path": str(path), "hours": params["hours"], "blocks": int(meta["nephele_blocks"]),
                "active_voxels": int(meta["nephele_active_voxels"]), "value_max": float(meta["nephele_value_max"]),
                "seconds": time.perf_counter() - t0, "reused": True, "cached": False}
    arrays = None
    if cache is not None:
        arrays = (cache if isinstance(cache, Cache) else Cache(cache)).load("volume", params)
    cached = arrays is not None
    if arrays is None:
        arrays = run("volume", params)
    if exact:
        return _write_exact(arrays, params, key, path, exr, cached, t0, frame)
    vol = SparseVolume.from_arrays(arrays, color_name=params["color_var"] or None)
    info = {
        "frame": frame, "path": str(path), "hours": params["hours"], "blocks": int(vol.blocks.shape[0]),
        "active_voxels": int(np.count_nonzero(vol.density)), "value_max": float(arrays["value_max"]),
        "reused": False, "cached": cached,
    }
    write_volume(path, vol, metadata={
        "nephele_key": key, "nephele_hours": params["hours"], "nephele_var": params["var"],
        "nephele_blocks": info["blocks"], "nephele_active_voxels": info["active_voxels"],
        "nephele_value_max": info["value_max"]})
    info["seconds"] = time.perf_counter() - t0
    return info


def _write_exact(arrays, params, key, path, exr, cached, t0, frame):
    """:func:`bake_frame`'s files for the exact mode: the values atlas and the support grid."""
    import time

    from .volume_exact import write_exr, write_support

    n = int(arrays["support"].shape[0])
    meta = {"nephele_key": key, "nephele_hours": params["hours"], "nephele_var": params["var"],
            "nephele_blocks": n, "nephele_active_voxels": n, "nephele_value_max": float(arrays["value_max"])}
    write_exr(exr, arrays["values"], meta)
    write_support(path, arrays["support"], float(arrays["support_size"]), meta)
    return {"frame": frame, "path": str(path), "hours": params["hours"], "blocks": n, "active_voxels": n,
            "value_max": float(arrays["value_max"]), "reused": False, "cached": cached,
            "seconds": time.perf_counter() - t0}


def bake_sequence(obj_params, frames, directory, prefix="clouds", *, cache=None, progress=None, reuse=True,
                  force=False):
    """Resample and write one ``.vdb`` per frame of ``frames`` (ascending ints) with :func:`bake_frame`.

    File ``k`` (1-based) holds ``frames[k-1]``, so ``frames`` must be
    consecutive for Blender's sequence to line up.  ``progress(i, n, info)``
    is called after each frame.  After the first frame, the frames left are
    sized from it; when they will not fit on the disk a
    :class:`~nephele.core.files.WriteError` says so before they are made
    (``force``: go on).

    Returns the list of :func:`bake_frame` dicts.
    """
    frames = [int(f) for f in frames]
    if not frames:
        return []
    if frames != list(range(frames[0], frames[0] + len(frames))):
        raise ValueError(f"frames must be consecutive, got {frames[:5]}...")
    out = []
    for n, frame in enumerate(frames, start=1):
        out.append(bake_frame(obj_params, frame, n, directory, prefix, cache=cache, reuse=reuse))
        if n == 1 and len(frames) > 1:
            from ..core.files import check_space

            each = Path(out[0]["path"]).stat().st_size
            check_space(directory, each * (len(frames) - 1), f"the {len(frames) - 1} volume frames left "
                                                             f"({each:,} bytes each, as the first)", force=force)
        if progress is not None:
            progress(n, len(frames), out[-1])
    return out


__all__ = ["DENSITY", "bake_frame", "bake_sequence", "file_key", "frame_path", "write_volume"]
