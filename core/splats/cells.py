"""Kernels fitted to grid cells: local Jacobians and the ellipsoids' principal axes.

A sample's kernel lives in *cell units*: the scene offset ``x`` from its
centre has cell offset ``d = J⁻¹ x``, ``J`` the grid's local Jacobian
``∂(scene position)/∂(i, j, k)`` (columns: one step in longitude, latitude
and level index — on a curvilinear grid, its two column indices — by central
differences; one-sided at the grid's edges, periodic across the seam).  On a
locally affine grid the weights of all samples then sum as on the unit
lattice.  With ``J = U S Vᵀ`` (SVD), the cut-off ellipsoid ``|J⁻¹ x| ≤ R`` is
``{M u : |u| ≤ 1}`` with ``M = R U S`` — the kernel's principal axes as
columns, which is what :class:`~.samples.Splats` stores (a rotation times a
scale, right-handed).  The weight at a scene point ``x`` is
``kernel.weight(R M⁻¹ (x − centre))``.

References
----------
.. [1] L. Westover, "Footprint Evaluation for Volume Rendering", 1990
   (ellipsoidal kernels for anisotropic grids).
"""

import numpy as np

from ..climate.grid import DEFAULT_EXAGGERATION


def principal_axes(jac, radius):
    """``R U S`` from Jacobians ``(n, 3, 3)`` (see the module docstring).

    Singular values are kept at least 1e-6 of the largest, so a cell that
    collapses (a pole row) still gives an invertible, if flat, ellipsoid.
    """
    u, s, _ = np.linalg.svd(jac)
    s = np.maximum(s, 1e-6 * s[:, :1])
    u[:, :, 2] *= np.where(np.linalg.det(u) < 0, -1.0, 1.0)[:, None]  # right-handed
    return radius * u * s[:, None, :]


def _diff(p, axis, stride, periodic):
    """Central differences of ``p`` along ``axis`` per ``stride`` samples; one-sided at open edges."""
    n = p.shape[axis]
    idx = np.arange(0, n, stride)
    if periodic:
        fwd = np.take(p, (idx + stride) % n, axis=axis)
        bwd = np.take(p, (idx - stride) % n, axis=axis)
        return 0.5 * (fwd - bwd)
    hi = np.where(idx + stride < n, idx + stride, idx)
    lo = np.where(idx - stride >= 0, idx - stride, idx)
    span = ((hi - lo) / stride).astype(np.float64)
    shape = [1] * p.ndim
    shape[axis] = idx.size
    d = np.take(p, hi, axis=axis) - np.take(p, lo, axis=axis)
    return d / np.maximum(span, 1.0).reshape(shape)


def cell_jacobians(grid, exaggeration=DEFAULT_EXAGGERATION, stride=1):
    """Scene positions and Jacobians of the (strided) grid samples.

    Returns
    -------
    points : (nk', nj', ni', 3) float64
    jac : (nk', nj', ni', 3, 3) float64
        Columns: ``∂x/∂i`` (longitude), ``∂x/∂j`` (latitude), ``∂x/∂k``
        (level), per ``stride`` samples.
    """
    p = grid.points(1.0, exaggeration, dtype=np.float64)
    sub = p[::stride, ::stride, ::stride]
    periodic = grid.periodic_lon and grid.shape[2] % stride == 0
    cols = []
    for axis, per in ((2, periodic), (1, False), (0, False)):
        d = _diff(p, axis, stride, per)
        # _diff strides only its own axis: take the others' strided samples.
        sl = [slice(None, None, stride)] * 3
        sl[axis] = slice(None)
        cols.append(d[tuple(sl)])
    return sub, np.stack(cols, axis=-1)


__all__ = ["cell_jacobians", "principal_axes"]
