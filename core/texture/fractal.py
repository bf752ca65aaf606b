"""The "poor-man's fractal": sums of perturbed planar sine waves, after Gardner (1985).

Max and Crawfis evaluate this analytic texture at the start coordinates
(longitude, latitude, altitude) of each point of a cloud surface and use it as
transparency.  Along each axis a sum of sine waves doubles in frequency and
falls by ``gain`` in amplitude each octave; each wave's phase is perturbed by
a slower sine of another axis, which breaks the grid-like regularity::

    X = Σ c_i sin(ω_i λ + a_i + π/2 · sin(ω_i φ / 2))
    Y = Σ c_i sin(ω_i φ + b_i + π/2 · sin(ω_i λ / 2))
    Z = Σ c_i sin(Ω_i z + d_i + π/2 · sin(ω_i φ / 2))
    T = (1 + X/C)(1 + Y/C)(1 + Z/C) / 8,   C = Σ c_i,

with ``ω_i`` the even integer nearest ``base · 1.93**i`` (even integers, so the texture is periodic across the
longitude seam), ``Ω_i = 2π 1.93**i / alt_wavelength`` and ``z`` the altitude in
metres.  ``T`` lies in ``[0, 1]``.  The Blender node group built by
:mod:`nephele.addon.advect_ops` computes the same formula from :func:`terms`.

References
----------
.. [1] G. Y. Gardner, "Visual simulation of clouds", Computer Graphics 19(3)
   (Proc. SIGGRAPH 1985) 297-303.
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 4).
"""

from dataclasses import asdict, dataclass

import numpy as np

RATIO = 1.93


@dataclass(frozen=True)
class Fractal:
    """Parameters of the texture.

    Parameters
    ----------
    base : int
        Waves around the globe of the first octave (even, >= 2).
    octaves : int
    gain : float
        Amplitude ratio between octaves (Gardner: 1/√2).
    alt_wavelength : float
        Wavelength in metres of the first altitude octave.
    """

    base: int = 6
    octaves: int = 7
    gain: float = 0.7071
    alt_wavelength: float = 12_000.0

    def __post_init__(self):
        if int(self.base) != self.base or self.base < 2 or self.base % 2:
            raise ValueError(f"base must be an even integer >= 2, got {self.base!r}")
        if int(self.octaves) != self.octaves or not 1 <= self.octaves <= 12:
            raise ValueError(f"octaves must be an integer in 1..12, got {self.octaves!r}")
        if not 0 < self.gain <= 1:
            raise ValueError(f"gain must be in (0, 1], got {self.gain!r}")
        if not self.alt_wavelength > 0:
            raise ValueError(f"alt_wavelength must be positive, got {self.alt_wavelength!r}")

    def as_dict(self):
        return asdict(self)


def terms(fractal):
    """Per octave: ``(omega, Omega, c/C, a, b, d)`` — frequencies, normalised amplitude, phases."""
    out = []
    amp = [fractal.gain**i for i in range(fractal.octaves)]
    total = sum(amp)
    for i in range(fractal.octaves):
        # Ratio 1.93 rather than 2 so octaves' crests do not coincide; even
        # integers keep every wave (and its half-frequency perturbation) periodic in longitude.
        omega = float(2 * round(fractal.base * RATIO**i / 2))
        big = 2.0 * np.pi * RATIO**i / fractal.alt_wavelength
        # Fixed, irregular phases (golden-ratio sequence) so octaves never line up.
        a, b, d = ((2.0 * np.pi * ((k + 1) * 0.618034 * (i + 1))) % (2 * np.pi) for k in range(3))
        out.append((omega, big, amp[i] / total, a, b, d))
    return out


def texture(lon, lat, alt, fractal=Fractal()):
    """The texture ``T`` in ``[0, 1]`` at longitudes, latitudes (degrees) and altitudes (m).

    Inputs broadcast against each other.
    """
    lam = np.deg2rad(np.asarray(lon, dtype=np.float64))
    phi = np.deg2rad(np.asarray(lat, dtype=np.float64))
    z = np.asarray(alt, dtype=np.float64)
    return _texture(lam, phi, z, fractal)


def texture_xyz(xyz, alt, fractal=Fractal()):
    """The texture at start positions given as vectors (any length) and altitudes (m).

    Longitude and latitude come from ``atan2`` exactly as in the node group, so
    the vectors need not be normalised.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    lam = np.arctan2(xyz[..., 1], xyz[..., 0])
    phi = np.arctan2(xyz[..., 2], np.hypot(xyz[..., 0], xyz[..., 1]))
    return _texture(lam, phi, np.asarray(alt, dtype=np.float64), fractal)


def _texture(lam, phi, z, fractal):
    sx = sy = sz = 0.0
    for omega, big, c, a, b, d in terms(fractal):
        sx = sx + c * np.sin(omega * lam + a + 0.5 * np.pi * np.sin(0.5 * omega * phi))
        sy = sy + c * np.sin(omega * phi + b + 0.5 * np.pi * np.sin(0.5 * omega * lam))
        sz = sz + c * np.sin(big * z + d + 0.5 * np.pi * np.sin(0.5 * omega * phi))
    return (1.0 + sx) * (1.0 + sy) * (1.0 + sz) / 8.0


def blend(copies_textures, weights):
    """``Σ w_k T_k`` of the texture copies of a restart strategy (weights sum to 1)."""
    w = np.asarray(weights, dtype=np.float64)
    return sum(wk * np.asarray(t) for wk, t in zip(w, copies_textures))


__all__ = ["Fractal", "blend", "terms", "texture", "texture_xyz"]
