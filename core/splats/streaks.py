"""Anisotropic streak textures that flow when cycled, and streak orientation.

The wind is shown by a second texture component on every splat: short
dashes elongated along the texture's +u axis (the splat turns it so +u lies
along the projected wind).  Map ``k`` of a cycle of ``n`` is the same dash
pattern advected by ``k/n`` of the tile along +u; because the pattern is
periodic over the tile, map ``n`` would equal map 0, so cycling
``0, 1, …, n-1, 0, …`` moves the dashes downwind by equal steps with no jump
at the loop.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3
   ("cycling through a sequence of different texture maps between frames").
.. [2] R. Crawfis, N. Max and B. Becker, "Vector Field Visualization",
   IEEE Computer Graphics and Applications 14(5), 1994, pp. 50-56.
"""

import numpy as np

from ..errors import DataError


def streak_maps(n=8, size=128, *, seed=0, count=24, length=0.6, width=0.03):
    """A cycle of ``n`` tileable streak textures.

    Parameters
    ----------
    n : int
        Maps in the cycle.
    size : int
        Texels per side.
    seed : int
        Seed of the dash positions.
    count : int
        Dashes per tile.
    length : float
        Length of a dash along +u, as a fraction of the tile (its profile is
        ``cos²`` over that length).
    width : float
        Gaussian standard deviation of a dash across (along v), fraction of the tile.

    Returns
    -------
    (n, size, size) float32 in [0, 1]
        ``maps[k, j, i]``: texel ``i`` along u (columns), ``j`` along v (rows),
        at ``u = (i + 0.5)/size``, ``v = (j + 0.5)/size``.  Map ``k`` is map 0
        advected by ``k/n`` of the tile along +u; every map tiles seamlessly.
    """
    for name, val, low in (("n", n, 1), ("size", size, 4), ("count", count, 1)):
        if int(val) != val or val < low:
            raise DataError(f"must be an integer >= {low}, got {val!r}", field=name)
    if not (0 < length <= 1 and 0 < width <= 0.5):
        raise DataError(f"length {length!r} must be in (0, 1] and width {width!r} in (0, 0.5]", field="streaks")
    n, size, count = int(n), int(size), int(count)
    rng = np.random.default_rng(seed)
    u0, v0 = rng.random(count), rng.random(count)
    gain = rng.uniform(0.5, 1.0, count)
    c = (np.arange(size) + 0.5) / size
    maps = np.zeros((n, size, size))
    for k in range(n):
        for uj, vj, gj in zip(u0 + k / n, v0, gain):
            du = (c - uj + 0.5) % 1.0 - 0.5  # periodic offsets in [-0.5, 0.5)
            dv = (c - vj + 0.5) % 1.0 - 0.5
            along = np.where(np.abs(du) < 0.5 * length, np.cos(np.pi * du / length) ** 2, 0.0)
            across = np.exp(-0.5 * (dv / width) ** 2)
            maps[k] += gj * across[:, None] * along[None, :]
    return (maps / maps.max()).astype(np.float32)


def _smooth(a, sigma):
    """Gaussian blur (periodic, by FFT); ``sigma`` in pixels."""
    ky = np.fft.fftfreq(a.shape[0])[:, None]
    kx = np.fft.rfftfreq(a.shape[1])[None, :]
    g = np.exp(-2.0 * np.pi**2 * sigma**2 * (kx * kx + ky * ky))
    return np.fft.irfft2(np.fft.rfft2(a) * g, s=a.shape)


def structure_tensor(image, sigma=2.0):
    """Smoothed structure tensor ``(Jxx, Jxy, Jyy)`` of a 2-D image.

    ``x`` runs along the columns, ``y`` along the rows (downward in an image).
    """
    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2:
        raise DataError(f"needs a 2-D image, got shape {a.shape}", field="image")
    gy, gx = np.gradient(a)
    return _smooth(gx * gx, sigma), _smooth(gx * gy, sigma), _smooth(gy * gy, sigma)


def streak_orientation(image, sigma=2.0, mask=None):
    """Direction of the streaks in ``image`` (radians in [0, π), from +x toward +y).

    The direction of least intensity change from the structure tensor:
    perpendicular to the dominant gradient.  With ``mask`` (bool, same shape)
    only those pixels' tensors are summed; returns also the coherence
    ``(λ1 − λ2)/(λ1 + λ2)`` of the summed tensor (0 isotropic, 1 perfectly
    oriented).

    References
    ----------
    .. [1] J. Bigün and G. H. Granlund, "Optimal orientation detection of
       linear symmetry", ICCV 1987.
    """
    jxx, jxy, jyy = structure_tensor(image, sigma)
    if mask is not None:
        m = np.asarray(mask, bool)
        jxx, jxy, jyy = jxx[m], jxy[m], jyy[m]
    a, b, c = float(np.sum(jxx)), float(np.sum(jxy)), float(np.sum(jyy))
    gradient = 0.5 * np.arctan2(2.0 * b, a - c)
    coherence = np.hypot(a - c, 2.0 * b) / (a + c) if a + c > 0 else 0.0
    return float((gradient + 0.5 * np.pi) % np.pi), float(coherence)


__all__ = ["streak_maps", "streak_orientation", "structure_tensor"]
