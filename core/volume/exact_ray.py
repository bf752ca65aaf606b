"""Exact opacity integration along rays (Williams & Max 1992) and a reference
ray caster through the curvilinear cells.

Within a ray segment where the scalar ``s`` varies linearly from ``s0`` to
``s1`` and the transfer function ``τ(s)`` is piecewise linear, the extinction
is piecewise linear in distance, so its integral is exactly quadratic between
the transfer function's breakpoints:

    ∫₀ᴸ τ(s0 + (s1 − s0) t / L) dt = L · (F(s1) − F(s0)) / (s1 − s0),

with ``F`` the (piecewise-quadratic) antiderivative of ``τ`` — the segment
split at every breakpoint, done in closed form.

The reference caster samples the curvilinear field (trilinear in each cell,
exactly as :class:`~nephele.core.volume.curvilinear.CurvilinearField` defines it) at
small steps along each ray, treats the scalar as linear between samples and
integrates each piece exactly.  The only approximation is the scalar's
linearity between samples (second order in the step); the threshold's kink,
where most of the opacity error of a resampled volume comes from, is exact.

References
----------
.. [1] P. Williams and N. Max, "A Volume Density Optical Model", Proc. 1992
   Workshop on Volume Visualization, ACM, pp. 61–68.
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization".
"""

import numpy as np

from ..errors import DataError
from .transfer import TransferFunction


def segment_optical_depth(tf, s0, s1, length):
    """Exact ``∫ τ(s(t)) dt`` over segments with ``s`` linear from ``s0`` to ``s1``.

    Parameters
    ----------
    tf : TransferFunction
    s0, s1 : array_like
        Scalar at the segment ends (broadcast together).  A NaN end makes the
        segment empty (missing data contributes nothing).
    length : array_like
        Segment lengths (>= 0).

    Returns
    -------
    ndarray
        Optical depth (transfer-function units × length).

    References
    ----------
    .. [1] P. Williams and N. Max, "A Volume Density Optical Model", 1992.
    """
    if not isinstance(tf, TransferFunction):
        raise DataError(f"needs a TransferFunction, got {type(tf).__name__}", field="transfer function")
    s0, s1, length = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (s0, s1, length)))
    if np.any(length < 0):
        raise DataError("segment lengths must be >= 0", field="length")
    ds = s1 - s0
    scale = np.maximum(np.abs(s0), np.abs(s1)) + (tf.values[-1] - tf.values[0]) + 1.0
    flat = np.abs(ds) <= 1e-9 * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(
            flat, tf(0.5 * (s0 + s1)), (tf.antiderivative(s1) - tf.antiderivative(s0)) / np.where(flat, 1.0, ds)
        )
    out = length * mean
    return np.where(np.isnan(out), 0.0, out)


def sphere_span(origins, dirs, r_outer, r_inner=None):
    """Parameter range ``[t0, t1]`` of each ray inside the shell, stopping at the ground.

    ``dirs`` must be unit vectors.  The ray enters the sphere of radius
    ``r_outer`` and ends where it leaves it or first hits the sphere of
    ``r_inner`` (the opaque ground).  ``t0 == t1`` for a miss.
    """
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    b = np.einsum("ij,ij->i", o, d)
    c = np.einsum("ij,ij->i", o, o)
    disc = b * b - (c - r_outer**2)
    hit = disc > 0
    sq = np.sqrt(np.where(hit, disc, 0.0))
    t0 = np.maximum(-b - sq, 0.0)
    t1 = np.maximum(-b + sq, 0.0)
    if r_inner is not None:
        disc_i = b * b - (c - r_inner**2)
        tin = -b - np.sqrt(np.where(disc_i > 0, disc_i, 0.0))
        ground = (disc_i > 0) & (tin > 0)
        t1 = np.where(ground, np.minimum(t1, tin), t1)
    t1 = np.where(hit, np.maximum(t1, t0), t0)
    return t0, t1


def ray_samples(origins, dirs, t0, t1, step):
    """Sample positions along rays: ``(points (n, m, 3), lengths (n, m-1))``.

    Every ray gets the same number ``m`` of equally spaced samples covering
    its own ``[t0, t1]``, with spacing at most ``step`` for the longest ray.
    """
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    span = t1 - t0
    m = int(np.ceil(span.max() / step)) + 1 if span.size and span.max() > 0 else 2
    u = np.linspace(0.0, 1.0, max(m, 2))
    t = t0[:, None] + span[:, None] * u[None, :]
    pts = o[:, None, :] + t[..., None] * d[:, None, :]
    return pts, np.diff(t, axis=1)


def reference_optical_depth(field, name, tf, origins, dirs, step, chunk=200_000):
    """Optical depth along rays through a :class:`CurvilinearField`, by exact
    piecewise-linear integration between samples ``step`` apart.

    Rays run through the atmosphere shell and stop at the ground: at the
    last sample above the lowest level (the terrain), or at the lowest
    level's smallest radius.  Returns ``(tau, t0, t1)`` per ray, ``t1`` where it
    stopped.
    """
    r_in, r_out = field.radius_range()
    t0, t1 = sphere_span(origins, dirs, r_out, r_in)
    pts, seg = ray_samples(origins, dirs, t0, t1, step)
    n, m = seg.shape[0], pts.shape[1]
    s = np.empty(n * m)
    below = np.empty(n * m, bool)
    flat_pts = pts.reshape(-1, 3)
    for a in range(0, flat_pts.shape[0], chunk):
        s[a : a + chunk] = field.sample(name, flat_pts[a : a + chunk])
        below[a : a + chunk] = field.below_ground(flat_pts[a : a + chunk])
    s = s.reshape(n, m)
    below = below.reshape(n, m)
    # Stop at the last sample above the terrain: the ground is opaque.
    hit = below.any(axis=1)
    first = np.where(hit, np.maximum(np.argmax(below, axis=1) - 1, 0), m - 1)
    u = np.arange(m)[None, :]
    keep = u[:, :-1] < first[:, None]
    tau = np.where(keep, segment_optical_depth(tf, s[:, :-1], s[:, 1:], seg), 0.0).sum(axis=1)
    t_samples = t0[:, None] + np.concatenate([np.zeros((n, 1)), np.cumsum(seg, axis=1)], axis=1)
    t_end = np.take_along_axis(t_samples, first[:, None], axis=1)[:, 0]
    return tau, t0, t_end


def volume_optical_depth(volume, origins, dirs, t0, t1, step, chunk=200_000):
    """Optical depth along rays through a :class:`SparseVolume` (trilinear
    density, trapezoids ``step`` apart)."""
    pts, seg = ray_samples(origins, dirs, t0, t1, step)
    n, m = seg.shape[0], pts.shape[1]
    flat_pts = pts.reshape(-1, 3)
    dens = np.empty(n * m)
    for a in range(0, flat_pts.shape[0], chunk):
        dens[a : a + chunk] = volume.sample(flat_pts[a : a + chunk])
    dens = dens.reshape(n, m)
    return (seg * 0.5 * (dens[:, :-1] + dens[:, 1:])).sum(axis=1)


def opacity(tau, extinction):
    """Ray opacity ``1 − exp(−extinction · tau)``."""
    return -np.expm1(-extinction * np.asarray(tau, dtype=np.float64))


__all__ = [
    "opacity",
    "ray_samples",
    "reference_optical_depth",
    "segment_optical_depth",
    "sphere_span",
    "volume_optical_depth",
]
