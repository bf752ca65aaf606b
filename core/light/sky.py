"""The sky seen from a cloud: an equirectangular panorama of radiance binned into the
direction bins of :mod:`.phase` (``6 n^2``, ``n = bins_per_face``: 96 by default), for
:func:`.scatter.solve`'s ``sky_radiance``.

A rendered world (Blender's Sky Texture, an HDRI) then lights the cloud from every direction
as it does in Cycles: :func:`nephele.addon.scatter_ops.bake_world` renders it and calls
:func:`panorama_radiance`.
"""

import numpy as np

from ..errors import DataError
from . import phase

LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights of linear RGB (Blender's default working space): the grey
solve lights a grey cloud with the luminance of a coloured sky (each channel of a grey
medium is lit by that channel alone, so the cloud's luminance is the luminance's solve)."""


def luminance(rgba):
    """Luminance (:data:`LUMINANCE`) of linear RGB(A) pixels (..., 3 or 4)."""
    return np.asarray(rgba)[..., :3] @ np.asarray(LUMINANCE, np.float32)


def _meridians(per_face):
    """Azimuths of the meridians that bound bins (the side faces' edges and their lines
    ``u = -1 + 2 i / n``): a pixel column is split there exactly, since a meridian cuts every
    row of a column alike."""
    u = -1.0 + 2.0 * np.arange(per_face) / per_face
    return np.mod(np.concatenate([k * np.pi / 2 + np.arctan(u) for k in range(4)]) + np.pi, 2 * np.pi) - np.pi


def panorama_radiance(pano, sub=None, bins_per_face=phase.N_PER_FACE):
    """Radiance of light travelling in each of the ``6 n^2`` bins (``n = bins_per_face``),
    averaged from an equirectangular panorama of the sky (for :func:`solve`'s ``sky_radiance``).

    Parameters
    ----------
    pano : (H, W) radiance seen looking toward each pixel's direction, in Blender's
        equirectangular convention (environment textures; Cycles' panoramic equirectangular
        camera with its default ±180°/±90° range pointed along +x with +z up): row 0 at the
        top, pixel ``(r, c)`` looks toward elevation ``pi/2 - pi (r + 1/2) / H`` and azimuth
        ``atan2(y, x) = pi - 2 pi (c + 1/2) / W`` (the centre column looks along +x, the
        left edge along -x, a quarter from the left along +y).  Light seen toward ``d``
        travels along ``-d``: it counts in ``phase.bin_of(-d)``.
    sub : sub-cells per pixel side (default: enough for 1024 rows).  Each pixel is split into
        ``sub x sub`` cells, also at the meridians and the horizon that bound bins, and each cell
        counts in its centre's bin with its exact solid angle (``dphi * d(sin elevation)``):
        the solid angles summed per bin are within 5e-4 of the bins' exact ones (3.3e-4 at
        128 x 256, 0.4 s).
    bins_per_face : the bins' layout (:func:`.phase.bins`), the solve's ``bins_per_face``.

    Returns
    -------
    (6 n^2,) float64: per bin, the solid-angle-weighted mean radiance of its pixels.
    """
    pano = np.asarray(pano, dtype=np.float64)
    if pano.ndim != 2 or min(pano.shape) < 1:
        raise DataError(f"a panorama must be a 2-D array, got shape {pano.shape}", field="panorama")
    if not np.all(np.isfinite(pano)) or np.any(pano < 0):
        raise DataError("panorama radiance must be finite and >= 0", field="panorama")
    n = phase.check_per_face(bins_per_face)
    idx, rows, cols, omega = _panorama_cells(*pano.shape, int(sub or -(-1024 // pano.shape[0])), n)
    power = np.bincount(idx, (omega * pano[rows[:, None], cols[None, :]]).ravel(), 6 * n * n)
    return power / np.bincount(idx, np.broadcast_to(omega, (len(rows), len(cols))).ravel(), 6 * n * n)


def panorama_solid_angles(shape, sub=None, bins_per_face=phase.N_PER_FACE):
    """Solid angle per bin that :func:`panorama_radiance` sums from a panorama of ``shape``
    (the bins' exact solid angles, up to the sub-cells' resolution)."""
    h, w = shape
    n = phase.check_per_face(bins_per_face)
    idx, rows, cols, omega = _panorama_cells(h, w, int(sub or -(-1024 // h)), n)
    return np.bincount(idx, np.broadcast_to(omega, (len(rows), len(cols))).ravel(), 6 * n * n)


def _panorama_cells(h, w, sub, per_face):
    """Sub-cells of an (h, w) panorama: bin of each (flat), pixel row and column of each
    row / column of cells, and their solid angles (rows x columns)."""
    if sub < 1:
        raise DataError(f"sub must be >= 1, got {sub}", field="sub")
    edges = np.unique(np.concatenate([np.pi - 2 * np.pi * np.arange(w * sub + 1) / (w * sub), _meridians(per_face)]))
    phi = 0.5 * (edges[:-1] + edges[1:])
    cols = np.minimum(((np.pi - phi) / (2 * np.pi) * w).astype(np.int64), w - 1)
    el_edges = np.unique(np.r_[np.pi / 2 - np.pi * np.arange(h * sub + 1) / (h * sub), 0.0])  # the horizon too
    el = 0.5 * (el_edges[:-1] + el_edges[1:])
    rows = np.minimum(((np.pi / 2 - el) / np.pi * h).astype(np.int64), h - 1)
    omega = np.diff(np.sin(el_edges))[:, None] * np.diff(edges)[None, :]
    toward = np.stack(np.broadcast_arrays(np.cos(el)[:, None] * np.cos(phi), np.cos(el)[:, None] * np.sin(phi),
                                          np.sin(el)[:, None]), -1)
    return phase.bin_of(-toward, per_face).ravel(), rows, cols, omega
