"""Volume sequences in files, for the add-on and the farm alike: one ``.vdb`` per frame [1]_.

A sequence is what a Blender volume with ``is_sequence``, ``frame_start`` = the
sequence's first frame and ``frame_offset`` = 0 reads natively: files
``<prefix>_0001.vdb``, ``<prefix>_0002.vdb``, … numbered from 1.  In the voxel
mode each holds the resampled :class:`~nephele.core.volume.sparse.SparseVolume`
(``density`` and a colour grid); in the exact mode
(:mod:`nephele.core.volume.volume_atlas`) the ``support`` grid, with the values
atlas of that frame in an ``.exr`` of the same name, plus ``<prefix>_heights.exr``
(the heights atlas, one file: the grid is fixed).  The shader that reads the
atlases is built by :mod:`nephele.addon.volume_exact` (the paper's Fig. 2 [2]_).

Files are written through :mod:`.fileio` (OpenVDB and OpenImageIO, bundled
with Blender): to a temporary name in the same folder, then renamed, so a
crash never leaves a half-written frame.  EXR rows are stored top-down and
Blender reads them bottom-up, so atlas row 0 is written last.  No ``bpy``
here, so ``nephele volume`` writes sequences without the add-on.

References
----------
.. [1] K. Museth, "VDB: High-resolution sparse volumes with dynamic
   topology", ACM Trans. Graph. 32(3), 2013.
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 2.
"""

from pathlib import Path

import numpy as np

from .fileio import block_grid, oiio, vdb_metadata, write_image, write_vdb

DENSITY = "density"
"""Name of the opacity grid (Principled Volume's default density attribute)."""

SUPPORT = "support"
"""Name of the support grid."""


def write_exr(path, img, metadata=None):
    """Write an ``(h, w, 4)`` float32 atlas as a 32-bit float EXR (row 0 at the bottom, as Blender reads it)."""
    return write_image(path, np.asarray(img, np.float32)[::-1], pixel_type="float", metadata=metadata,
                       compression="zip")


def read_exr(path):
    """An atlas written by :func:`write_exr`, row 0 at the bottom, and its metadata."""
    io = oiio()
    inp = io.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"{path}: cannot read EXR: {io.geterror()}")
    spec = inp.spec()
    img = inp.read_image("float")
    meta = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    return np.asarray(img, np.float32)[::-1], meta


def exr_key(path):
    """The ``nephele_key`` metadata of an EXR (None if absent or unreadable)."""
    if not Path(path).is_file():
        return None
    try:
        io = oiio()
        inp = io.ImageInput.open(str(path))
        if inp is None:
            io.geterror()  # clear it: OpenImageIO complains at exit about unread errors
            return None
        key = inp.spec().get_string_attribute("nephele_key") or None
        inp.close()
        return key
    except (OSError, RuntimeError):
        return None


def write_support(path, support, support_size, metadata=None):
    """The ``support`` grid (1 in every voxel of ``support`` (n, 3)) as a ``.vdb``, atomically."""
    B = 8
    vox = np.asarray(support, np.int64).reshape(-1, 3)
    blocks, inverse = np.unique(np.floor_divide(vox, B), axis=0, return_inverse=True)
    data = np.zeros((blocks.shape[0], B, B, B), np.float32)
    loc = vox - blocks[inverse.reshape(-1)] * B
    data[inverse.reshape(-1), loc[:, 0], loc[:, 1], loc[:, 2]] = 1.0
    return write_vdb(path, [block_grid(SUPPORT, blocks, data, B, support_size)], metadata or {})


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
        bg = (
            float(volume.color[volume.density > 0].mean())
            if volume.density.size and (volume.density > 0).any()
            else 0.0
        )
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
    (:func:`write_exr`, :func:`write_support`).

    ``obj_params`` as for :func:`nephele.core.volume.volume_task.frame_params` (the task comes
    from :func:`nephele.core.pipeline.tasks.plan`, as in Blender and on the farm).  The file
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

    from .core.pipeline.cache import Cache, cache_key
    from .core.pipeline.tasks import plan, run
    from .core.volume.sparse import EXACT, SparseVolume

    t0 = time.perf_counter()
    (kind, params), = plan(dict(obj_params, kind="volume"), frame)
    key = cache_key(kind, params)
    path = frame_path(directory, prefix, number)
    exact = params.get("mode") == EXACT
    if exact:
        exr = path.with_suffix(".exr")
        reuse = reuse and exr_key(exr) == key
    if reuse and path.is_file() and file_key(path) == key:
        meta = vdb_metadata(path)
        return {"frame": frame, "path": str(path), "hours": params["hours"], "blocks": int(meta["nephele_blocks"]),
                "active_voxels": int(meta["nephele_active_voxels"]), "value_max": float(meta["nephele_value_max"]),
                "seconds": time.perf_counter() - t0, "reused": True, "cached": False}
    arrays = None
    if cache is not None:
        arrays = (cache if isinstance(cache, Cache) else Cache(cache)).load(kind, params)
    cached = arrays is not None
    if arrays is None:
        arrays = run(kind, params)
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
            from .core.files import check_space

            each = Path(out[0]["path"]).stat().st_size
            check_space(directory, each * (len(frames) - 1), f"the {len(frames) - 1} volume frames left "
                                                             f"({each:,} bytes each, as the first)", force=force)
        if progress is not None:
            progress(n, len(frames), out[-1])
    return out


__all__ = ["DENSITY", "SUPPORT", "bake_frame", "bake_sequence", "exr_key", "file_key", "frame_path", "read_exr",
           "write_exr", "write_support", "write_volume"]
