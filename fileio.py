"""Images and volumes in files, for the add-on and the farm alike.

OpenImageIO and OpenVDB ship inside Blender (and the ``bpy`` wheel), not as
core dependencies, so they are imported on first use: from the environment
when installed there, else after ``bpy.utils.expose_bundled_modules()``.  No
Blender UI module is imported, so the farm reads and writes frames, atlases
and ``.vdb`` files without loading the add-on.  Every file is written with
:func:`nephele.core.files.atomic_write`.

References
----------
.. [1] K. Museth, "VDB: High-resolution sparse volumes with dynamic
   topology", ACM Trans. Graph. 32(3), 2013.
"""

import importlib
from pathlib import Path

import numpy as np

from .core.errors import DataError
from .core.files import atomic_write


def bundled(name):
    """The module ``name`` (``"OpenImageIO"``, ``"openvdb"``), exposing bpy's bundled modules if needed."""
    try:
        return importlib.import_module(name)
    except ImportError:
        import bpy

        bpy.utils.expose_bundled_modules()
        return importlib.import_module(name)


def oiio():
    """The ``OpenImageIO`` module."""
    return bundled("OpenImageIO")


def openvdb():
    """The ``openvdb`` module."""
    return bundled("openvdb")


# --- images -------------------------------------------------------------------------------------


_TEXT_CACHE = {}


def text_mask(string, size):
    """``string`` drawn by Blender's font engine (``blf``, the interface font) as a ``(h, w)`` float alpha mask.

    ``size`` is pixels per em; every string of one size gets the same height
    (:func:`nephele.core.annotate.canvas.line_height`), its baseline at the
    same row, so lines line up.  OpenImageIO in the bpy wheel has no FreeType;
    ``blf`` draws into an image buffer without a GPU or a window.
    """
    import bpy  # noqa: F401  (blf and imbuf are Blender's own modules, importable once bpy is)

    # isort: split
    import blf
    import imbuf

    from .core.annotate.canvas import line_height

    key = (str(string), int(size))
    hit = _TEXT_CACHE.get(key)
    if hit is not None:
        return hit
    fid = 0  # Blender's default (interface) font
    blf.size(fid, int(size))
    pad = max(1, int(size) // 8)
    width = int(np.ceil(blf.dimensions(fid, key[0])[0])) + 2 * pad
    height = line_height(size)
    ib = imbuf.new((max(1, width), height))
    with blf.bind_imbuf(fid, ib):
        blf.color(fid, 1.0, 1.0, 1.0, 1.0)
        blf.position(fid, pad, int(round(0.3 * size)), 0)
        blf.draw_buffer(fid, key[0])
    if hasattr(ib, "with_buffer"):  # Blender 5.1+
        with ib.with_buffer() as buf:
            alpha = np.array(buf, copy=True)[::-1, :, 3]
    else:  # older Blenders: no pixel access from Python, so through a PNG
        import tempfile

        with tempfile.TemporaryDirectory(prefix="nephele-text-") as tmp:
            imbuf.write(ib, filepath=str(Path(tmp) / "text.png"))
            alpha = read_image(Path(tmp) / "text.png")[:, :, 3]
    ib.free()
    mask = alpha.astype(np.float32) / 255.0 if alpha.dtype == np.uint8 else alpha.astype(np.float32)
    if len(_TEXT_CACHE) > 4096:
        _TEXT_CACHE.clear()
    _TEXT_CACHE[key] = mask
    return mask



def read_image(path):
    """All channels of an image file as ``(H, W, C)`` float32 (rows top-down, as stored)."""
    io = oiio()
    buf = io.ImageBuf(str(path))
    if buf.has_error:
        raise DataError(f"cannot read image: {buf.geterror()}", path=path)
    return np.asarray(buf.get_pixels(io.FLOAT), dtype=np.float32)


def write_image(path, pixels, *, pixel_type=None, metadata=None, compression=None):
    """Write ``(H, W, C)`` values atomically; returns the path.

    Parameters
    ----------
    path : str or Path
        The format follows the extension (``.png``, ``.exr``, ...).
    pixels : array_like
        Rows top-down.  Integer files store values in [0, 1] (clipped).
    pixel_type : str, optional
        OpenImageIO's type name: ``"uint8"``, ``"half"``, ``"float"``...  Default:
        ``"half"`` for ``.exr``, ``"uint8"`` otherwise.
    metadata : dict, optional
        String attributes stored in the header.
    compression : str, optional
        e.g. ``"zip"`` for EXR.
    """
    io = oiio()
    path = Path(path)
    if pixel_type is None:
        pixel_type = "half" if path.suffix.lower() == ".exr" else "uint8"
    px = np.asarray(pixels, dtype=np.float32)
    if px.ndim == 2:
        px = px[..., None]
    if pixel_type.startswith(("uint", "int")):
        px = np.clip(px, 0.0, 1.0)
    px = np.ascontiguousarray(px)
    h, w, c = px.shape
    spec = io.ImageSpec(w, h, c, pixel_type)
    if compression:
        spec.attribute("compression", compression)
    for k, v in (metadata or {}).items():
        spec.attribute(str(k), str(v))
    with atomic_write(path) as tmp:
        out = io.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise DataError(f"cannot write image: {io.geterror()}", path=path)
        ok = out.write_image(px)
        err = "" if ok else out.geterror()
        out.close()
        if not ok:
            raise DataError(f"cannot write image: {err}", path=path)
    return path


# --- volumes --------------------------------------------------------------------------------------


def block_grid(name, blocks, data, block, voxel_size, background=0.0):
    """A sparse float fog grid from ``block``³ blocks: ``data[i]`` fills block ``blocks[i]`` (index / block).

    Voxel index ``(a, b, c)`` sits at ``voxel_size * (a, b, c)`` (OpenVDB's linear transform);
    voxels equal to ``background`` stay inactive, and values are stored as 16-bit floats.
    """
    vdb = openvdb()
    grid = vdb.FloatGrid(float(background))
    for b, a in zip(blocks, data):
        # Voxels equal to the background become inactive, so the tree stays sparse.
        grid.copyFromArray(np.ascontiguousarray(a, dtype=np.float32), ijk=tuple(int(c) * block for c in b))
    grid.transform = vdb.createLinearTransform(voxelSize=float(voxel_size))
    grid.name = name
    grid.gridClass = vdb.GridClass.FOG_VOLUME
    # 16-bit floats on disk: opacity to ~1e-3, altitude to ~8 m; half the size.
    grid.saveFloatAsHalf = True
    return grid


def dense_grids(grids, size):
    """Float grids from ``{name: (nz, ny, nx) array}`` filling the box ``size`` (x, y, z).

    Voxel ``(k, j, i)`` is centred at ``((i+.5)dx, (j+.5)dy, (k+.5)dz)`` in object space.
    """
    vdb = openvdb()
    shape = next(iter(grids.values())).shape
    h = np.asarray(size, float) / np.asarray(shape[::-1])
    xf = vdb.createLinearTransform([[h[0], 0, 0, 0], [0, h[1], 0, 0], [0, 0, h[2], 0],
                                    [0.5 * h[0], 0.5 * h[1], 0.5 * h[2], 1]])
    out = []
    for name, a in grids.items():
        g = vdb.FloatGrid()
        g.copyFromArray(np.ascontiguousarray(np.asarray(a, np.float32).transpose(2, 1, 0)))
        g.name = name
        g.transform = xf
        out.append(g)
    return out


def write_vdb(path, grids, metadata=None):
    """Write openvdb ``grids`` (and string ``metadata``) to a ``.vdb`` file atomically; returns the path."""
    vdb = openvdb()
    kw = {} if metadata is None else {"metadata": {str(k): str(v) for k, v in metadata.items()}}
    with atomic_write(path) as tmp:
        vdb.write(str(tmp), grids=list(grids), **kw)
    return Path(path)


def read_grid(path, name="density"):
    """Read grid ``name`` of a ``.vdb`` file: ``(dense array [x, y, z], index origin, voxel size)``.

    For tests and checks; ``(None, None, voxel size)`` for an empty grid.
    """
    vdb = openvdb()
    grid = vdb.read(str(path), name)
    vs = grid.transform.voxelSize()[0]
    if grid.activeVoxelCount() == 0:
        return None, None, vs
    lo, hi = grid.evalActiveVoxelBoundingBox()
    shape = tuple(i1 - i0 + 1 for i0, i1 in zip(lo, hi))
    a = np.zeros(shape, dtype=np.float32)
    grid.copyToArray(a, ijk=lo)
    return a, np.array(lo), vs


def vdb_metadata(path):
    """The file-level metadata of a ``.vdb`` file (a dict)."""
    return openvdb().readMetadata(str(path))


__all__ = ["block_grid", "bundled", "dense_grids", "oiio", "openvdb", "read_grid", "read_image", "vdb_metadata",
           "write_image", "write_vdb"]
