"""Dome cameras: fisheye pixel <-> direction mappings, cube-map and equirect remapping, stereo eyes.

Conventions
-----------
Directions live in the *theatre frame*, which is also Blender's world frame
for a dome camera at the origin with no rotation:

* ``x`` to the audience's right, ``y`` forward (the dome's front horizon),
  ``z`` up (vertical);
* a dome tilted by ``tilt`` degrees has its zenith tipped forward:
  ``zenith = (0, sin tilt, cos tilt)``.

Pixel coordinates ``(col, row)`` are floats with integer values at pixel
centres: the top-left pixel is ``(0, 0)`` and the image spans
``[-0.5, width - 0.5] x [-0.5, height - 0.5]``; rows grow downwards.

Every dome image is a fisheye whose lens axis is the dome's zenith, seen from
the dome's centre (non-mirrored, as from inside):

* **domemaster** -- square, ``fov`` (180 deg) across the width, zenith at the
  centre, the front at the bottom and the audience's right on the right.
* **omnimax** -- the 15-perf 70 mm frame (70.41 x 52.63 mm, 2048 x 1500 by
  default), ``fov`` = 180 deg across the frame width, the lens centre
  ``lens_shift`` frame heights (0.16) *below* the frame centre so most of the
  circle's lower half -- the back of the dome over the seats -- falls off the
  film.  As on the film, the front of the dome is at the *top* (the image is a
  domemaster turned by 180 deg, then truncated).  With the default 25 deg tilt
  the frame reaches 22 deg below the horizon at the front, 180 deg across and
  about 110 deg above the front horizon at the back (quoted for the first
  theatre: 100 deg; an exact f-theta lens of 180 deg across 2048 px cannot
  give both that and 22 deg below within 1500 px).

Lenses: ``equidistant`` (f-theta, ``r = R theta / theta_max``) or
``equisolid`` (``r = R sin(theta/2) / sin(theta_max/2)``), ``R = width / 2``.

Cube maps are six 90 deg perspective faces of ``n x n`` pixels named by
:data:`CUBE_FACES`, each a non-mirrored view with (forward, up) axes given in
:data:`CUBE_AXES`.  Equirectangular images have longitude 0 (the front, +y) at
the centre column, +90 deg (right, +x) to the right, the back at both edges,
latitude +90 at the top.

Stereo uses a fixed left-right eye baseline along the theatre ``x`` axis (see
:func:`stereo_eyes`).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 7:
   2048 x 1500, counter-distorted for Omnimax projection onto a tilted dome,
   in stereo with two projectors).
.. [2] N. Max, "Computer graphics distortion for IMAX and OMNIMAX projection",
   Proc. Nicograph '83, 137-159, 1983.
"""

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import DataError

PRESETS = ("domemaster", "omnimax")
LENSES = ("equidistant", "equisolid")
SOURCES = ("cube", "equirect")

PRESET_DEFAULTS = {
    "domemaster": {"width": 2048, "height": 2048, "fov": 180.0, "tilt": 0.0, "lens_shift": 0.0},
    "omnimax": {"width": 2048, "height": 1500, "fov": 180.0, "tilt": 25.0, "lens_shift": 0.16},
}
"""Default frame size, field of view (deg across the width), dome tilt (deg) and lens shift."""

OMNIMAX_FILM_MM = (70.41, 52.63)
"""The 15-perf 70 mm frame's projectable area, width x height in mm."""

CUBE_FACES = ("front", "right", "back", "left", "up", "down")
CUBE_AXES = {
    # face: (forward, up) in the theatre frame; right = forward x up.
    "front": ((0, 1, 0), (0, 0, 1)),
    "right": ((1, 0, 0), (0, 0, 1)),
    "back": ((0, -1, 0), (0, 0, 1)),
    "left": ((-1, 0, 0), (0, 0, 1)),
    "up": ((0, 0, 1), (0, -1, 0)),
    "down": ((0, 0, -1), (0, 1, 0)),
}


def _cube_basis():
    """(6, 3, 3): per face the rows right, up, forward."""
    out = np.empty((6, 3, 3))
    for i, name in enumerate(CUBE_FACES):
        f, u = (np.asarray(v, dtype=np.float64) for v in CUBE_AXES[name])
        out[i] = (np.cross(f, u), u, f)
    return out


_CUBE = _cube_basis()


def _check_finite(value, field):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DataError(f"must be a number, got {value!r}", field=field) from None
    if not math.isfinite(v):
        raise DataError(f"must be finite, got {value!r}", field=field)
    return v


def _check_size(value, field):
    try:
        ok = not isinstance(value, bool) and int(value) == value and int(value) > 0
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise DataError(f"must be a positive whole number of pixels, got {value!r}", field=field)
    return int(value)


@dataclass(frozen=True)
class DomeCamera:
    """A dome frame: size, lens, field of view, tilt and lens shift (see the module notes).

    Build it with :func:`dome_camera`, which checks the values.

    Attributes
    ----------
    preset : str
        ``"domemaster"`` or ``"omnimax"`` (sets the orientation: front at the
        bottom or at the top).
    width, height : int
        Frame size in pixels.
    fov : float
        Degrees spanned by the fisheye across the frame width (the circle's
        diameter is the width).
    tilt : float
        Degrees the dome's zenith (the lens axis) is tipped forward from vertical.
    lens : str
        ``"equidistant"`` or ``"equisolid"``.
    lens_shift : float
        Lens centre below the frame centre, in frame heights.
    """

    preset: str
    width: int
    height: int
    fov: float
    tilt: float
    lens: str
    lens_shift: float

    @property
    def centre(self):
        """Pixel coordinates (col, row) of the lens centre."""
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0 + self.lens_shift * self.height

    @property
    def radius(self):
        """Pixels from the lens centre to the ``fov / 2`` circle."""
        return self.width / 2.0

    @property
    def basis(self):
        """(3, 3) rows: image right, image up and lens axis in the theatre frame."""
        t = math.radians(self.tilt)
        axis = np.array([0.0, math.sin(t), math.cos(t)])
        back = np.array([0.0, -math.cos(t), math.sin(t)])
        up = back if self.preset == "domemaster" else -back
        return np.stack([np.cross(axis, up), up, axis])

    def _r_of_theta(self, theta):
        half = math.radians(self.fov) / 2.0
        if self.lens == "equidistant":
            return self.radius * theta / half
        return self.radius * np.sin(theta / 2.0) / math.sin(half / 2.0)

    def _theta_of_r(self, r):
        half = math.radians(self.fov) / 2.0
        if self.lens == "equidistant":
            return r / self.radius * half
        return 2.0 * np.arcsin(np.clip(r / self.radius * math.sin(half / 2.0), -1.0, 1.0))

    def pixel_to_direction(self, col, row):
        """Unit directions (theatre frame) seen at pixel coordinates.

        Parameters
        ----------
        col, row : array_like
            Pixel coordinates (broadcast together).

        Returns
        -------
        dirs : (..., 3) float64 array
            Unit vectors; NaN outside the fisheye circle.
        inside : (...) bool array
            Whether the pixel lies within ``fov / 2`` of the lens axis.
        """
        cx, cy = self.centre
        dx = np.asarray(col, dtype=np.float64) - cx
        dy = cy - np.asarray(row, dtype=np.float64)
        r = np.hypot(dx, dy)
        inside = r <= self.radius * (1 + 1e-12)
        theta = self._theta_of_r(np.where(inside, r, 0.0))
        s = np.sin(theta) / np.where(r > 0, r, 1.0)
        lens = np.stack([dx * s, dy * s, np.cos(theta)], axis=-1)
        dirs = lens @ self.basis
        dirs[~inside] = np.nan
        return dirs, inside

    def direction_to_pixel(self, dirs):
        """Pixel coordinates of directions (theatre frame; need not be unit length).

        Returns
        -------
        col, row : float64 arrays
            Pixel coordinates (may fall outside the frame for a truncated frame).
        visible : bool array
            Within ``fov / 2`` of the lens axis and inside the frame.
        """
        d = np.asarray(dirs, dtype=np.float64)
        lens = d @ self.basis.T
        a, b, c = lens[..., 0], lens[..., 1], lens[..., 2]
        sin_t = np.hypot(a, b)
        theta = np.arctan2(sin_t, c)
        r = self._r_of_theta(theta)
        scale = np.where(sin_t > 0, r / np.where(sin_t > 0, sin_t, 1.0), 0.0)
        cx, cy = self.centre
        col = cx + a * scale
        row = cy - b * scale
        half = math.radians(self.fov) / 2.0
        visible = (
            (theta <= half + 1e-12)
            & (col >= -0.5)
            & (col <= self.width - 0.5)
            & (row >= -0.5)
            & (row <= self.height - 0.5)
        )
        return col, row, visible

    def elevation_row(self, elevation, azimuth=0.0):
        """Row and column where a direction at ``elevation`` deg above the horizon,
        ``azimuth`` deg right of the front, lands (e.g. the horizon: elevation 0)."""
        el, az = np.radians(elevation), np.radians(azimuth)
        d = np.stack(np.broadcast_arrays(np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)), axis=-1)
        col, row, _ = self.direction_to_pixel(d)
        return row, col


def dome_camera(preset="omnimax", *, width=None, height=None, fov=None, tilt=None, lens="equidistant", lens_shift=None):
    """A checked :class:`DomeCamera`; unset values come from :data:`PRESET_DEFAULTS`.

    A domemaster given only ``width`` (or ``height``) stays square.

    Raises
    ------
    DataError
        Unknown preset or lens, ``fov`` not in (0, 360], a size that is not a
        positive integer, ``tilt`` outside [-90, 90], a non-finite value.
    """
    if preset not in PRESETS:
        raise DataError(f"unknown dome preset {preset!r}; choose one of {', '.join(PRESETS)}", field="preset")
    if lens not in LENSES:
        raise DataError(f"unknown lens {lens!r}; choose one of {', '.join(LENSES)}", field="lens")
    d = PRESET_DEFAULTS[preset]
    if preset == "domemaster" and (width is None) != (height is None):
        width = height = width if width is not None else height
    width = _check_size(d["width"] if width is None else width, "width")
    height = _check_size(d["height"] if height is None else height, "height")
    fov = _check_finite(d["fov"] if fov is None else fov, "fov")
    if not 0.0 < fov <= 360.0:
        raise DataError(f"field of view must be in (0, 360] degrees, got {fov:g}", field="fov")
    tilt = _check_finite(d["tilt"] if tilt is None else tilt, "tilt")
    if not -90.0 <= tilt <= 90.0:
        raise DataError(f"dome tilt must be in [-90, 90] degrees, got {tilt:g}", field="tilt")
    lens_shift = _check_finite(d["lens_shift"] if lens_shift is None else lens_shift, "lens_shift")
    return DomeCamera(preset, width, height, fov, tilt, lens, lens_shift)


# --- sources: cube faces and equirectangular images -------------------------------------------


def direction_to_cube(dirs, n):
    """Face index (into :data:`CUBE_FACES`) and pixel coordinates on an ``n x n`` face."""
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
    xmaj = (ax >= ay) & (ax >= az)
    ymaj = ~xmaj & (ay >= az)
    # Face coordinates (right, up) / forward; the sign conventions of CUBE_AXES folded in.
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(xmaj, -y / x, np.where(ymaj, x / y, x / az))
        b = np.where(xmaj, z / ax, np.where(ymaj, z / ay, -y / z))
    face = np.where(xmaj, np.where(x > 0, 1, 3), np.where(ymaj, np.where(y > 0, 0, 2), np.where(z > 0, 4, 5)))
    return face, (a + 1.0) * n / 2.0 - 0.5, (1.0 - b) * n / 2.0 - 0.5


def cube_to_direction(face, col, row, n):
    """Directions (not normalised) of pixel coordinates on cube faces (may lie beyond the face)."""
    a = 2.0 * (np.asarray(col, dtype=np.float64) + 0.5) / n - 1.0
    b = 1.0 - 2.0 * (np.asarray(row, dtype=np.float64) + 0.5) / n
    basis = _CUBE[np.asarray(face)]
    return a[..., None] * basis[..., 0, :] + b[..., None] * basis[..., 1, :] + basis[..., 2, :]


def direction_to_equirect(dirs, width, height):
    """Pixel coordinates (col, row) of directions on an equirectangular image."""
    d = np.asarray(dirs, dtype=np.float64)
    lon = np.arctan2(d[..., 0], d[..., 1])
    lat = np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))
    return (lon / (2 * np.pi) + 0.5) * width - 0.5, (0.5 - lat / np.pi) * height - 0.5


def _bilinear(x, y):
    """Integer taps (x0, y0) and fractional weights of bilinear interpolation."""
    x0, y0 = np.floor(x), np.floor(y)
    return x0.astype(np.int64), y0.astype(np.int64), x - x0, y - y0


def _cube_taps(dirs, n):
    """Flat source indices (face*n*n + row*n + col) and weights, 4 taps per direction.

    A tap that falls off its face (bilinear support straddling an edge) is
    re-projected through its direction to the neighbouring face, so seams blend.
    """
    face, x, y = direction_to_cube(dirs, n)
    x0, y0, fx, fy = _bilinear(x, y)
    idx, wts = [], []
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        tx, ty, tf = x0 + dx, y0 + dy, face.copy()
        off = (tx < 0) | (tx >= n) | (ty < 0) | (ty >= n)
        if off.any():
            d2 = cube_to_direction(tf[off], tx[off], ty[off], n)
            f2, x2, y2 = direction_to_cube(d2, n)
            tf[off] = f2
            tx[off] = np.clip(np.rint(x2), 0, n - 1).astype(np.int64)
            ty[off] = np.clip(np.rint(y2), 0, n - 1).astype(np.int64)
        idx.append((tf * n + ty) * n + tx)
        wts.append(w)
    return np.stack(idx, axis=-1), np.stack(wts, axis=-1)


def _equirect_taps(dirs, width, height):
    """Flat indices and weights, 4 taps per direction; wraps the +-180 deg seam, reflects over the poles."""
    x, y = direction_to_equirect(dirs, width, height)
    x0, y0, fx, fy = _bilinear(x, y)
    idx, wts = [], []
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        tx, ty = x0 + dx, y0 + dy
        over = (ty < 0) | (ty >= height)
        # Beyond a pole: the same latitude on the opposite meridian.
        ty = np.where(ty < 0, -1 - ty, np.where(ty >= height, 2 * height - 1 - ty, ty))
        tx = np.where(over, tx + width // 2, tx) % width
        idx.append(ty * width + tx)
        wts.append(w)
    return np.stack(idx, axis=-1), np.stack(wts, axis=-1)


# --- the remap table ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RemapTable:
    """A precomputed resampling of a source image (cube faces or equirect) to a dome frame.

    ``frame = M @ source`` with ``M`` a sparse (pixels x source texels) matrix
    in CSR form: per output pixel the supersampled directions' bilinear taps,
    merged.  Build once per camera with :func:`remap_table` (cached), then
    :meth:`apply` per frame.
    """

    shape: tuple
    """Output (height, width)."""
    source: str
    source_shape: tuple
    """(6, n, n) for a cube map, (height, width) for an equirect."""
    indptr: np.ndarray
    indices: np.ndarray
    weights: np.ndarray

    @functools.cached_property
    def matrix(self):
        from scipy.sparse import csr_matrix

        n_src = int(np.prod(self.source_shape))
        return csr_matrix((self.weights, self.indices, self.indptr), shape=(self.shape[0] * self.shape[1], n_src))

    def arrays(self):
        """Plain arrays for :class:`~nephele.core.pipeline.cache.Cache` (no pickle)."""
        return {
            "shape": np.asarray(self.shape, dtype=np.int64),
            "source_shape": np.asarray(self.source_shape, dtype=np.int64),
            "source": np.asarray(SOURCES.index(self.source)),
            "indptr": self.indptr,
            "indices": self.indices,
            "weights": self.weights,
        }

    @classmethod
    def from_arrays(cls, a):
        return cls(
            tuple(int(v) for v in a["shape"]),
            SOURCES[int(a["source"])],
            tuple(int(v) for v in a["source_shape"]),
            a["indptr"],
            a["indices"],
            a["weights"],
        )

    def apply(self, source):
        """Remap one frame.

        Parameters
        ----------
        source : array
            Cube map ``(6, n, n[, C])`` in :data:`CUBE_FACES` order, or an
            equirect ``(H, W[, C])``; any numeric dtype.

        Returns
        -------
        float32 array ``(height, width[, C])``: black outside the fisheye circle.
        """
        src = np.asarray(source)
        if tuple(src.shape[: len(self.source_shape)]) != tuple(self.source_shape):
            raise DataError(
                f"source image has shape {src.shape}, the remap table expects {self.source_shape} (+ channels)",
                field="source",
            )
        chans = src.shape[len(self.source_shape) :]
        flat = src.reshape(int(np.prod(self.source_shape)), -1).astype(np.float32, copy=False)
        out = self.matrix @ flat
        return np.asarray(out, dtype=np.float32).reshape(self.shape + chans)


def _sample_offsets(supersample):
    k = (np.arange(supersample) + 0.5) / supersample - 0.5
    ox, oy = np.meshgrid(k, k)
    return ox.ravel(), oy.ravel()


def remap_table(camera, source, source_shape, supersample=2, rows_per_chunk=128):
    """Precompute the resampling from a cube map or equirect to ``camera``'s frame.

    Each output pixel averages ``supersample**2`` directions on a regular
    sub-grid, each read bilinearly (a box-filtered footprint: antialiased when
    the source has about the dome frame's angular resolution).  Directions
    outside the fisheye circle count as black, so the circle's edge is
    antialiased too.  Results are cached per (camera, source, shape,
    supersample) in memory; use :meth:`RemapTable.arrays` to keep them on disk.

    Parameters
    ----------
    camera : DomeCamera
    source : {"cube", "equirect"}
    source_shape : tuple
        ``n`` or ``(6, n, n)`` for a cube map of ``n x n`` faces; ``(height, width)``
        for an equirect.
    supersample : int
        Directions per pixel along each axis (1 = bilinear at the pixel centre).

    Returns
    -------
    RemapTable
    """
    if source not in SOURCES:
        raise DataError(f"unknown source {source!r}; choose one of {', '.join(SOURCES)}", field="source")
    if source == "cube":
        shp = np.atleast_1d(np.asarray(source_shape)).tolist()
        n = shp[-1]
        if not (len(shp) == 1 or (len(shp) == 3 and shp[0] == 6 and shp[1] == shp[2])):
            raise DataError(f"cube map must be (6, n, n), got {tuple(shp)}", field="source_shape")
        source_shape = (6, _check_size(n, "source_shape"), int(n))
    else:
        shp = tuple(source_shape)
        if len(shp) != 2:
            raise DataError(f"equirect shape must be (height, width), got {shp}", field="source_shape")
        source_shape = (_check_size(shp[0], "source_shape"), _check_size(shp[1], "source_shape"))
    supersample = _check_size(supersample, "supersample")
    return _remap_table(camera, source, source_shape, supersample, int(rows_per_chunk))


@functools.lru_cache(maxsize=4)
def _remap_table(camera, source, source_shape, supersample, rows_per_chunk):
    from scipy.sparse import coo_matrix

    w, h = camera.width, camera.height
    ox, oy = _sample_offsets(supersample)
    ns = ox.size
    n_src = int(np.prod(source_shape))
    cols = np.arange(w, dtype=np.float64)
    indptr = [np.zeros(1, dtype=np.int64)]
    indices, weights = [], []
    nnz = 0
    for r0 in range(0, h, rows_per_chunk):
        rows = np.arange(r0, min(h, r0 + rows_per_chunk), dtype=np.float64)
        cc, rr = np.meshgrid(cols, rows)
        dirs, inside = camera.pixel_to_direction(cc[..., None] + ox, rr[..., None] + oy)  # (nr, w, ns)
        dirs = np.where(inside[..., None], dirs, 0.0)
        dirs[~inside, 2] = 1.0  # any direction; its weight is zero
        if source == "cube":
            idx, wt = _cube_taps(dirs, source_shape[-1])
        else:
            idx, wt = _equirect_taps(dirs, source_shape[1], source_shape[0])
        wt = wt * (inside[..., None] / ns)
        npx = rows.size * w
        pix = np.broadcast_to(np.arange(npx).reshape(rows.size, w, 1, 1), idx.shape)
        keep = wt.ravel() > 0
        m = coo_matrix((wt.ravel()[keep], (pix.ravel()[keep], idx.ravel()[keep])), shape=(npx, n_src)).tocsr()
        m.sum_duplicates()
        indptr.append(m.indptr[1:].astype(np.int64) + nnz)
        indices.append(m.indices.astype(np.int32))
        weights.append(m.data.astype(np.float32))
        nnz += m.nnz
    return RemapTable(
        (h, w),
        source,
        tuple(source_shape),
        np.concatenate(indptr),
        np.concatenate(indices) if indices else np.zeros(0, np.int32),
        np.concatenate(weights) if weights else np.zeros(0, np.float32),
    )


def stored_remap_table(camera, source, source_shape, supersample=2, cache=None):
    """:func:`remap_table`, kept on disk in a :class:`~nephele.core.pipeline.cache.Cache` (kind ``"dome_map"``).

    Render-farm workers are separate processes: the first one builds the
    table (seconds for a 2048 x 1500 frame), the others load it.
    """
    if cache is None:
        return remap_table(camera, source, source_shape, supersample)
    shape = np.atleast_1d(np.asarray(source_shape)).tolist()
    params = {"camera": dataclasses.asdict(camera), "source": source, "shape": shape, "supersample": int(supersample)}
    arrays = cache.load("dome_map", params)
    if arrays is not None:
        return RemapTable.from_arrays(arrays)
    table = remap_table(camera, source, source_shape, supersample)
    cache.store("dome_map", params, table.arrays())
    return table


def remap(source_image, camera, source="cube", supersample=2):
    """Remap a cube map ``(6, n, n[, C])`` or an equirect ``(H, W[, C])`` to ``camera``'s frame.

    Convenience around :func:`remap_table` (cached) and :meth:`RemapTable.apply`.
    """
    src = np.asarray(source_image)
    shape = src.shape[:3] if source == "cube" else src.shape[:2]
    return remap_table(camera, source, shape, supersample).apply(src)


# --- stereo ---------------------------------------------------------------------------------------


def stereo_eyes(separation, centre=(0.0, 0.0, 0.0)):
    """Left and right eye positions for a forward-facing dome audience.

    A *fixed* baseline along the theatre's ``x`` axis (left-right for a viewer
    facing the front), the same for every direction, with parallel views (no
    toe-in): both eyes render the whole dome with the camera's orientation.
    For the Omnimax and tilted-dome audience, who face forward and look mostly
    ahead and up, this gives horizontal disparity only where they look.
    Spherical (omnidirectional) stereo instead turns the baseline with each
    direction's azimuth; for a viewer who keeps facing forward that yields
    vertical disparity at the sides (Cycles, a marker 90 deg right and 10 deg
    up at 10x the eye separation: 5.3 deg of elevation difference between the
    eyes, against the true 1.0 deg that this fixed baseline gives; see
    ``tests/addon/test_dome_render.py``).

    Limits: disparity shrinks to zero toward +-90 deg azimuth (objects there
    lie along the baseline) and is reversed for viewers who turn round to look
    backwards; it is right only for viewers near the centre seat facing the
    front; eyes are not toed in, so zero parallax is at infinity.

    Parameters
    ----------
    separation : float
        Eye separation in scene units (> 0; e.g. 0.065 for metres).
    centre : (3,) array_like
        The dome camera's position.

    Returns
    -------
    dict ``{"L": (3,) array, "R": (3,) array}``
    """
    sep = _check_finite(separation, "separation")
    if sep <= 0:
        raise DataError(f"eye separation must be positive, got {sep:g}", field="separation")
    c = np.asarray(centre, dtype=np.float64)
    half = np.array([sep / 2.0, 0.0, 0.0])
    return {"L": c - half, "R": c + half}
