"""Reference splat renderer: EWA-projected footprints composited in depth order.

Each splat's optical depth at a pixel is ``extinction · opacity · ∫ w ds``
along the pixel's ray, with ``∫ w ds`` the kernel's footprint: the ray's
line in the splat's cell space ``d = R M⁻¹ (x − centre)`` passes at distance
``ρ`` from the centre, so ``∫ w ds = F(ρ) / |R M⁻¹ v|`` (``v`` the unit ray
direction).  For an orthographic view this is exact.  Under perspective the
projection is replaced by its affine approximation at the splat's centre
(EWA, Zwicker et al. 2001): ``ρ² = δᵀ Q δ`` for a pixel offset ``δ`` from
the projected centre, ``Q`` a 2×2 conic per splat.  A Gaussian pixel
prefilter of variance ``prefilter`` (px²) is added to the footprint's own
covariance (``variance · Q⁻¹``), which widens ``Q`` to ``Q'`` and lowers
the amplitude by ``√(det Q'/det Q)`` so the footprint keeps its integral:
splats smaller than a pixel blur instead of aliasing.

A splat's alpha is ``1 − exp(−τ)``, so the transmission through any set of
splats is ``exp(−Σ τ)`` whatever the order, and a lattice of equal splats
(a partition of unity) gives the exact opacity of a constant medium.  Colour
needs the order: splats are composited front to back (equivalently, back to
front with *over*), sorted by distance from the eye (orthographic: by depth).

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3.
.. [2] L. Westover, "Footprint Evaluation for Volume Rendering", 1990.
.. [3] M. Zwicker, H. Pfister, J. van Baar and M. Gross, "EWA Volume
   Splatting", Proc. IEEE Visualization 2001.
.. [4] R. Crawfis and N. Max, "Texture Splats for 3D Scalar and Vector Field
   Visualization", IEEE Visualization '93.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..memory import check_memory
from ..volume.sparse import DEFAULT_EXTINCTION
from .camera import Camera
from .kernel import SplatKernel
from .samples import Splats

DEFAULT_PREFILTER = 0.25
"""Variance (px²) of the Gaussian pixel prefilter: σ = 0.5 px."""

DEFAULT_STREAK_CONTRAST = 0.6
"""How strongly the streak texture ``T`` modulates a splat's optical depth:
``τ × ((1 − contrast) + contrast · T / mean(T))`` (the mean optical depth is kept)."""

MAX_FRAGMENTS = 2_000_000
"""Pixel fragments composited per batch (bounds the temporary memory to a few hundred MB)."""


@dataclass(frozen=True, eq=False)
class ScreenSplats:
    """Splats projected on the image (only those with a visible footprint).

    Attributes
    ----------
    keep : (m,) int
        Indices into the :class:`Splats`.
    center : (m, 2)
        Projected centre in pixels (x right, y down; pixel ``(row, col)``
        covers ``[col, col+1) × [row, row+1)``).
    key : (m,)
        Sort key, larger = farther (distance from the eye; orthographic: depth).
    conic : (m, 2, 2)
        ``Q'``: ``ρ² = δᵀ Q' δ`` (cell units²) for a pixel offset ``δ``; prefilter included.
    amplitude : (m,)
        Optical depth per unit footprint: ``τ(δ) = amplitude · F(√(δᵀQ'δ))``.
    bbox : (m, 4) int
        Inclusive pixel ranges ``col0, col1, row0, row1`` of the cut-off ellipse ``ρ < R``.
    wind_dir : (m, 2)
        Unit screen direction of the projected wind (x right, y down); ``(1, 0)`` when calm.
    wind_speed : (m,)
        Projected wind speed, pixels per hour.
    tex : (m, 2, 2)
        Pixel offset → streak texture coordinates (in tiles):
        ``(a, b) = tex · δ + tex_offset`` (see :func:`streak_factor`).
    tex_offset : (m, 2)
        :func:`streak_offsets` of the splat's position in :class:`Splats`.
    rate : (m,)
        ``|projected wind| / tile``: streak tiles per hour; the splat shows map
        ``floor(n · frac(rate · hours)) mod n``.
    """

    keep: np.ndarray
    center: np.ndarray
    key: np.ndarray
    conic: np.ndarray
    amplitude: np.ndarray
    bbox: np.ndarray
    wind_dir: np.ndarray
    wind_speed: np.ndarray
    tex: np.ndarray
    tex_offset: np.ndarray
    rate: np.ndarray


def streak_offsets(index):
    """Per-splat texture offsets in [0, 1)², a fixed hash of the splat's position in
    :class:`Splats` (SplitMix64), the same in every frame and for every renderer."""
    z = np.asarray(index, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
    out = []
    for salt in (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xD1B54A32D192ED03)):
        with np.errstate(over="ignore"):
            x = z * salt
            x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            x = x ^ (x >> np.uint64(31))
        out.append((x >> np.uint64(11)).astype(np.float64) / float(1 << 53))
    return np.stack(out, axis=-1)


def _inv2(m):
    det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    inv = np.empty_like(m)
    inv[:, 0, 0], inv[:, 1, 1] = m[:, 1, 1] / det, m[:, 0, 0] / det
    inv[:, 0, 1], inv[:, 1, 0] = -m[:, 0, 1] / det, -m[:, 1, 0] / det
    return inv, det


def _check(splats, kernel, camera, width, height):
    if not isinstance(splats, Splats):
        raise DataError(f"needs Splats, got {type(splats).__name__}", field="splats")
    if not isinstance(kernel, SplatKernel):
        raise DataError(f"needs a SplatKernel, got {type(kernel).__name__}", field="kernel")
    if not isinstance(camera, Camera):
        raise DataError(f"needs a Camera, got {type(camera).__name__}", field="camera")
    if abs(kernel.radius - splats.radius) > 1e-12 * kernel.radius:
        raise DataError(
            f"splats were built for cut-off {splats.radius}, the kernel's is {kernel.radius}", field="kernel"
        )
    for name, v in (("width", width), ("height", height)):
        if int(v) != v or v < 1:
            raise DataError(f"must be an integer >= 1, got {v!r}", field=name)


def default_tile(splats):
    """Default streak tile (scene units): the median cut-off diameter of the splats' largest axis."""
    if not len(splats):
        return 1.0
    return float(2.0 * np.median(np.linalg.norm(splats.axes, axis=1).max(axis=1)))


def _streak_frame(wind, v, fallback):
    """``e_a`` (projected wind direction), ``e_b = v × e_a`` and ``|wp|`` for unit view vectors ``v``
    toward the viewer; ``fallback`` (the camera's x axis) where the projected wind vanishes."""
    wp = wind - np.einsum("ij,ij->i", wind, v)[:, None] * v
    speed = np.linalg.norm(wp, axis=1)
    fb = fallback - np.einsum("ij,ij->i", fallback, v)[:, None] * v
    calm = speed < 1e-12
    ea = np.where(calm[:, None], fb, wp) / np.where(calm, np.linalg.norm(fb, axis=1), speed)[:, None]
    return ea, np.cross(v, ea), np.where(calm, 0.0, speed)


def project_splats(
    splats,
    kernel,
    camera,
    width,
    height,
    *,
    extinction=DEFAULT_EXTINCTION,
    prefilter=DEFAULT_PREFILTER,
    streak_tile=None,
):
    """Screen-space footprints of the splats (see the module docstring).

    Splats behind the eye or straddling its plane (perspective; orthographic:
    centres behind the camera), with zero opacity, or whose footprint misses
    the image are dropped.

    Parameters
    ----------
    splats, kernel, camera, width, height
        As for :func:`render_splats`.
    extinction : float
        Extinction per scene unit at opacity 1.
    prefilter : float
        Gaussian pixel prefilter variance (px²).
    streak_tile : float, optional
        Streak tile side in scene units (default :func:`default_tile`).

    Returns
    -------
    ScreenSplats

    References
    ----------
    .. [1] M. Zwicker et al., "EWA Volume Splatting", IEEE Visualization 2001.
    """
    _check(splats, kernel, camera, width, height)
    if not (np.isfinite(extinction) and extinction >= 0):
        raise DataError(f"must be >= 0, got {extinction!r}", field="extinction")
    if not (np.isfinite(prefilter) and prefilter >= 0):
        raise DataError(f"must be >= 0 px², got {prefilter!r}", field="prefilter")
    tile = default_tile(splats) if streak_tile is None else streak_tile
    if not (np.isfinite(tile) and tile > 0):
        raise DataError(f"must be a positive length in scene units, got {streak_tile!r}", field="streak_tile")
    R = kernel.radius
    rot = camera.world_to_camera[:3, :3]
    c = camera.to_camera(splats.centers)
    A = np.einsum("ij,njk->nik", rot, splats.axes) / R  # camera offset = A d, d in cell units
    reach = np.linalg.norm(splats.axes, axis=1).max(axis=1)  # semi-axes are orthogonal: largest = bounding sphere
    f = camera.pixels_per_unit(width)
    n = len(splats)
    depth = -c[:, 2]
    if camera.orthographic:
        ok = (splats.opacity > 0) & (depth > 0)
        jp = np.zeros((n, 2, 3))
        jp[:, 0, 0], jp[:, 1, 1] = f, -f
        v = np.tile([0.0, 0.0, -1.0], (n, 1))
        center = np.column_stack([0.5 * width + f * c[:, 0], 0.5 * height - f * c[:, 1]])
        key = depth
    else:
        ok = (splats.opacity > 0) & (depth > reach * 1.0001)
        d = np.where(ok, depth, 1.0)
        jp = np.zeros((n, 2, 3))
        jp[:, 0, 0] = f / d
        jp[:, 0, 2] = f * c[:, 0] / d**2
        jp[:, 1, 1] = -f / d
        jp[:, 1, 2] = -f * c[:, 1] / d**2
        dist = np.linalg.norm(c, axis=1)
        v = c / np.where(dist > 0, dist, 1.0)[:, None]
        center = np.column_stack([0.5 * width + f * c[:, 0] / d, 0.5 * height - f * c[:, 1] / d])
        key = dist
    idx = np.flatnonzero(ok)
    A, jp, v, center, key, c = A[idx], jp[idx], v[idx], center[idx], key[idx], c[idx]
    ainv = np.linalg.inv(A)
    jjt, _ = _inv2(np.einsum("nij,nkj->nik", jp, jp))
    b = np.einsum("nji,njk->nik", jp, jjt)  # right inverse of the projection Jacobian, (m, 3, 2)
    g = np.einsum("nij,njk->nik", ainv, b)
    a = np.einsum("nij,nj->ni", ainv, v)
    la = np.linalg.norm(a, axis=1)
    gn = np.einsum("ni,nik->nk", a / la[:, None], g)
    q = np.einsum("nik,nil->nkl", g, g) - gn[:, :, None] * gn[:, None, :]
    qinv, qdet = _inv2(q)
    cov = kernel.variance * qinv + prefilter * np.eye(2)  # pixel covariance of footprint + prefilter
    conic, _ = _inv2(cov / kernel.variance)
    cdet = conic[:, 0, 0] * conic[:, 1, 1] - conic[:, 0, 1] ** 2
    amplitude = extinction * splats.opacity[idx].astype(np.float64) / la * np.sqrt(cdet / qdet)
    shape = cov / kernel.variance  # = conic⁻¹
    half = R * np.sqrt(np.stack([shape[:, 0, 0], shape[:, 1, 1]], axis=1))
    lo = np.ceil(center - half - 0.5).astype(np.int64)
    hi = np.floor(center + half - 0.5).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    vis = np.all(hi >= lo, axis=1)
    bbox = np.column_stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]])
    # Streaks: the wind's screen velocity (for reference), and the texture frame in the
    # view plane through the centre (e_a along the projected wind, e_b = v × e_a), in camera space.
    wc = splats.wind[idx] @ rot.T
    ws = np.einsum("nij,nj->ni", jp, wc)
    speed = np.linalg.norm(ws, axis=1)
    calm = speed <= 1e-12
    wdir = np.where(calm[:, None], [1.0, 0.0], ws / np.where(calm, 1.0, speed)[:, None])
    toward = -v  # unit vector toward the viewer
    ea, eb, wp = _streak_frame(wc, toward, np.tile([1.0, 0.0, 0.0], (len(idx), 1)))
    tex = np.stack([np.einsum("ni,nik->nk", ea, b), np.einsum("ni,nik->nk", eb, b)], axis=1) / tile
    return ScreenSplats(
        idx[vis], center[vis], key[vis], conic[vis], amplitude[vis], bbox[vis], wdir[vis], speed[vis], tex[vis],
        streak_offsets(idx[vis]), wp[vis] / tile,
    )


def _repeat_ranges(start, count):
    """``(owner, value)`` for every integer ``start[i] .. start[i] + count[i] - 1``."""
    owner = np.repeat(np.arange(count.size), count)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    return owner, start[owner] + (np.arange(owner.size) - first[owner])


def _fragments(scr, batch, radius, width):
    """``(splat, col, row)`` of the pixels whose centres lie inside each splat's cut-off
    ellipse ``δᵀQ'δ ≤ R²``: row by row, the exact span of columns (no bounding-box waste)."""
    bbox = scr.bbox[batch]
    owner, row = _repeat_ranges(bbox[:, 2], bbox[:, 3] - bbox[:, 2] + 1)
    s = batch[owner]
    q = scr.conic[s]
    cx = scr.center[s, 0]
    dy = row + 0.5 - scr.center[s, 1]
    disc = (q[:, 0, 1] * dy) ** 2 - q[:, 0, 0] * (q[:, 1, 1] * dy * dy - radius * radius)
    root = np.sqrt(np.maximum(disc, 0.0))
    mid = cx - q[:, 0, 1] * dy / q[:, 0, 0]
    half = root / q[:, 0, 0]
    c0 = np.maximum(np.ceil(mid - half - 0.5), 0).astype(np.int64)
    c1 = np.minimum(np.floor(mid + half - 0.5), width - 1).astype(np.int64)
    count = np.where(disc > 0, np.maximum(c1 - c0 + 1, 0), 0)
    pair, col = _repeat_ranges(c0, count)
    return s[pair], col, row[pair]


def _pyramid(tex, levels=6):
    """``tex`` blurred for minification: level ``L`` by a periodic Gaussian of σ = 0.5·2^L texels (level 0 as is)."""
    ky = np.fft.fftfreq(tex.shape[0])[:, None]
    kx = np.fft.rfftfreq(tex.shape[1])[None, :]
    spec = np.fft.rfft2(tex)
    out = [tex]
    for level in range(1, levels):
        g = np.exp(-2.0 * np.pi**2 * (0.5 * 2**level) ** 2 * (kx * kx + ky * ky))
        out.append(np.fft.irfft2(spec * g, s=tex.shape))
    return np.stack(out)


def _lookup(pyr, level, s, t):
    """Bilinear, periodic lookup in pyramid level ``level`` (per fragment) of ``pyr[L, j, i]``
    at texture coordinates ``(s, t)`` (u, v in tiles)."""
    size = pyr.shape[1] * pyr.shape[2]
    flat = pyr.reshape(pyr.shape[0], -1)
    size_v, size_u = pyr.shape[1:]
    x = s * size_u - 0.5
    y = t * size_v - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = x0.astype(np.int64) % size_u, y0.astype(np.int64) % size_v
    i1, j1 = (i0 + 1) % size_u, (j0 + 1) % size_v
    base = level * size
    f = flat.reshape(-1)
    return (1 - fy) * ((1 - fx) * f[base + j0 * size_u + i0] + fx * f[base + j0 * size_u + i1]) + fy * (
        (1 - fx) * f[base + j1 * size_u + i0] + fx * f[base + j1 * size_u + i1]
    )


def render_splats(
    splats,
    kernel,
    camera,
    width,
    height,
    *,
    streaks=None,
    hours=0.0,
    extinction=DEFAULT_EXTINCTION,
    prefilter=DEFAULT_PREFILTER,
    streak_tile=None,
    streak_contrast=DEFAULT_STREAK_CONTRAST,
    depth=None,
):
    """Render splats: EWA footprints, sorted by distance, composited with *over*.

    Parameters
    ----------
    splats : Splats
    kernel : SplatKernel
        The kernel the splats were built for (same cut-off).
    camera : Camera
    width, height : int
        Image size in pixels.
    streaks : (n_maps, size, size) array, optional
        A :func:`~.streaks.streak_maps` cycle.  Each splat's optical depth is
        multiplied by :func:`streak_factor` — the map chosen by the time
        ``hours`` and the splat's projected wind speed, laid in the view plane
        along the projected wind with ``streak_tile`` scene units per tile —
        at the point where the pixel's ray meets the plane through the
        splat's centre (the EWA linearisation: ``ScreenSplats.tex``).  For
        minification the map is blurred (a Gaussian pyramid, σ = 0.5·2^L
        texels at level ``L = round(log2(texels per pixel))``).
    hours : float
        Model time driving the streak cycle: streaks move downwind at the
        projected wind speed, in steps of ``1/n_maps`` tile.
    extinction : float
        Extinction per scene unit at opacity 1 (as the volume clouds).
    prefilter : float
        Pixel prefilter variance in px² (0: none).
    streak_tile : float, optional
        Streak tile side in scene units (default :func:`default_tile`).
    streak_contrast : float
        0 (no streaks) .. 1.
    depth : (height, width) array, optional
        Opaque surface behind the splats (the globe: :func:`sphere_depth`):
        a splat is hidden at pixels whose depth is less than its centre's, in
        the measure of :attr:`ScreenSplats.key` (distance from the eye;
        orthographic: depth along the view).

    Returns
    -------
    (height, width, 4) float32
        Premultiplied linear RGB and alpha over a transparent background:
        put over a background ``B`` as ``rgb + (1 − alpha) B``.

    References
    ----------
    .. [1] M. Zwicker et al., "EWA Volume Splatting", IEEE Visualization 2001.
    .. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3.
    """
    maps = _check_streaks(streaks, hours, streak_contrast)
    # The image's running sums, the splats' screen footprints and one batch of fragments (tracemalloc: 366 MB
    # for 5,766 splats at 256x256, the batch of MAX_FRAGMENTS dominating).
    check_memory(120 * int(width) * int(height) + 400 * len(splats.color) + 190 * MAX_FRAGMENTS,
                 f"splatting {len(splats.color):,} splats into {int(width)}x{int(height)} pixels",
                 hint="render a smaller image or fewer splats", field="splats")
    scr = project_splats(
        splats, kernel, camera, width, height, extinction=extinction, prefilter=prefilter, streak_tile=streak_tile
    )
    w, h = int(width), int(height)
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (h, w) or np.isnan(depth).any():
            raise DataError(
                f"needs a NaN-free (height, width) = {(h, w)} array, got shape {depth.shape}", field="depth"
            )
        depth = depth.ravel()
    color = np.zeros((h * w, 3))
    trans = np.ones(h * w)
    color_of = splats.color[scr.keep].astype(np.float64)
    order = np.argsort(scr.key, kind="stable")  # front first
    counts = (scr.bbox[order, 1] - scr.bbox[order, 0] + 1) * (scr.bbox[order, 3] - scr.bbox[order, 2] + 1)
    ends = np.cumsum(counts)
    streak = None if maps is None else _streak_layers(maps, scr, hours, streak_contrast)
    start = 0
    while start < order.size:
        stop = max(
            start + 1, int(np.searchsorted(ends, (ends[start - 1] if start else 0) + MAX_FRAGMENTS, side="right"))
        )
        pix, tau, rgb = _batch_fragments(scr, order[start:stop], kernel, w, depth, streak, color_of)
        start = stop
        cum = np.cumsum(tau)
        before = cum - tau
        first = np.concatenate([[True], pix[1:] != pix[:-1]]) if pix.size else np.zeros(0, bool)
        seg = np.maximum.accumulate(np.where(first, np.arange(pix.size), 0))
        before = before - before[seg]
        contrib = (-np.expm1(-tau) * np.exp(-before))[:, None] * rgb
        batch_color = np.stack([np.bincount(pix, contrib[:, c], minlength=h * w) for c in range(3)], axis=1)
        color += trans[:, None] * batch_color
        trans *= np.exp(-np.bincount(pix, tau, minlength=h * w))
    out = np.empty((h, w, 4), dtype=np.float32)
    out[..., :3] = color.reshape(h, w, 3)
    out[..., 3] = (1.0 - trans).reshape(h, w)
    return out


def _streak_layers(maps, scr, hours, contrast):
    """What the fragments need of the streak maps: the mip pyramids, each splat's layer (its map at
    ``hours`` and its level of detail), the maps' mean and the contrast."""
    levels = 6
    layers = np.concatenate([_pyramid(m, levels) for m in maps])
    n_maps, size = maps.shape[0], max(maps.shape[1:])
    k = np.floor(n_maps * np.mod(scr.rate * float(hours), 1.0)).astype(np.int64) % n_maps
    per_px = size * np.linalg.norm(scr.tex, ord=2, axis=(1, 2))  # texels per pixel, largest direction
    level = np.clip(np.round(np.log2(np.maximum(per_px, 1.0))), 0, levels - 1).astype(np.int64)
    return {"layers": layers, "layer": k * levels + level, "mean": float(maps.mean()), "contrast": contrast}


def _batch_fragments(scr, batch, kernel, w, depth, streak, color_of):
    """The fragments of splats ``batch`` inside their footprints (and in front of ``depth``), sorted by
    pixel, each pixel's front to back: ``(pixel, optical depth, colour)``."""
    s, col, row = _fragments(scr, batch, kernel.radius, w)
    dx = col + 0.5 - scr.center[s, 0]
    dy = row + 0.5 - scr.center[s, 1]
    q = scr.conic[s]
    rho2 = q[:, 0, 0] * dx * dx + 2.0 * q[:, 0, 1] * dx * dy + q[:, 1, 1] * dy * dy
    inside = rho2 < kernel.radius**2
    if depth is not None:
        inside &= scr.key[s] <= depth[row * w + col]
    s, dx, dy, rho2, col, row = s[inside], dx[inside], dy[inside], rho2[inside], col[inside], row[inside]
    tau = scr.amplitude[s] * kernel.footprint_rho2(rho2)
    if streak is not None:
        t, off = scr.tex[s], scr.tex_offset[s]
        a = t[:, 0, 0] * dx + t[:, 0, 1] * dy + off[:, 0]
        b = t[:, 1, 0] * dx + t[:, 1, 1] * dy + off[:, 1]
        c = streak["contrast"]
        tau = tau * ((1.0 - c) + c / streak["mean"] * _lookup(streak["layers"], streak["layer"][s], a, b))
    pix = (row * w + col).astype(np.int32)
    # Stable sort by pixel keeps each pixel's fragments front to back.
    o = np.argsort(pix, kind="stable")
    return pix[o], tau[o], color_of[s[o]]


def _check_streaks(streaks, hours, contrast):
    if streaks is None:
        return None
    maps = np.asarray(streaks, dtype=np.float64)
    if (
        maps.ndim != 3
        or maps.shape[0] < 1
        or min(maps.shape[1:]) < 2
        or not np.all(np.isfinite(maps))
        or maps.mean() <= 0
    ):
        raise DataError(
            f"needs finite (n_maps, size, size) maps with a positive mean, got shape {maps.shape}", field="streaks"
        )
    if not (np.isfinite(hours) and 0 <= contrast <= 1):
        raise DataError(f"hours {hours!r} must be finite and the contrast {contrast!r} in [0, 1]", field="streaks")
    return maps


def streak_factor(
    splats, index, xyz, camera, hours, streaks, streak_tile=None, streak_contrast=DEFAULT_STREAK_CONTRAST
):
    """The streak modulation of splat ``index[i]``'s optical depth at scene point ``xyz[i]`` (no minification blur).

    With ``v`` the unit vector from the point toward the viewer (orthographic:
    the camera's +z), ``wp = wind − (wind·v) v``, ``e_a = wp/|wp|`` (the
    camera's x axis made perpendicular to ``v`` when ``|wp| < 1e-12``) and
    ``e_b = v × e_a``: texture coordinates
    ``(a, b) = ((x − c)·e_a, (x − c)·e_b) / tile + streak_offsets(index)``,
    map ``k = floor(n · frac(|wp| · hours / tile)) mod n``, sampled
    bilinearly and periodically at ``(a mod 1, b mod 1)`` (a along the
    columns, b along the rows) as ``T``; the factor is
    ``(1 − contrast) + contrast · T / mean(maps)``.

    Returns
    -------
    (m,) float64
    """
    maps = _check_streaks(streaks, hours, streak_contrast)
    if maps is None:
        raise DataError("needs the streak maps", field="streaks")
    if not isinstance(camera, Camera):
        raise DataError(f"needs a Camera, got {type(camera).__name__}", field="camera")
    tile = default_tile(splats) if streak_tile is None else streak_tile
    if not (np.isfinite(tile) and tile > 0):
        raise DataError(f"must be a positive length in scene units, got {streak_tile!r}", field="streak_tile")
    index = np.asarray(index, dtype=np.int64).reshape(-1)
    x = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    rot = camera.world_to_camera[:3, :3]
    if camera.orthographic:
        v = np.tile(rot[2], (len(x), 1))
    else:
        v = camera.position - x
        v /= np.linalg.norm(v, axis=1)[:, None]
    ea, eb, wp = _streak_frame(splats.wind[index], v, np.tile(rot[0], (len(x), 1)))
    rel = x - splats.centers[index]
    off = streak_offsets(index)
    a = np.einsum("ij,ij->i", rel, ea) / tile + off[:, 0]
    b = np.einsum("ij,ij->i", rel, eb) / tile + off[:, 1]
    n = maps.shape[0]
    k = np.floor(n * np.mod(wp * float(hours) / tile, 1.0)).astype(np.int64) % n
    return (1.0 - streak_contrast) + streak_contrast / maps.mean() * _lookup(maps, k, a, b)


def sphere_depth(camera, width, height, radius=1.0, center=(0.0, 0.0, 0.0)):
    """Per-pixel depth of an opaque sphere (the globe) for :func:`render_splats`' ``depth``.

    Distance from the eye to the first hit along each pixel-centre ray
    (orthographic: depth along the view); ``inf`` where the ray misses.
    """
    if not isinstance(camera, Camera):
        raise DataError(f"needs a Camera, got {type(camera).__name__}", field="camera")
    w, h = int(width), int(height)
    f = camera.pixels_per_unit(w)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    px, py = ((cols - 0.5 * w) / f).ravel(), (-(rows - 0.5 * h) / f).ravel()
    c = camera.to_camera(np.asarray(center, dtype=np.float64))[0]
    if camera.orthographic:
        origin = np.column_stack([px, py, np.zeros_like(px)])
        dirs = np.tile([0.0, 0.0, -1.0], (px.size, 1))
    else:
        origin = np.zeros((px.size, 3))
        dirs = np.column_stack([px, py, -np.ones_like(px)])
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    rel = c - origin
    tc = np.einsum("ij,ij->i", rel, dirs)
    disc = tc * tc - (np.einsum("ij,ij->i", rel, rel) - radius * radius)
    with np.errstate(invalid="ignore"):
        t = tc - np.sqrt(disc)
    return np.where((disc >= 0) & (t > 0), t, np.inf).reshape(h, w)


def reconstruct(splats, kernel, xyz, values=None, chunk=2_000_000):
    """The kernel-reconstructed field ``Σ_s values_s w_s(x)`` at scene points ``xyz`` ``(m, 3)``.

    ``values`` ``(n,)`` or ``(n, c)`` (default ones: the sum of the weights,
    a partition of unity where the samples form a lattice).  Brute force
    over splat × point pairs near each other (for tests and benchmarks).
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    vals = np.ones(len(splats)) if values is None else np.asarray(values, dtype=np.float64)
    out = np.zeros((xyz.shape[0],) + vals.shape[1:])
    if not len(splats):
        return out
    reach = np.linalg.norm(splats.axes, axis=1).max(axis=1)
    inv = np.linalg.inv(splats.axes) * splats.radius
    order = np.argsort(xyz[:, 0])
    xs = xyz[order, 0]
    for s in range(len(splats)):
        c = splats.centers[s]
        i0, i1 = np.searchsorted(xs, [c[0] - reach[s], c[0] + reach[s]])
        if i1 <= i0:
            continue
        pts = order[i0:i1]
        d = (xyz[pts] - c) @ inv[s].T
        w = kernel.weight(d)
        hit = w > 0
        out[pts[hit]] += np.multiply.outer(w[hit], vals[s])
    return out


def ray_integral(splats, kernel, camera, width, height, *, extinction=DEFAULT_EXTINCTION, steps=512):
    """Exact emission–absorption ray integral of the kernel-reconstructed field (reference).

    The medium has extinction ``extinction · Σ opacity_s w_s(x)`` and
    emission colour ``Σ opacity_s colour_s w_s(x) / Σ opacity_s w_s(x)``;
    each pixel-centre ray is integrated by the midpoint rule with ``steps``
    steps over the splats' depth range (no EWA approximation, no
    prefilter, no streaks).  Slow: for tests and benchmarks.

    Returns
    -------
    (height, width, 4) float32, premultiplied as :func:`render_splats`.
    """
    _check(splats, kernel, camera, width, height)
    w, h = int(width), int(height)
    rot = camera.world_to_camera[:3, :3]
    cam = camera.to_camera(splats.centers)
    reach = np.linalg.norm(splats.axes, axis=1).max(axis=1)
    f = camera.pixels_per_unit(w)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    px, py = (cols.ravel() - 0.5 * w) / f, -(rows.ravel() - 0.5 * h) / f
    if camera.orthographic:
        origin = np.column_stack([px, py, np.zeros_like(px)])
        dirs = np.tile([0.0, 0.0, -1.0], (px.size, 1))
        along = -cam[:, 2]
    else:
        origin = np.zeros((px.size, 3))
        dirs = np.column_stack([px, py, -np.ones_like(px)])
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        along = np.linalg.norm(cam, axis=1)
    t0, t1 = float((along - reach).min()), float((along + reach).max())
    ds = (t1 - t0) / steps
    t = t0 + (np.arange(steps) + 0.5) * ds
    sigma = np.zeros((px.size, steps))
    emit = np.zeros((px.size, steps, 3))
    inv = np.linalg.inv(splats.axes) * splats.radius
    for s in range(len(splats)):
        if splats.opacity[s] <= 0:
            continue
        k0, k1 = np.searchsorted(t, [along[s] - reach[s], along[s] + reach[s]])
        # Rays that pass within the bounding sphere: distance from centre to ray < reach.
        rel = cam[s] - origin
        tc = np.einsum("ij,ij->i", rel, dirs)
        dist2 = np.einsum("ij,ij->i", rel, rel) - tc * tc
        rays = np.flatnonzero(dist2 < reach[s] ** 2)
        if rays.size == 0 or k1 <= k0:
            continue
        p = origin[rays, None, :] + t[None, k0:k1, None] * dirs[rays, None, :]  # camera space
        world = (p - camera.world_to_camera[:3, 3]) @ rot  # rotᵀ (p − translation), row-vector form
        d = (world - splats.centers[s]) @ inv[s].T
        wts = kernel.weight(d.reshape(-1, 3)).reshape(rays.size, k1 - k0) * splats.opacity[s]
        sigma[rays, k0:k1] += wts
        emit[rays, k0:k1] += wts[..., None] * splats.color[s].astype(np.float64)
    tau = extinction * sigma * ds
    before = np.cumsum(tau, axis=1) - tau
    with np.errstate(invalid="ignore", divide="ignore"):
        colour = np.where(sigma[..., None] > 0, emit / sigma[..., None], 0.0)
    rgb = np.sum(colour * (-np.expm1(-tau) * np.exp(-before))[..., None], axis=1)
    out = np.empty((h, w, 4), dtype=np.float32)
    out[..., :3] = rgb.reshape(h, w, 3)
    out[..., 3] = (1.0 - np.exp(-tau.sum(axis=1))).reshape(h, w)
    return out


__all__ = [
    "DEFAULT_PREFILTER",
    "DEFAULT_STREAK_CONTRAST",
    "ScreenSplats",
    "default_tile",
    "project_splats",
    "ray_integral",
    "reconstruct",
    "render_splats",
    "sphere_depth",
    "streak_factor",
    "streak_offsets",
]
