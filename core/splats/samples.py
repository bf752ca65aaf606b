"""One splat per sample: centre, ellipsoid fitted to its cell, colour, opacity, wind.

By default the samples are the field resampled on *shells* (levels at fixed
heights above sea level; :mod:`.partition`), where the weights sum to one
within about 1e-3; ``vertical="native"`` takes the grid's own samples.

A sample's kernel lives in *cell units* (:mod:`.cells`): :class:`Splats`
stores its ellipsoid's principal axes ``M = R U S`` from the local cell
Jacobian ``J = U S Vᵀ``.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization".
.. [2] L. Westover, "Footprint Evaluation for Volume Rendering", 1990
   (ellipsoidal kernels for anisotropic grids).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..climate.dataset import Dataset
from ..climate.grid import DEFAULT_EXAGGERATION, EARTH_RADIUS, GlobeGrid
from ..climate.readers import open_dataset
from ..errors import DataError
from ..volume.transfer import ALTITUDE_COLORS, TEMPERATURE_COLORS, ColorMap, TransferFunction
from .cells import cell_jacobians, principal_axes
from .kernel import SplatKernel, splat_kernel
from .partition import ShellSampler, check_shells, curvilinear_shells, shell_factors, shell_heights, widen, widening

HOUR = 3600.0
ALTITUDE = "altitude"
"""``color_var`` meaning "height above sea level in metres"."""


@dataclass(frozen=True, eq=False)
class Splats:
    """Splats as arrays (``n`` samples).

    Attributes
    ----------
    centers : (n, 3) float64
        Scene positions (the globe convention of :mod:`nephele.core.climate.grid`:
        sea level at radius 1, heights scaled by the exaggeration).
    axes : (n, 3, 3) float64
        ``axes[s] = M``: principal semi-axes of the kernel's cut-off ellipsoid
        in scene units, as columns (orthogonal, right-handed), ``M = R U S``
        for the cell Jacobian ``J = U S Vᵀ`` and the kernel's cut-off ``R``.
        The cut-off ellipsoid is ``{centre + M u : |u| ≤ 1}``; a scene point
        ``x`` has cell offset ``d = R M⁻¹ (x − centre)``.
    color : (n, 3) float32
        Linear RGB.
    opacity : (n,) float32
        The transfer function's opacity of the sample (extinction relative to
        the extinction scale, as the volume clouds' density grid); the
        reconstructed extinction is ``extinction * Σ opacity_s w_s(x)``.
    wind : (n, 3) float64
        Velocity in scene units per hour.
    radius : float
        The kernel cut-off ``R`` (cell units) the axes were built with.
    index : (n, 3) int
        Grid index ``(k, j, i)`` (level, latitude, longitude) of each sample.
    """

    centers: np.ndarray
    axes: np.ndarray
    color: np.ndarray
    opacity: np.ndarray
    wind: np.ndarray
    radius: float
    index: np.ndarray = None

    def __post_init__(self):
        for name, dtype in (
            ("centers", np.float64),
            ("axes", np.float64),
            ("color", np.float32),
            ("opacity", np.float32),
            ("wind", np.float64),
        ):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=dtype))
        if self.index is not None:
            object.__setattr__(self, "index", np.asarray(self.index, dtype=np.int64))
        object.__setattr__(self, "radius", float(self.radius))
        n = len(self.centers)
        shapes = (("centers", (n, 3)), ("axes", (n, 3, 3)), ("color", (n, 3)), ("opacity", (n,)), ("wind", (n, 3)))
        for name, shape in shapes:
            a = np.asarray(getattr(self, name))
            if a.shape != shape:
                raise DataError(f"shape {a.shape} should be {shape}", field=name)
            if not np.all(np.isfinite(a)):
                raise DataError("has NaN or infinite values", field=name)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise DataError(f"must be positive, got {self.radius!r}", field="radius")
        if np.any(np.asarray(self.opacity) < 0):
            raise DataError("opacities must be >= 0", field="opacity")

    def __len__(self):
        return len(self.centers)

    def subset(self, sel):
        """The splats picked by a bool mask or index array."""
        return Splats(
            self.centers[sel], self.axes[sel], self.color[sel], self.opacity[sel], self.wind[sel], self.radius,
            None if self.index is None else self.index[sel],
        )

    def cell_offsets(self, xyz, s):
        """Cell offsets ``d`` ``(m, 3)`` of scene points ``xyz`` from splat ``s``."""
        x = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) - self.centers[s]
        return self.radius * np.linalg.solve(self.axes[s], x.T).T


def _color(dataset, color_var, colormap, hour, height, pick, n):
    if color_var is None:
        return np.ones((n, 3), dtype=np.float32)
    if color_var == ALTITUDE:
        vals = height
        cmap = ALTITUDE_COLORS if colormap is None else colormap
    else:
        vals = pick(dataset.read_at(color_var, hour))
        cmap = colormap
        if cmap is None:
            if color_var == "temperature":
                cmap = TEMPERATURE_COLORS
            else:
                ok = vals[np.isfinite(vals)]
                lo, hi = (float(ok.min()), float(ok.max())) if ok.size else (0.0, 1.0)
                cmap = ColorMap(points=((lo, (0.2, 0.2, 0.2)), (max(hi, lo + 1e-9), (1.0, 1.0, 1.0))))
    if not isinstance(cmap, ColorMap):
        raise DataError(f"needs a ColorMap, got {type(cmap).__name__}", field="colormap")
    return np.nan_to_num(cmap(vals), nan=0.0).astype(np.float32)


def _wind(dataset, hour, grid, exaggeration, sel, centers, pick):
    """Scene velocity per hour: ``u`` east and ``v`` north on the sphere through
    the sample (angular speed × its radius, the shallow-atmosphere convention of
    the project's advection, on the dataset's ``earth_radius``; on a curvilinear
    grid east and north of the column's own longitude and latitude), ``w``
    outward scaled by the exaggeration."""
    n = sel[0].size
    if "u" not in dataset or "v" not in dataset:
        return np.zeros((n, 3))
    u = pick(dataset.read_at("u", hour))
    v = pick(dataset.read_at("v", hour))
    w = pick(dataset.read_at("w", hour)) if "w" in dataset else np.zeros(n)
    bad = ~(np.isfinite(u) & np.isfinite(v) & np.isfinite(w))
    if bad.any():
        raise DataError(
            f"{int(bad.sum())} splat samples have NaN wind at {hour:g} h", path=dataset.source, field="u/v/w"
        )
    if grid.curvilinear:  # east/north of each column's own true longitude and latitude
        lam, phi = np.deg2rad(grid.lon2d[sel[1], sel[2]]), np.deg2rad(grid.lat2d[sel[1], sel[2]])
    else:
        lam, phi = np.deg2rad(grid.lon[sel[2]]), np.deg2rad(grid.lat[sel[1]])
    east = np.column_stack([-np.sin(lam), np.cos(lam), np.zeros(n)])
    north = np.column_stack([-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)])
    up = np.column_stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])
    if grid.rotation is not None:
        east, north, up = (a @ grid.rotation.T for a in (east, north, up))
    r = np.linalg.norm(centers, axis=1)
    sphere = float(getattr(dataset, "earth_radius", None) or EARTH_RADIUS)  # the file's sphere, as advection
    horiz = (u[:, None] * east + v[:, None] * north) * (HOUR / sphere) * r[:, None]
    return horiz + (w * HOUR * exaggeration / EARTH_RADIUS)[:, None] * up


def _layout(grid, heights, stride, exaggeration, kernel, path):
    """Sample positions, Jacobians, factors (None: native) and the lon/lat shells' widening
    ``(λ_lon, λ_lev)`` still to apply to the selected Jacobians (None: applied or native)."""
    if heights is None:
        return (*cell_jacobians(grid, exaggeration, stride), None, None)
    if grid.curvilinear:
        return (*curvilinear_shells(grid, heights, stride, exaggeration, kernel), None)
    step = np.diff(grid.lon)
    if not np.allclose(step, step[0], rtol=1e-6, atol=0.0):
        raise DataError("shells need evenly spaced longitudes (use vertical='native')", path=path, field="lon")
    layout = GlobeGrid(
        grid.lon,
        grid.lat,
        np.broadcast_to(heights[:, None, None], (heights.size,) + grid.shape[1:]).copy(),
        rotation=grid.rotation,
    )
    points, jac = cell_jacobians(layout, exaggeration, stride)
    lat, h = grid.lat[::stride], heights[::stride]
    factors = shell_factors(lat, h, (grid.lon[1] - grid.lon[0]) * stride, exaggeration, kernel)[:, :, None]
    return points, jac, factors, widening(lat, h, kernel.radius)


def _check_inputs(dataset, transfer, exaggeration, stride, threshold, kernel, vertical):
    """:func:`splat_samples`'s arguments checked, each bad one a :class:`DataError` naming it:
    ``(dataset, threshold, kernel)`` with their defaults filled in."""
    if isinstance(dataset, (str, Path)):
        dataset = open_dataset(dataset)
    if not isinstance(dataset, Dataset):
        raise DataError(f"needs a Dataset or a data source, got {type(dataset).__name__}", field="dataset")
    if not isinstance(transfer, TransferFunction):
        raise DataError(
            f"needs a TransferFunction, got {type(transfer).__name__}", path=dataset.source, field="transfer function"
        )
    if not (np.isfinite(exaggeration) and exaggeration > 0):
        raise DataError(f"must be positive, got {exaggeration!r}", path=dataset.source, field="exaggeration")
    if int(stride) != stride or stride < 1:
        raise DataError(f"must be an integer >= 1, got {stride!r}", path=dataset.source, field="stride")
    threshold = 0.0 if threshold is None else float(threshold)
    if not (np.isfinite(threshold) and threshold >= 0):
        raise DataError(f"must be >= 0, got {threshold!r}", path=dataset.source, field="threshold")
    kernel = splat_kernel() if kernel is None else kernel
    if not isinstance(kernel, SplatKernel):
        raise DataError(f"needs a SplatKernel, got {type(kernel).__name__}", field="kernel")
    if vertical not in ("shells", "native"):
        raise DataError(f"must be 'shells' or 'native', got {vertical!r}", path=dataset.source, field="vertical")
    return dataset, threshold, kernel


def _opaque_samples(dataset, var, hour, transfer, stride, threshold, kernel, exaggeration, vertical, shells):
    """The samples whose opacity exceeds ``threshold``: ``(centres, axes, opacity, grid index of each,
    shell heights or None, the shell sampler or None)``."""
    grid = dataset.grid
    values = dataset.read_at(var, float(hour))
    if vertical == "shells":
        heights = check_shells(shell_heights(grid) if shells is None else shells, dataset.source)
        sampler = ShellSampler(grid, heights)
        values = sampler(values)
    else:
        heights = None
        values = np.asarray(values, dtype=np.float64)
    opacity = np.nan_to_num(transfer(values[::stride, ::stride, ::stride]), nan=0.0)
    points, jac, factors, lam = _layout(grid, heights, stride, exaggeration, kernel, dataset.source)
    if factors is not None:
        opacity = opacity * factors
    sel_sub = np.nonzero(opacity > threshold)
    opacity = opacity[sel_sub]
    jac = jac[sel_sub]
    if lam is not None:
        jac = widen(jac, lam[0][sel_sub[1]], lam[1][sel_sub[0]])
    centers = points[sel_sub]
    axes = principal_axes(jac, kernel.radius)
    sel = tuple(a * stride for a in sel_sub)
    return centers, axes, opacity, sel, heights, (sampler if vertical == "shells" else None)


def splat_samples(
    dataset,
    var,
    hour,
    transfer,
    *,
    color_var=None,
    colormap=None,
    exaggeration=DEFAULT_EXAGGERATION,
    threshold=None,
    stride=1,
    kernel=None,
    vertical="shells",
    shells=None,
):
    """One splat per sample whose opacity exceeds ``threshold``, on shells or the grid's own levels.

    Parameters
    ----------
    dataset : Dataset or str
        A dataset, or a source for :func:`nephele.core.climate.readers.open_dataset`
        (``"demo"``, ``"demo:small"``, a file path).
    var : str
        Scalar behind the opacity (``"cloud"``).
    hour : float
        Hours since the first step (linear between steps).
    transfer : TransferFunction
        Opacity of ``var``.
    color_var : str, optional
        Variable for the colour (``"altitude"`` = height in metres); white when None.
    colormap : ColorMap, optional
        Its colours (defaults: the project's altitude and temperature maps,
        else a grey ramp over the values).
    exaggeration : float
        Vertical exaggeration of the globe.
    threshold : float, optional
        Keep samples with opacity (on shells: including the partition factor)
        strictly above it (default 0).
    stride : int
        Take every ``stride``-th sample along each grid axis (kernels grow to match).
    kernel : SplatKernel, optional
        Its cut-off sets the axes' length (default :func:`splat_kernel`).
    vertical : {"shells", "native"}
        ``"shells"`` (default): sample the field, column by column (linear in
        height), on levels at fixed heights above sea level, with kernels
        widened where the spacing changes fast and per-sample factors folded
        into the opacity, so that the weights sum to one within about 1e-3
        (:mod:`.partition`; on a longitude/latitude grid the longitudes must be
        evenly spaced; on a curvilinear grid the factors are solved per sample).
        ``"native"``: one splat per grid sample, ellipsoids from the cell
        Jacobians, no factors (on terrain-following levels over steep terrain
        the weights sum to one only within several per cent).
    shells : (n,) array, optional
        Shell heights in metres (default :func:`.partition.shell_heights`: the
        grid's level heights over the sea).

    Returns
    -------
    Splats
        Ordered by index (level or shell slowest, longitude fastest).  On
        shells, ``index[:, 0]`` is the shell and ``opacity`` is the transfer
        function's opacity times the sample's partition factor.

    References
    ----------
    .. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization", Fig. 3.
    """
    dataset, threshold, kernel = _check_inputs(dataset, transfer, exaggeration, stride, threshold, kernel, vertical)
    grid = dataset.grid
    centers, axes, opacity, sel, heights, sampler = _opaque_samples(
        dataset, var, hour, transfer, int(stride), threshold, kernel, exaggeration, vertical, shells
    )
    if vertical == "shells":
        height = heights[sel[0]]

        def pick(a):
            return sampler.at(a, sel)
    else:
        height = grid.height[sel]

        def pick(a):
            return np.asarray(a, dtype=np.float64)[sel]

    color = _color(dataset, color_var, colormap, float(hour), height, pick, sel[0].size)
    wind = _wind(dataset, float(hour), grid, exaggeration, sel, centers, pick)
    return Splats(centers, axes, color, opacity.astype(np.float32), wind, kernel.radius, np.column_stack(sel))


__all__ = ["ALTITUDE", "Splats", "splat_samples"]
