"""A cloud's droplet density: Perlin noise superimposed on three ellipsoids.

Fig. 6 of Max & Crawfis defines the droplet density on a 24x24x18 grid as
Perlin's 3-D noise superimposed on a sum of three ellipsoidal densities.
Any grid size works; the density is a function of position in the box, so a
finer grid samples the same cloud.

Array order follows the rest of Nephele: ``(nz, ny, nx)``, level 0 at the
bottom; voxel ``(k, j, i)`` has its centre at ``((i+.5)dx, (j+.5)dy, (k+.5)dz)``
in a box ``[0, Lx] x [0, Ly] x [0, Lz]``.

References
----------
N. Max, R. Crawfis, "Advances in Scientific Visualization", section "Cloud rendering".
K. Perlin, "Improving noise", SIGGRAPH 2002.
"""

from dataclasses import dataclass, field

import numpy as np

from ..texture.noise import turbulence


@dataclass(frozen=True)
class Ellipsoid:
    """An ellipsoidal density bump ``weight * (1 - r^2)^2`` for ``r < 1``.

    ``center`` and ``radii`` are in box units (x, y, z).
    """

    center: tuple
    radii: tuple
    weight: float = 1.0


def _default_ellipsoids():
    # A cumulus: a broad body, a tower rising on one side, a lobe on the other.
    return (
        Ellipsoid((0.50, 0.50, 0.30), (0.36, 0.30, 0.18), 1.0),
        Ellipsoid((0.40, 0.46, 0.44), (0.22, 0.20, 0.24), 0.9),
        Ellipsoid((0.66, 0.58, 0.36), (0.20, 0.18, 0.16), 0.8),
    )


@dataclass(frozen=True)
class CloudParams:
    """Parameters of :func:`cloud_density` (all exposed in the add-on and CLI).

    Attributes
    ----------
    shape : (nz, ny, nx) grid size (paper: 18, 24, 24).
    size : (Lx, Ly, Lz) box size in scene units.
    ellipsoids : the density bumps.
    noise_amplitude : amplitude of the added noise (0 = smooth ellipsoids).
    noise_scale : noise lattice cells per box unit.
    octaves : noise octaves (fractal sum).
    seed : shifts the noise lattice, giving a different cloud.
    noise_offset : (x, y, z) shift of the noise in box units: a cloud whose texture drifts
        from frame to frame (:func:`..light.evolving.drifting_cloud`) keeps its ellipsoids.
    """

    shape: tuple = (18, 24, 24)
    size: tuple = (1.0, 1.0, 0.75)
    ellipsoids: tuple = field(default_factory=_default_ellipsoids)
    noise_amplitude: float = 0.7
    noise_scale: float = 5.0
    octaves: int = 4
    seed: int = 0
    noise_offset: tuple = (0.0, 0.0, 0.0)


def voxel_centres(shape, size):
    """Coordinates ``(x, y, z)`` of voxel centres, each broadcastable to ``shape``."""
    nz, ny, nx = shape
    lx, ly, lz = size
    x = (np.arange(nx) + 0.5) * (lx / nx)
    y = (np.arange(ny) + 0.5) * (ly / ny)
    z = (np.arange(nz) + 0.5) * (lz / nz)
    return x[None, None, :], y[None, :, None], z[:, None, None]


def cloud_density(params=None):
    """Droplet density in [0, 1] on the grid of ``params`` (a :class:`CloudParams`).

    ``base = sum_i w_i (1 - r_i^2)_+^2`` over the ellipsoids, then
    ``density = clip(base + a * turbulence(s * p + seed) * min(1, base / 0.15), 0, 1)``:
    the noise fades out where the ellipsoids end, so the cloud stays inside the box.

    Returns
    -------
    ndarray float32, shape ``params.shape``.

    References
    ----------
    Max & Crawfis, "Cloud rendering" (Fig. 6); Perlin 2002.
    """
    p = CloudParams() if params is None else params
    shape = tuple(int(n) for n in p.shape)
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"cloud_density: shape must be three positive ints, got {p.shape}")
    if len(p.size) != 3 or min(p.size) <= 0:
        raise ValueError(f"cloud_density: size must be three positive lengths, got {p.size}")
    x, y, z = voxel_centres(shape, p.size)
    base = np.zeros(shape)
    for e in p.ellipsoids:
        if min(e.radii) <= 0:
            raise ValueError(f"cloud_density: ellipsoid radii must be positive, got {e.radii}")
        r2 = ((x - e.center[0]) / e.radii[0]) ** 2 + ((y - e.center[1]) / e.radii[1]) ** 2 + (
            (z - e.center[2]) / e.radii[2]) ** 2
        base += e.weight * np.clip(1.0 - r2, 0.0, None) ** 2
    if p.noise_amplitude == 0:
        return np.clip(base, 0.0, 1.0).astype(np.float32)
    off = 17.31 * int(p.seed)
    s = float(p.noise_scale)
    xb, yb, zb = np.broadcast_arrays(x, y, z)
    ox, oy, oz = (float(v) for v in p.noise_offset)
    n = turbulence(s * (xb + ox) + off, s * (yb + oy) + 0.5 * off, s * (zb + oz) + 0.25 * off, octaves=p.octaves)
    d = base + p.noise_amplitude * n * np.minimum(1.0, base / 0.15)
    return np.clip(d, 0.0, 1.0).astype(np.float32)
