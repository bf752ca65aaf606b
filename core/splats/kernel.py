"""Radial splat kernels normalised to a partition of unity, and their footprints.

A splat kernel is a spherically symmetric weight ``w(|d|)`` of an offset
``d`` in *cell units* (the sample spacing is 1), zero beyond the cut-off
radius ``R``.  Anisotropic and curvilinear cells reach it through each
sample's cell Jacobian (:mod:`.samples`): a scene offset ``x`` has cell offset
``J⁻¹ x``, so the kernel becomes an ellipsoid fitted to the cell.

Two kinds:

* ``"gaussian"`` (default): ``exp(-r²/2σ²) (1 - r²/R²)²`` with ``R = 2.5``,
  ``σ = 0.85``.  The smooth window removes the cut-off step that makes a
  truncated Gaussian ripple, and ``σ`` is tuned so that the sum of the
  weights over the unit cubic lattice is constant to about 1.2e-4 (worst
  deviation from the mean over random points; see
  ``tests/core/splats/test_splat_kernel.py``).
* ``"paper"``: the truncated Gaussian ``exp(-r²/2σ²)``, ``σ = 0.65``,
  ``R = 2.5``: Crawfis & Max's adjusted spherical kernel whose weights sum to
  within 0.5 % of constant (measured here: 3.0e-3 worst deviation).

Both are divided by their integral over space, so the weights sum to 1 on
average on the unit lattice (Poisson summation: the mean of the lattice sum
is the integral) and the footprint of a sample integrates to 1 over the view
plane.

The footprint ``F(ρ) = ∫ w(√(ρ² + z²)) dz`` (the integral along the view
direction at distance ``ρ`` from the centre) is computed by Gauss–Legendre
quadrature on the chord ``|z| ≤ √(R² − ρ²)``: the integrand is a Gaussian
times a polynomial there, so 48 nodes give it to rounding error.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization"
   (splatting, footprint tables, Fig. 3).
.. [2] L. Westover, "Footprint Evaluation for Volume Rendering", Computer
   Graphics 24(4), 1990, pp. 367-376.
.. [3] R. Crawfis and N. Max, "Texture Splats for 3D Scalar and Vector Field
   Visualization", Proc. IEEE Visualization '93, pp. 261-266.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError

KINDS = {
    "gaussian": dict(radius=2.5, sigma=0.85, window=2),
    "paper": dict(radius=2.5, sigma=0.65, window=0),
}
"""Default parameters of each kernel kind (``window``: power of ``1 - r²/R²``, 0 = hard cut)."""

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(48)
_TABLE = 4096  # radial footprint table entries (in ρ²) used by the renderer


@dataclass(frozen=True, eq=False)
class SplatKernel:
    """A normalised radial splat kernel (build with :func:`splat_kernel`).

    Attributes
    ----------
    kind : str
    radius : float
        Cut-off in cell units: the weight is zero for ``|d| >= radius``.
    sigma : float
        Width of the Gaussian factor (cell units).
    window : int
        Power of the window ``(1 - r²/R²)``; 0 is a hard cut.
    scale : float
        Normalising factor: the unnormalised kernel's integral is ``1/scale``.
    variance : float
        Second moment per axis, ``∫ x² w d³x`` (cell units²); also the
        second moment of the footprint per view-plane axis.
    peak : float
        ``footprint(0)``, the largest footprint value (cell units of length).
    """

    kind: str
    radius: float
    sigma: float
    window: int
    scale: float = 1.0
    variance: float = 0.0
    peak: float = 0.0

    def __post_init__(self):
        r = 0.5 * self.radius * (_NODES + 1.0)
        g = 0.5 * self.radius * _WEIGHTS
        w = self._raw(r)
        integral = 4.0 * np.pi * np.sum(g * r * r * w)
        object.__setattr__(self, "scale", float(1.0 / integral))
        object.__setattr__(self, "variance", float(4.0 * np.pi / 3.0 * np.sum(g * r**4 * w) / integral))
        object.__setattr__(self, "peak", float(self._footprint_rho(np.zeros(1))[0]))
        rho2 = np.linspace(0.0, self.radius**2, _TABLE)
        object.__setattr__(self, "_table", self._footprint_rho(np.sqrt(rho2)))

    def _raw(self, r):
        r = np.asarray(r, dtype=np.float64)
        q = r * r
        w = np.exp(-q / (2.0 * self.sigma**2))
        if self.window:
            w = w * np.clip(1.0 - q / self.radius**2, 0.0, None) ** self.window
        return np.where(r < self.radius, w, 0.0)

    def profile(self, r):
        """Normalised weight at distances ``r`` (cell units) from the centre."""
        return self.scale * self._raw(r)

    def weight(self, d):
        """Weight at offsets ``d`` ``(n, 3)`` in cell units; ``(n,)``."""
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        return self.profile(np.sqrt(np.einsum("ij,ij->i", d, d)))

    def _footprint_rho(self, rho):
        rho = np.asarray(rho, dtype=np.float64)
        half = np.sqrt(np.clip(self.radius**2 - rho * rho, 0.0, None))
        z = 0.5 * half[..., None] * (_NODES + 1.0)
        vals = self.profile(np.sqrt(rho[..., None] ** 2 + z * z))
        return np.where(rho < self.radius, half * np.sum(_WEIGHTS * vals, axis=-1), 0.0)

    def footprint(self, p):
        """Integral of the weight along the view direction at view-plane offsets
        ``p`` ``(n, 2)`` (cell units); ``(n,)``, in cell units of length."""
        p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
        return self._footprint_rho(np.sqrt(np.einsum("ij,ij->i", p, p)))

    def footprint_rho2(self, rho2):
        """:meth:`footprint` from squared distances, by linear interpolation in a
        4096-entry table of ``ρ²`` (error below 1e-6 of :attr:`peak`; the renderer's lookup)."""
        rho2 = np.asarray(rho2, dtype=np.float64)
        step = self.radius**2 / (_TABLE - 1)
        x = np.clip(rho2 / step, 0.0, _TABLE - 1.0)
        i = np.minimum(x.astype(np.intp), _TABLE - 2)
        f = x - i
        out = (1.0 - f) * self._table[i] + f * self._table[i + 1]
        return np.where(rho2 < self.radius**2, out, 0.0)


def splat_kernel(kind="gaussian", radius=None, sigma=None, window=None):
    """A normalised radial splat kernel.

    Parameters
    ----------
    kind : {"gaussian", "paper"}
        ``"gaussian"``: windowed Gaussian tuned to a partition of unity within
        ~1.2e-4; ``"paper"``: the truncated Gaussian (σ 0.65, R 2.5) whose
        weights sum to within 0.5 % of constant, as in the paper.
    radius, sigma, window : optional
        Override the kind's cut-off (cell units), Gaussian width (cell units)
        and window power (0 = hard cut).  Other values are no longer tuned to
        a partition of unity.

    Returns
    -------
    SplatKernel

    References
    ----------
    .. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
    .. [2] R. Crawfis and N. Max, "Texture Splats for 3D Scalar and Vector
       Field Visualization", IEEE Visualization '93.
    """
    if kind not in KINDS:
        raise DataError(f"unknown kernel {kind!r} (choose from {', '.join(KINDS)})", field="kernel")
    p = dict(KINDS[kind])
    for name, val in (("radius", radius), ("sigma", sigma)):
        if val is not None:
            if not (np.isfinite(val) and val > 0):
                raise DataError(f"must be a positive number of cells, got {val!r}", field=name)
            p[name] = float(val)
    if window is not None:
        if int(window) != window or window < 0:
            raise DataError(f"must be an integer >= 0, got {window!r}", field="window")
        p["window"] = int(window)
    return SplatKernel(kind, p["radius"], p["sigma"], p["window"])


def footprint_table(kernel, size=64, normalized=False):
    """The kernel's footprint sampled on a ``size × size`` texture over ``[-R, R]²``.

    Texel ``[j, i]`` holds ``kernel.footprint`` at the texel centre
    ``(-R + (i + 0.5) 2R/size, -R + (j + 0.5) 2R/size)`` (``i`` along x, the
    columns; ``j`` along y, the rows).  Values are in cell units of length;
    the largest possible value is ``kernel.peak`` (the centre, which an even
    ``size`` does not sample exactly).  ``normalized=True`` divides by
    ``kernel.peak`` so the texture runs 0..1 (multiply back by ``kernel.peak``).

    Returns
    -------
    (size, size) float32
    """
    if not isinstance(kernel, SplatKernel):
        raise DataError(f"needs a SplatKernel, got {type(kernel).__name__}", field="kernel")
    if int(size) != size or size < 2:
        raise DataError(f"must be an integer >= 2, got {size!r}", field="size")
    size = int(size)
    c = -kernel.radius + (np.arange(size) + 0.5) * (2.0 * kernel.radius / size)
    x, y = np.meshgrid(c, c)
    t = kernel.footprint(np.column_stack([x.ravel(), y.ravel()])).reshape(size, size)
    if normalized:
        t = t / kernel.peak
    return t.astype(np.float32)


__all__ = ["KINDS", "SplatKernel", "footprint_table", "splat_kernel"]
