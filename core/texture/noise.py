"""Perlin's improved noise (2002), vectorised over NumPy arrays.

A faithful port of Perlin's reference implementation: the fixed 256-entry
permutation, the quintic fade ``6t^5 - 15t^4 + 10t^3`` and the twelve edge
gradients (four repeated) chosen by the low four bits of the hash.  The
result lies in about [-1, 1], is 0 at integer lattice points and has
continuous second derivatives.

References
----------
K. Perlin, "Improving noise", ACM Trans. Graphics 21(3) (SIGGRAPH 2002), 681-682.
N. Max, R. Crawfis, "Advances in Scientific Visualization" (the clouds of Fig. 6
use Perlin's 3-D noise superimposed on three ellipsoids).
"""

import numpy as np

# Perlin's reference permutation (https://mrl.cs.nyu.edu/~perlin/noise/).
_PERM = np.array([
    151, 160, 137, 91, 90, 15, 131, 13, 201, 95, 96, 53, 194, 233, 7, 225, 140, 36, 103, 30, 69, 142,
    8, 99, 37, 240, 21, 10, 23, 190, 6, 148, 247, 120, 234, 75, 0, 26, 197, 62, 94, 252, 219, 203, 117,
    35, 11, 32, 57, 177, 33, 88, 237, 149, 56, 87, 174, 20, 125, 136, 171, 168, 68, 175, 74, 165, 71,
    134, 139, 48, 27, 166, 77, 146, 158, 231, 83, 111, 229, 122, 60, 211, 133, 230, 220, 105, 92, 41,
    55, 46, 245, 40, 244, 102, 143, 54, 65, 25, 63, 161, 1, 216, 80, 73, 209, 76, 132, 187, 208, 89,
    18, 169, 200, 196, 135, 130, 116, 188, 159, 86, 164, 100, 109, 198, 173, 186, 3, 64, 52, 217, 226,
    250, 124, 123, 5, 202, 38, 147, 118, 126, 255, 82, 85, 212, 207, 206, 59, 227, 47, 16, 58, 17, 182,
    189, 28, 42, 223, 183, 170, 213, 119, 248, 152, 2, 44, 154, 163, 70, 221, 153, 101, 155, 167, 43,
    172, 9, 129, 22, 39, 253, 19, 98, 108, 110, 79, 113, 224, 232, 178, 185, 112, 104, 218, 246, 97,
    228, 251, 34, 242, 193, 238, 210, 144, 12, 191, 179, 162, 241, 81, 51, 145, 235, 249, 14, 239,
    107, 49, 192, 214, 31, 181, 199, 106, 157, 184, 84, 204, 176, 115, 121, 50, 45, 127, 4, 150, 254,
    138, 236, 205, 93, 222, 114, 67, 29, 24, 72, 243, 141, 128, 195, 78, 66, 215, 61, 156, 180,
], dtype=np.int64)
_P = np.concatenate([_PERM, _PERM])

# grad(hash, x, y, z) of the reference code as a table: gradient for h = hash & 15.
_GRAD = np.array([
    [1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0],
    [1, 0, 1], [-1, 0, 1], [1, 0, -1], [-1, 0, -1],
    [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1],
    [1, 1, 0], [0, -1, 1], [-1, 1, 0], [0, -1, -1],
], dtype=np.float64)


def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _grad(h, x, y, z):
    g = _GRAD[h & 15]
    return g[..., 0] * x + g[..., 1] * y + g[..., 2] * z


def improved_noise(x, y, z):
    """Perlin's improved 3-D noise at points ``(x, y, z)`` (broadcast arrays).

    Parameters
    ----------
    x, y, z : array_like
        Coordinates in lattice units (the noise repeats every 256 units).

    Returns
    -------
    ndarray of float64
        Noise values, about in [-1, 1]; exactly 0 at integer points.

    References
    ----------
    K. Perlin, "Improving noise", SIGGRAPH 2002.
    """
    x, y, z = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x, y, z)))
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
        raise ValueError("improved_noise: coordinates must be finite")
    fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
    X = fx.astype(np.int64) & 255
    Y = fy.astype(np.int64) & 255
    Z = fz.astype(np.int64) & 255
    x, y, z = x - fx, y - fy, z - fz
    u, v, w = _fade(x), _fade(y), _fade(z)
    A = _P[X] + Y
    AA, AB = _P[A] + Z, _P[A + 1] + Z
    B = _P[X + 1] + Y
    BA, BB = _P[B] + Z, _P[B + 1] + Z

    def lerp(t, a, b):
        return a + t * (b - a)

    return lerp(
        w,
        lerp(v, lerp(u, _grad(_P[AA], x, y, z), _grad(_P[BA], x - 1, y, z)),
             lerp(u, _grad(_P[AB], x, y - 1, z), _grad(_P[BB], x - 1, y - 1, z))),
        lerp(v, lerp(u, _grad(_P[AA + 1], x, y, z - 1), _grad(_P[BA + 1], x - 1, y, z - 1)),
             lerp(u, _grad(_P[AB + 1], x, y - 1, z - 1), _grad(_P[BB + 1], x - 1, y - 1, z - 1))),
    )


def turbulence(x, y, z, octaves=4, lacunarity=2.0, gain=0.5):
    """Fractal sum of :func:`improved_noise` octaves (signed, not absolute).

    ``sum_k gain**k * noise(lacunarity**k * p)``; with the defaults the
    result stays within about [-1.9, 1.9].
    """
    if int(octaves) < 1:
        raise ValueError("turbulence: octaves must be >= 1")
    total = 0.0
    amp, freq = 1.0, 1.0
    for _ in range(int(octaves)):
        total = total + amp * improved_noise(np.asarray(x) * freq, np.asarray(y) * freq, np.asarray(z) * freq)
        amp *= gain
        freq *= lacunarity
    return total
