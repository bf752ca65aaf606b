"""Splat kernels: partition of unity on lattices (unit, sheared, globe cells), exact footprints."""

import numpy as np
import pytest
from scipy import ndimage

from nephele.core.climate.dataset import ArrayDataset, hourly
from nephele.core.climate.grid import GlobeGrid
from nephele.core.climate.synthetic import demo_dataset
from nephele.core.errors import DataError
from nephele.core.splats import (
    Splats,
    cell_jacobians,
    footprint_table,
    principal_axes,
    reconstruct,
    splat_kernel,
    splat_samples,
)
from nephele.core.splats.partition import shell_heights, shell_reach, stencil_weights, widening
from nephele.core.volume.transfer import TransferFunction


def lattice_sum(kernel, pts):
    """Σ_k w(x − k) over the integer lattice, at points in the unit cube."""
    n = int(np.ceil(kernel.radius)) + 1
    g = np.arange(-n, n + 2)
    lat = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return sum(kernel.weight(pts - k) for k in lat)


def worst_deviation(kernel, n=4000, seed=0):
    pts = np.random.default_rng(seed).random((n, 3))
    # Hard cases: lattice points, cell centres, face and edge midpoints.
    special = np.array([[0, 0, 0], [0.5, 0.5, 0.5], [0.5, 0, 0], [0.5, 0.5, 0], [0.25, 0.25, 0.25]])
    s = lattice_sum(kernel, np.vstack([pts, special]))
    return float(np.abs(s - 1.0).max())


def test_gaussian_kernel_is_a_partition_of_unity_within_1e3():
    worst = worst_deviation(splat_kernel("gaussian"))
    print(f"gaussian kernel: worst |sum - 1| on the unit lattice = {worst:.2e}")
    assert worst < 1e-3


def test_paper_kernel_is_within_half_a_percent_and_ours_is_better():
    paper = worst_deviation(splat_kernel("paper"))
    ours = worst_deviation(splat_kernel("gaussian"))
    print(f"paper kernel: worst |sum - 1| = {paper:.2e}, ours {ours:.2e}")
    assert paper < 5e-3  # the paper's claim: weights sum to within 0.5 % of 1
    assert ours < paper / 5


def test_vtk_gaussian_splatter_ripples_more_than_ours():
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    n = 16
    g = np.arange(n, dtype=np.float64)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    poly = vtk.vtkPolyData()
    vp = vtk.vtkPoints()
    vp.SetData(numpy_to_vtk(pts, deep=True))
    poly.SetPoints(vp)
    sp = vtk.vtkGaussianSplatter()
    sp.SetInputData(poly)
    sub = 4  # samples per cell
    dims = (n - 1) * sub + 1
    sp.SetSampleDimensions(dims, dims, dims)
    sp.SetModelBounds(0, n - 1, 0, n - 1, 0, n - 1)
    sp.SetRadius(2.5 / (n - 1))  # a fraction of the longest side of the volume: 2.5 cells
    sp.SetAccumulationModeToSum()
    sp.ScalarWarpingOff()
    sp.NormalWarpingOff()
    sp.CappingOff()
    sp.Update()
    vol = vtk_to_numpy(sp.GetOutput().GetPointData().GetScalars()).reshape(dims, dims, dims)
    inner = vol[4 * sub : -4 * sub, 4 * sub : -4 * sub, 4 * sub : -4 * sub]
    vtk_dev = float(np.abs(inner / inner.mean() - 1).max())
    ours = worst_deviation(splat_kernel("gaussian"))
    print(f"vtkGaussianSplatter (R 2.5 cells, exponent -5): worst deviation from its mean {vtk_dev:.2e}; ours "
          f"{ours:.2e}")
    assert vtk_dev > 5 * ours


def test_weight_is_zero_at_and_beyond_the_cutoff():
    k = splat_kernel()
    d = np.array([[k.radius, 0, 0], [0, 0, -k.radius * 1.01], [0, 0, 0]])
    w = k.weight(d)
    assert w[0] == 0 and w[1] == 0 and w[2] > 0
    assert k.footprint([[k.radius, 0.0]])[0] == 0


@pytest.mark.parametrize("kind", ["gaussian", "paper"])
def test_footprint_equals_a_numerical_line_integral(kind):
    integrate = pytest.importorskip("scipy.integrate")
    k = splat_kernel(kind)
    rng = np.random.default_rng(3)
    p = np.vstack([[0.0, 0.0], [2.4, 0.3], rng.uniform(-2.0, 2.0, (12, 2))])
    ref = np.array([integrate.quad(lambda z, x=x, y=y: k.weight([[x, y, z]])[0], -3, 3, points=[0], limit=200,
                                   epsabs=1e-13)[0] for x, y in p])
    assert np.abs(k.footprint(p) - ref).max() < 1e-9 * k.peak
    # The renderer's ρ² table.
    assert np.abs(k.footprint_rho2(np.sum(p * p, axis=1)) - ref).max() < 1e-6 * k.peak
    # The footprint integrates to 1 over the view plane (the kernel's integral).
    assert 2 * np.pi * integrate.quad(lambda r: r * k.footprint([[r, 0.0]])[0], 0,
                                      k.radius)[0] == pytest.approx(1.0, abs=1e-9)


def test_footprint_table_matches_line_integrals_at_texel_centres():
    integrate = pytest.importorskip("scipy.integrate")
    k = splat_kernel()
    t = footprint_table(k, 32)
    assert t.shape == (32, 32) and t.dtype == np.float32
    c = -k.radius + (np.arange(32) + 0.5) * (2 * k.radius / 32)
    for j, i in [(0, 0), (15, 16), (16, 16), (3, 20), (31, 9)]:
        ref = integrate.quad(lambda z, i=i, j=j: k.weight([[c[i], c[j], z]])[0], -3, 3, limit=200)[0]
        assert abs(t[j, i] - ref) < 1e-3 * k.peak
    assert t.max() <= k.peak
    assert footprint_table(k, 33, normalized=True).max() == pytest.approx(1.0, abs=1e-6)  # odd size samples the centre
    assert np.allclose(t, t.T) and np.allclose(t, t[::-1])


def test_bad_kernel_arguments_raise_data_error():
    for call in (
        lambda: splat_kernel("cubic"),
        lambda: splat_kernel(radius=-1),
        lambda: splat_kernel(sigma=np.nan),
        lambda: splat_kernel(window=1.5),
        lambda: footprint_table(splat_kernel(), 1),
        lambda: footprint_table("gaussian"),
    ):
        with pytest.raises(DataError):
            call()


def lattice_splats(jac, n, kernel):
    """Splats on the lattice ``jac @ k`` for k in 0..n-1 along each axis."""
    g = np.arange(n, dtype=np.float64)
    idx = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    m = len(idx)
    axes = principal_axes(np.broadcast_to(jac, (m, 3, 3)), kernel.radius)
    return Splats(idx @ jac.T, axes, np.ones((m, 3)), np.ones(m), np.zeros((m, 3)), kernel.radius)


def test_sheared_lattice_after_the_jacobian_mapping():
    k = splat_kernel()
    jac = 0.1 * np.array([[1.0, 0.4, 0.1], [0.0, 0.8, 0.3], [0.2, 0.0, 1.3]])
    sp = lattice_splats(jac, 12, k)
    a = sp.axes[0]
    assert np.allclose(a.T @ a, np.diag(np.diag(a.T @ a)), atol=1e-12) and np.linalg.det(a) > 0
    u = np.random.default_rng(1).uniform(4, 7, (1500, 3))
    s = reconstruct(sp, k, u @ jac.T)
    worst = float(np.abs(s - 1).max())
    print(f"sheared lattice: worst |sum - 1| = {worst:.2e}")
    assert worst < 1e-3


def globe_block(levels):
    """A 31×31-column block of the full demo grid (22–57°N, 0–34°E) with the given level heights."""
    full = demo_dataset("full").grid
    lon, lat = full.lon[:31], full.lat[100:131]
    if levels == "demo":
        h = full.height[:, 100:131, :31]
    else:
        h = np.broadcast_to(np.linspace(0.0, 20000.0, full.shape[0])[:, None, None], (full.shape[0], 31, 31)).copy()
    return GlobeGrid(lon, lat, h)


def curvilinear_partition(grid, m=800, seed=0, vertical="native"):
    """Worst |Σ opacity·w − 1| (what the renderer draws for a constant field of opacity 1) at
    random points inside the grid's interior (3 cells from every edge)."""
    k = splat_kernel()
    ds = ArrayDataset(grid, hourly("2000-01-01", 1), {"cloud": np.ones((1,) + grid.shape)})
    sp = splat_samples(ds, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), kernel=k, vertical=vertical)
    nk, nj, ni = grid.shape
    rng = np.random.default_rng(seed)
    f = np.column_stack([rng.uniform(3, nk - 4, m), rng.uniform(3, nj - 4, m), rng.uniform(3, ni - 4, m)])
    # Points inside the curvilinear cells: trilinear in the cell corners.
    p = grid.points(1.0, 30.0, dtype=np.float64)
    b = np.floor(f).astype(int)
    fr = f - b
    x = np.zeros((m, 3))
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([fr[:, a] if c else 1 - fr[:, a] for a, c in enumerate(corner)], axis=0)
        x += w[:, None] * p[b[:, 0] + corner[0], b[:, 1] + corner[1], b[:, 2] + corner[2]]
    return float(np.abs(reconstruct(sp, k, x, values=sp.opacity) - 1).max())


def test_globe_cells_with_even_levels_are_a_partition_within_1e3():
    # Curvature of the sphere and converging meridians, levels evenly spaced.
    worst = curvilinear_partition(globe_block("even"))
    print(f"globe cells (1.125 deg, 19 even levels): worst |sum - 1| = {worst:.2e}")
    assert worst < 1e-3


def test_demo_stretched_levels_measured():
    # The demo's own terrain-following levels (vertical="native"): a per-sample ellipsoid is the
    # affine approximation of the grid map, so the weights sum to one only within a few per cent.
    worst = curvilinear_partition(globe_block("demo"))
    print(f"demo cells (stretched terrain-following levels, native): worst |sum - 1| = {worst:.2e}")
    assert worst < 0.05


def interior_sweep(grid, kernel, m=3000, seed=0, exaggeration=30.0, reach=4):
    """|Σ w − 1| at ``m`` random points of the whole grid's interior (3 cells from the top,
    bottom and poles; all longitudes, across the seam), summing every sample within
    ``reach`` index steps of the point's cell.  Returns the points' fractional
    indices ``(k, j, i)`` and the deviations."""
    nk, nj, ni = grid.shape
    p, jac = cell_jacobians(grid, exaggeration)
    to_cell = kernel.radius * np.linalg.inv(principal_axes(jac.reshape(-1, 3, 3), kernel.radius)).reshape(jac.shape)
    rng = np.random.default_rng(seed)
    f = np.column_stack([rng.uniform(3, nk - 4, m), rng.uniform(3, nj - 4, m), rng.uniform(0, ni, m)])
    b = np.floor(f).astype(int)
    fr = f - b
    x = np.zeros((m, 3))
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([fr[:, a] if c else 1 - fr[:, a] for a, c in enumerate(corner)], axis=0)
        x += w[:, None] * p[b[:, 0] + corner[0], b[:, 1] + corner[1], (b[:, 2] + corner[2]) % ni]
    total = np.zeros(m)
    for off in np.ndindex(2 * reach + 2, 2 * reach + 2, 2 * reach + 2):
        t = b + np.array(off) - reach
        ok = (t[:, 0] >= 0) & (t[:, 0] < nk) & (t[:, 1] >= 0) & (t[:, 1] < nj)
        k, j, i = t[ok, 0], t[ok, 1], t[ok, 2] % ni
        d = np.einsum("nij,nj->ni", to_cell[k, j, i], x[ok] - p[k, j, i])
        total[ok] += kernel.weight(d)
    return f, np.abs(total - 1)


def drawn_sum(sp, layout, kernel, f, reach, exaggeration=30.0):
    """Σ opacity_s w_s at points of fractional layout indices ``f`` (m, 3), with each splat's own
    axes and opacity (what the renderers draw), and whether every layout sample within
    ``reach`` of the point's cell is a splat (False: next to the ground, where shells below
    the terrain have none)."""
    shape = layout.shape
    p = layout.points(1.0, exaggeration, dtype=np.float64)
    k, j, i = sp.index.T
    assert np.allclose(sp.centers, p[k, j, i], rtol=0, atol=1e-12)
    to_cell = np.tile(np.eye(3), shape + (1, 1))
    fac = np.zeros(shape)
    present = np.zeros(shape, bool)
    to_cell[k, j, i] = sp.radius * np.linalg.inv(sp.axes)
    fac[k, j, i] = sp.opacity
    present[k, j, i] = True
    row, kk, jj, ii, w = stencil_weights(p, to_cell, f, kernel, reach)
    total = np.bincount(row, w * fac[kk, jj, ii], minlength=len(f))
    size = tuple(2 * r + 2 for r in reach)  # the stencil: offsets -r .. r + 1 from the cell's corner
    full = ndimage.minimum_filter(present.astype(np.uint8), size=size, origin=(-1, -1, -1),
                                  mode=("nearest", "nearest", "wrap"))
    b = np.floor(f).astype(int)
    return total, full[b[:, 0], b[:, 1], b[:, 2] % shape[2]].astype(bool)


def demo_grid(every):
    """The full demo's grid, every ``every``-th column and row (its terrain and levels there)."""
    g = demo_dataset("full").grid
    if every == 1:
        return g
    return GlobeGrid(g.lon[::every], g.lat[::every], g.height[:, ::every, ::every].copy())


# The demo's own 320 x 160 x 19 grid (12 CPU s) is the full tier's; the quick tier runs the same
# globe at every second column and row (2.25 degree cells: the seam, both polar caps, the same levels).
@pytest.mark.parametrize("every", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_demo_on_shells_is_a_partition_within_1e3(every):
    # The default layout: the demo's field on shells (its level heights over the sea, fixed
    # height above sea level), kernels widened near the poles and the bottom, factors folded
    # into the opacity.  Measured with the splats' own axes and opacities at 3000 random
    # points of the whole interior (3 shells from the bottom and top, 3 rows from the poles,
    # all longitudes across the seam) whose neighbourhood has all its splats.
    full = demo_grid(every)
    k = splat_kernel()
    ds = ArrayDataset(full, hourly("2000-01-01", 1), {"cloud": np.ones((1,) + full.shape, np.float32)})
    sp = splat_samples(ds, "cloud", 0.0, TransferFunction(points=((0.0, 1.0),)), kernel=k)
    h = shell_heights(full)
    layout = GlobeGrid(full.lon, full.lat, np.broadcast_to(h[:, None, None], full.shape).copy())
    nk, nj, ni = full.shape
    rk, rj, ri = shell_reach(full.lat, h, k.radius, *widening(full.lat, h, k.radius))
    reach = (int(rk[3 : nk - 3].max()), rj, int(ri[3 : nj - 3].max()))
    rng = np.random.default_rng(0)
    f = np.column_stack([rng.uniform(3, nk - 4, 3000), rng.uniform(3, nj - 4, 3000), rng.uniform(0, ni, 3000)])
    s, ok = drawn_sum(sp, layout, k, f, reach)
    e = np.abs(s - 1)
    lat = np.abs(np.interp(f[:, 1], np.arange(nj), full.lat))
    polar = ok & (lat > 75)
    print(f"demo on shells: {ok.sum()} of 3000 points away from the ground: worst |sum - 1| = {e[ok].max():.2e}, "
          f"median {np.median(e[ok]):.2e}; |lat| > 75: {e[polar].max():.2e} ({polar.sum()} points); "
          f"shells 3-6: {e[ok & (f[:, 0] < 6)].max():.2e}")
    assert ok.sum() > 1500 and polar.sum() > 100
    assert e[ok].max() < 1e-3
    # Next to the ground the sum falls off (no splats below the terrain): the field ends there.
    assert np.all(s[~ok] < 1 + 1e-3)


# On the demo's full grid (8 CPU s): the full tier's.  The quick tier keeps both halves on smaller
# blocks: test_demo_stretched_levels_measured (the demo's levels, a few per cent) and
# test_globe_cells_with_even_levels_are_a_partition_within_1e3.
@pytest.mark.slow
def test_demo_grid_interior_sweep_measured():
    # The 1e-3 goal on the demo's real cells is NOT met: the worst deviation over the whole
    # interior is ~8e-2 (median ~2e-3).  Cause: a per-sample ellipsoid is the affine
    # approximation of the grid map at the sample; the sum's error is second order in
    # G = J⁻¹ ∂²x/∂ξ² (times the kernel's variance), and the terrain-following levels have
    # large G: stretched spacing (eta^1.4, alone 1.4e-2 on a 31×31 block) and level surfaces
    # whose tilt changes from column to column over terrain (even levels over terrain alone:
    # 2.0e-2).  The same sweep with levels at fixed heights above sea level meets 1e-3
    # away from the poles (the converging meridians make G large at |lat| > 75°).
    full = demo_dataset("full").grid
    k = splat_kernel()
    f, e = interior_sweep(full, k)
    low, high = f[:, 0] < 6, f[:, 0] >= 10
    print(f"demo grid interior, {e.size} points: worst |sum - 1| = {e.max():.2e}, median {np.median(e):.2e}, "
          f"90th percentile {np.percentile(e, 90):.2e}; levels 3-6 worst {e[low].max():.2e}, levels 10-15 worst "
          f"{e[high].max():.2e}")
    assert e.max() < 0.15 and np.median(e) < 5e-3
    assert e[high].max() < e[low].max()  # the error follows the stretching and the terrain, both largest low down
    even = GlobeGrid(full.lon, full.lat,
                     np.broadcast_to(np.linspace(0.0, 20000.0, full.shape[0])[:, None, None], full.shape).copy())
    f, e = interior_sweep(even, k)
    lat = np.interp(f[:, 1], np.arange(full.shape[1]), full.lat)
    mid = np.abs(lat) < 75
    print(f"same grid, levels at fixed heights: worst |sum - 1| = {e[mid].max():.2e} at |lat| < 75°, {e.max():.2e} "
          "overall")
    assert e[mid].max() < 1e-3
