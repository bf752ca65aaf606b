"""Isosurfaces on curvilinear grids: topology on hard cases, accuracy against
analytic surfaces, agreement with VTK and scikit-image."""

import numpy as np
import pytest

from nephele.core.climate.grid import GlobeGrid, lonlat_to_xyz
from nephele.core.errors import DataError
from nephele.core.surface import _mc_tables as tables
from nephele.core.surface import contour
from nephele.core.surface.contour import EDGE_MARGIN, isosurface, regular_points
from nephele.core.surface.mesh import triangle_areas

METHODS = ["cubes", "tetra5"]
CENTRE = np.array([0.1, 0.05, 0.2])  # off the grid's centre: the sphere cuts every kind of edge


def edge_counts(faces):
    """How many faces use each undirected edge."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def directed_edges_unique(faces):
    """Consistent winding: every directed edge appears once (its twin runs the other way)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return len(np.unique(e, axis=0)) == len(e)


def assert_closed_manifold(mesh):
    """Watertight, two faces per edge, consistently wound, no zero-area or repeated triangle."""
    assert not mesh.is_empty
    assert np.all(np.isfinite(mesh.vertices))
    counts = edge_counts(mesh.faces)
    assert counts.min() == 2 and counts.max() == 2, f"edges used {np.unique(counts)} times"
    assert directed_edges_unique(mesh.faces), "winding is not consistent"
    assert triangle_areas(mesh.vertices, mesh.faces).min() > 0.0
    assert len(np.unique(np.sort(mesh.faces, axis=1), axis=0)) == len(mesh.faces)
    tm = mesh.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent


def shell_points(ni, nj, nk, poles=True, r=(0.2, 1.2)):
    """A spherical-shell lon × lat × r grid (periodic in longitude, rows at ±90° if ``poles``)."""
    lon = np.arange(ni) * 360.0 / ni
    lat = np.linspace(-90.0, 90.0, nj) if poles else np.linspace(-80.0, 80.0, nj)
    rad = np.linspace(r[0], r[1], nk)
    return lonlat_to_xyz(lon[None, None, :], lat[None, :, None], rad[:, None, None])


def sheared_points(n, wobble=0.0):
    """A sheared (and optionally bent) curvilinear grid covering [-1, 1]^3 and more."""
    u = np.arange(n + 1) * 2.0 / n - 1.0
    k, j, i = np.meshgrid(u, u, u, indexing="ij")
    x = i + 0.3 * j + 0.1 * k + wobble * np.sin(3 * j)
    y = j + 0.2 * k
    z = k + wobble * np.cos(2 * i)
    return np.stack([x, y, z], axis=-1)


# ---------------------------------------------------------------- tables


@pytest.mark.parametrize("split", range(len(tables.SPLITS)))
def test_tetrahedral_splits_fill_the_cube_exactly_once(split):
    tets = tables.SPLITS[split]
    corners = tables.CORNERS.astype(float)
    volume = sum(abs(np.linalg.det(corners[list(t[1:])] - corners[t[0]])) / 6 for t in tets)
    assert volume == pytest.approx(1.0)
    x = np.random.default_rng(0).random((4000, 3))
    hits = np.zeros(len(x), int)
    for t in tets:
        p = corners[list(t)]
        lam = (x - p[0]) @ np.linalg.inv((p[1:] - p[0]).T).T
        hits += (lam >= 0).all(axis=1) & (lam.sum(axis=1) <= 1)
    assert np.all(hits == 1)


def test_seam_split_flips_only_the_diagonal_toward_the_seam():
    def diagonals(tets):
        out = set()
        for t in tets:
            for a in t:
                for b in t:
                    if a < b and bin(a ^ b).count("1") == 2:
                        out.add((a, b))
        return out

    for standard, seam in ((tables.EVEN, tables.SEAM_EVEN), (tables.ODD, tables.SEAM_ODD)):
        d0, d1 = diagonals(standard), diagonals(seam)
        face1 = {p for p in d0 | d1 if tables.CORNERS[p[0], 0] == 1 and tables.CORNERS[p[1], 0] == 1}
        assert len(face1 & d0) == 1 and len(face1 & d1) == 1 and face1 & d0 != face1 & d1
        assert d0 - face1 == d1 - face1 and len(d0) == 6


def test_cube_table_normals_point_toward_the_corners_below():
    table, ntri = tables.cube_table()
    mid = {e: tables.CORNERS[list(p)].mean(axis=0) for e, p in enumerate(tables.PAIRS)}
    for config in range(1, 255):
        above = [(config >> c) & 1 for c in range(8)]
        down = tables.CORNERS[[c for c in range(8) if not above[c]]].mean(axis=0)
        up = tables.CORNERS[[c for c in range(8) if above[c]]].mean(axis=0)
        flux = sum(np.dot(np.cross(mid[b] - mid[a], mid[c] - mid[a]), down - up)
                   for a, b, c in table[config, : ntri[config]])
        assert flux >= 0  # zero only for the symmetric configurations
    assert ntri[0] == ntri[255] == 0


# ---------------------------------------------------------------- closed surfaces


@pytest.mark.parametrize("method", METHODS)
def test_sphere_regular_grid_closed_normals_toward_decreasing_values(method):
    p = regular_points((24, 25, 26), spacing=(0.05, 0.05, 0.05))
    c = np.array([0.6, 0.62, 0.58])
    v = np.linalg.norm(p - c, axis=-1)  # increases outward: normals must point inward
    mesh = isosurface(p, v, 0.4, method=method)
    assert_closed_manifold(mesh)
    grad = (mesh.vertices - c) / np.linalg.norm(mesh.vertices - c, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", mesh.normals, grad) < -0.9)
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-5)
    # Faces agree with the normals: signed volume is negative (they face the inside).
    tri = mesh.vertices[mesh.faces].astype(float)
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert signed == pytest.approx(-4 / 3 * np.pi * 0.4**3, rel=0.02)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("ni", [36, 37])
def test_sphere_in_spherical_shell_with_poles_and_seam(method, ni):
    p = shell_points(ni, 19, 15)
    v = np.linalg.norm(p - CENTRE, axis=-1)
    mesh = isosurface(p, v, 0.6, periodic_lon=True, method=method)
    assert_closed_manifold(mesh)
    # The sphere crosses the polar axis once at each pole: one vertex there, not one per longitude.
    r_axis = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])
    assert np.count_nonzero(r_axis < 1e-6) == 2
    d = np.abs(np.linalg.norm(mesh.vertices - CENTRE, axis=1) - 0.6)
    assert d.max() < 0.02


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("ni", [20, 21])
def test_seam_without_periodic_leaves_an_open_surface(method, ni):
    # A torus around the polar axis cuts the seam; only periodic_lon closes it.
    p = shell_points(ni, 15, 12, poles=False)
    rho = np.hypot(p[..., 0], p[..., 1])
    v = np.hypot(rho - 0.7, p[..., 2])
    closed = isosurface(p, v, 0.25, periodic_lon=True, method=method)
    assert_closed_manifold(closed)
    open_ = isosurface(p, v, 0.25, periodic_lon=False, method=method)
    assert edge_counts(open_.faces).min() == 1


def test_odd_ring_cracks_without_the_seam_split(monkeypatch):
    # The check above is sensitive: with plain (i+j+k) parity the odd seam cracks.
    p = shell_points(21, 15, 12, poles=False)
    v = np.hypot(np.hypot(p[..., 0], p[..., 1]) - 0.7, p[..., 2])
    table, ntri, pairs = contour._tet_lookup()
    plain = (table[[0, 1, 0, 1]], ntri[[0, 1, 0, 1]], pairs)
    monkeypatch.setattr(contour, "_tet_lookup", lambda: plain)
    mesh = isosurface(p, v, 0.25, periodic_lon=True, method="tetra5")
    assert edge_counts(mesh.faces).min() == 1


@pytest.mark.parametrize("method", METHODS)
def test_pole_rows_with_different_values_per_longitude(method):
    # Data that disagree along a pole row are averaged: the pole is one point with one value.
    p = shell_points(16, 11, 10)
    v = np.linalg.norm(p - CENTRE, axis=-1)
    rng = np.random.default_rng(3)
    v[:, 0, :] += 0.02 * rng.standard_normal(v[:, 0, :].shape)
    v[:, -1, :] += 0.02 * rng.standard_normal(v[:, -1, :].shape)
    mesh = isosurface(p, v, 0.6, periodic_lon=True, method=method)
    assert_closed_manifold(mesh)


@pytest.mark.parametrize("method", METHODS)
def test_random_fields_at_the_poles_stay_manifold(method):
    # Merging the pole vertices must never join more than two triangles at an edge
    # (a fan diagonal in one polar cell could otherwise meet its twin in the next).
    rng = np.random.default_rng(11)
    for _ in range(40):
        ni, nj, nk = (int(n) for n in rng.integers((3, 3, 2), (14, 9, 6)))
        p = shell_points(ni, nj, nk, r=(0.5, 1.5))
        v = rng.integers(0, 3, size=(nk, nj, ni)).astype(float) if rng.random() < 0.5 else rng.random((nk, nj, ni))
        mesh = isosurface(p, v, 1.0 if rng.random() < 0.5 else 0.5, periodic_lon=True, method=method)
        if mesh.is_empty:
            continue
        assert edge_counts(mesh.faces).max() == 2
        assert directed_edges_unique(mesh.faces)
        assert triangle_areas(mesh.vertices, mesh.faces).min() > 0
        assert np.all(np.isfinite(mesh.normals))


def test_pole_at_one_level_only():
    # A row that collapses at the lowest level only (a cone's apex): its cells
    # take the centre-fanned table; still no edge with more than two triangles.
    rng = np.random.default_rng(2)
    p = shell_points(9, 7, 4, r=(0.5, 1.5))
    p[0, -1] = p[0, -1].mean(axis=0)
    for _ in range(30):
        v = rng.random(p.shape[:3])
        mesh = isosurface(p, v, 0.5, periodic_lon=True)
        assert edge_counts(mesh.faces).max() == 2
        assert directed_edges_unique(mesh.faces)
        assert triangle_areas(mesh.vertices, mesh.faces).min() > 0


def test_globe_grid_points_at_the_poles():
    lon = np.arange(32) * 360.0 / 32
    lat = np.linspace(-90, 90, 17)
    height = np.broadcast_to(np.linspace(0, 20000, 9)[:, None, None], (9, 17, 32))
    grid = GlobeGrid(lon, lat, height)
    p = grid.points(exaggeration=30)
    r = np.linalg.norm(p.astype(float), axis=-1)
    # A blob around each pole reaching from the ground up to mid-height.
    v = np.abs(lat)[None, :, None] / 90.0 - (r - 1.0) / 0.2
    mesh = isosurface(p, v, 0.8, periodic_lon=grid.periodic_lon, method="cubes")
    assert not mesh.is_empty
    assert triangle_areas(mesh.vertices, mesh.faces).min() > 0
    counts = edge_counts(mesh.faces)
    assert counts.max() == 2  # open only at the ground (level 0), never non-manifold


@pytest.mark.parametrize("method", METHODS)
def test_close_poles_on_cell_centred_latitudes(method):
    # Latitudes stop at ±85°: the polar caps are holes unless the poles are added.
    ni, nj = 24, 18
    lon = np.arange(ni) * 360.0 / ni
    lat = -85.0 + 10.0 * np.arange(nj)
    p = lonlat_to_xyz(lon[None, None, :], lat[None, :, None], np.linspace(0.2, 1.2, 11)[:, None, None])
    v = np.linalg.norm(p - CENTRE, axis=-1)
    alt = np.linalg.norm(p, axis=-1)
    holes = isosurface(p, v, 0.6, periodic_lon=True, method=method)
    assert edge_counts(holes.faces).min() == 1
    mesh = isosurface(p, v, 0.6, periodic_lon=True, method=method, close_poles=True, attributes={"r": alt})
    assert_closed_manifold(mesh)
    assert np.count_nonzero(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1]) < 1e-6) == 2
    assert np.abs(np.linalg.norm(mesh.vertices - CENTRE, axis=1) - 0.6).max() < 0.03
    # The radius attribute is linear along radial pole edges: exact there too.
    assert np.allclose(mesh.attributes["r"], np.linalg.norm(mesh.vertices, axis=1), atol=0.02)
    # A grid that already has its poles is left as it is.
    with_poles = shell_points(ni, 19, 11)
    vp = np.linalg.norm(with_poles - CENTRE, axis=-1)
    a = isosurface(with_poles, vp, 0.6, periodic_lon=True, method=method)
    b = isosurface(with_poles, vp, 0.6, periodic_lon=True, method=method, close_poles=True)
    assert np.array_equal(a.faces, b.faces) and np.allclose(a.vertices, b.vertices)
    with pytest.raises(DataError):
        isosurface(p, v, 0.6, close_poles=True)
    # A latitude band is not closed: its edge rows are far from the poles.
    band = p[:, 5:-5]
    vb = v[:, 5:-5]
    assert np.array_equal(
        isosurface(band, vb, 0.6, periodic_lon=True, close_poles=True).faces,
        isosurface(band, vb, 0.6, periodic_lon=True).faces,
    )


# ---------------------------------------------------------------- values at the level


@pytest.mark.parametrize("method", METHODS)
def test_values_exactly_at_the_level_integer_sphere(method):
    # i²+j²+k² = 25 has many integer solutions: grid points lying exactly on the surface.
    p = regular_points((15, 15, 15), origin=(-7, -7, -7))
    v = (p.astype(np.float64) ** 2).sum(axis=-1)
    assert np.count_nonzero(v == 25.0) > 20
    mesh = isosurface(p, v, 25.0, method=method)
    assert_closed_manifold(mesh)
    d = np.linalg.norm(mesh.vertices, axis=1)
    assert d.min() > 4.6 and d.max() <= 5.0 + 1e-5


@pytest.mark.parametrize("method", METHODS)
def test_values_exactly_at_the_level_random_integer_fields(method):
    # Plateaus, saddles and spikes all exactly at the level.
    rng = np.random.default_rng(1)
    for _ in range(25):
        v = np.pad(rng.integers(0, 3, size=rng.integers(2, 7, size=3)), 1).astype(np.float32)
        mesh = isosurface(regular_points(v.shape), v, 1.0, method=method)
        if not mesh.is_empty:
            assert_closed_manifold(mesh)
            # Vertices keep their margin from the grid points, never more.
            frac = np.abs(mesh.vertices - np.round(mesh.vertices))
            assert frac[frac > 0].min() >= EDGE_MARGIN * 0.999


def test_level_cast_to_float32_values():
    # 0.15 is not a float32: values equal to float32(0.15) still count as at the level.
    v = np.zeros((4, 4, 4), np.float32)
    v[1:3, 1:3, 1:3] = np.float32(0.15)
    mesh = isosurface(regular_points(v.shape), v, 0.15)
    assert_closed_manifold(mesh)
    # The cube's surface sits at the plateau's grid points (within the margin).
    assert np.abs(mesh.vertices - np.clip(np.round(mesh.vertices), 1, 2)).max() <= EDGE_MARGIN * 1.01


# ---------------------------------------------------------------- NaN, empty, constant


@pytest.mark.parametrize("method", METHODS)
def test_nan_cells_are_skipped(method):
    p = regular_points((20, 20, 20), spacing=(0.1, 0.1, 0.1))
    v = np.linalg.norm(p - 0.95, axis=-1)
    full = isosurface(p, v, 0.6, method=method)
    # NaN far from the surface changes nothing.
    far = v.copy()
    far[:2, :2, :2] = np.nan
    same = isosurface(p, far, 0.6, method=method)
    assert np.array_equal(same.faces, full.faces) and np.allclose(same.vertices, full.vertices)
    # NaN on the surface leaves a hole: no NaN vertex, no vertex in the cells around the NaN.
    hole = v.copy()
    hole[10, 10, 16] = np.nan  # a grid point near x = 1.6, where the sphere passes
    mesh = isosurface(p, hole, 0.6, method=method)
    assert np.all(np.isfinite(mesh.vertices)) and np.all(np.isfinite(mesh.normals))
    assert edge_counts(mesh.faces).min() == 1 and edge_counts(mesh.faces).max() == 2
    near = np.abs(mesh.vertices - p[10, 10, 16]).max(axis=1) < 0.1 - 1e-6
    assert not near.any()
    assert len(mesh.faces) < len(full.faces)
    assert directed_edges_unique(mesh.faces)


@pytest.mark.parametrize("method", METHODS)
def test_empty_results(method):
    p = regular_points((5, 6, 7))
    v = np.random.default_rng(0).random((5, 6, 7))
    for level in (2.0, -1.0):
        mesh = isosurface(p, v, level, method=method, attributes={"t": v})
        assert mesh.is_empty and mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3)
        assert mesh.attributes["t"].shape == (0,)
    for const in (0.0, 0.5, 1.0):
        assert isosurface(p, np.full((5, 6, 7), const), 0.5, method=method).is_empty
    assert isosurface(p, np.full((5, 6, 7), np.nan), 0.5, method=method).is_empty


def test_bad_input_names_the_field():
    p = regular_points((4, 4, 4))
    v = np.zeros((4, 4, 4))
    cases = [
        (dict(points=p[:, :, :3]), "points"),
        (dict(values=np.zeros((4, 4))), "values"),
        (dict(level=np.nan), "level"),
        (dict(method="cubes2"), "method"),
        (dict(attributes={"alt": np.zeros(3)}), "alt"),
        (dict(points=p[:, :, :2], values=v[:, :, :2], periodic_lon=True), "values"),
    ]
    for change, field in cases:
        kwargs = dict(points=p, values=v, level=0.5)
        kwargs.update(change)
        with pytest.raises(DataError) as err:
            isosurface(kwargs.pop("points"), kwargs.pop("values"), kwargs.pop("level"), **kwargs)
        assert err.value.field == field


# ---------------------------------------------------------------- attributes


@pytest.mark.parametrize("method", METHODS)
def test_attributes_linear_in_position_are_exact(method):
    p = sheared_points(12, wobble=0.05)
    v = ((p / [0.7, 0.5, 0.35]) ** 2).sum(axis=-1)
    lin = 2.0 * p[..., 0] - p[..., 1] + 3.0 * p[..., 2] + 0.5
    mesh = isosurface(p, v, 1.0, method=method, attributes={"lin": lin, "alt": p[..., 2]})
    x = mesh.vertices.astype(float)
    assert np.allclose(mesh.attributes["lin"], 2 * x[:, 0] - x[:, 1] + 3 * x[:, 2] + 0.5, atol=2e-6)
    assert np.allclose(mesh.attributes["alt"], x[:, 2], atol=1e-6)
    assert mesh.attributes["lin"].dtype == np.float32


# ---------------------------------------------------------------- accuracy


def slope(h, err):
    return np.polyfit(np.log(h), np.log(err), 1)[0]


@pytest.mark.parametrize("method", METHODS)
def test_sphere_in_shell_converges_second_order(method):
    h, dist, area = [], [], []
    for s in (1, 2, 4):
        p = shell_points(24 * s, 12 * s + 1, 10 * s + 1)
        v = np.linalg.norm(p - CENTRE, axis=-1)
        mesh = isosurface(p, v, 0.6, periodic_lon=True, method=method)
        d = np.linalg.norm(mesh.vertices.astype(float) - CENTRE, axis=1) - 0.6
        h.append(1.0 / s)
        dist.append(np.abs(d).max())
        area.append(abs(mesh.area() / (4 * np.pi * 0.36) - 1))
    assert slope(h, dist) == pytest.approx(2.0, abs=0.25)
    assert slope(h, area) == pytest.approx(2.0, abs=0.25)
    assert area[-1] < 2e-3


def ellipsoid_area(a, b, c):
    """Exact surface area of a triaxial ellipsoid (Legendre's elliptic-integral form)."""
    from scipy.special import ellipeinc, ellipkinc

    a, b, c = sorted((a, b, c), reverse=True)
    phi = np.arccos(c / a)
    m = a * a * (b * b - c * c) / (b * b * (a * a - c * c))
    s = np.sin(phi)
    return 2 * np.pi * c * c + 2 * np.pi * a * b / s * (ellipeinc(phi, m) * s * s + ellipkinc(phi, m) * (1 - s * s))


@pytest.mark.parametrize("method", METHODS)
def test_ellipsoid_in_sheared_grid_converges_second_order(method):
    axes = np.array([0.7, 0.5, 0.35])
    exact = ellipsoid_area(*axes)
    assert ellipsoid_area(1, 1, 1 - 1e-9) == pytest.approx(4 * np.pi, rel=1e-6)
    h, dist, area = [], [], []
    for n in (16, 32, 64):
        p = sheared_points(n)
        mesh = isosurface(p, ((p / axes) ** 2).sum(axis=-1), 1.0, method=method)
        assert_closed_manifold(mesh)
        # Radial distance in the ellipsoid's unit-sphere coordinates.
        d = np.linalg.norm(mesh.vertices.astype(float) / axes, axis=1) - 1
        h.append(2.0 / n)
        dist.append(np.abs(d).max())
        area.append(abs(mesh.area() / exact - 1))
    assert slope(h, dist) == pytest.approx(2.0, abs=0.25)
    assert slope(h, area) == pytest.approx(2.0, abs=0.25)


# ---------------------------------------------------------------- independent tools


def vtk_contour(points, values, level):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    nk, nj, ni = values.shape
    grid = vtk.vtkStructuredGrid()
    grid.SetDimensions(ni, nj, nk)
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(points.reshape(-1, 3), dtype=np.float64), deep=True))
    grid.SetPoints(pts)
    grid.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(values.reshape(-1), dtype=np.float64), deep=True))
    f = vtk.vtkContourFilter()
    f.SetInputData(grid)
    f.SetValue(0, level)
    f.Update()
    out = f.GetOutput()
    return vtk_to_numpy(out.GetPoints().GetData()), vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)


def test_agrees_with_vtk_contour_filter_on_structured_grid():
    from scipy.spatial import cKDTree

    p = sheared_points(40, wobble=0.05)
    v = ((p / [0.7, 0.5, 0.35]) ** 2).sum(axis=-1)
    mesh = isosurface(p, v, 1.0)
    vv, vf = vtk_contour(p, v, 1.0)
    assert abs(len(mesh.faces) / len(vf) - 1) < 0.01
    assert len(mesh.vertices) == len(vv)  # one vertex per crossed edge, as VTK
    assert mesh.area() == pytest.approx(triangle_areas(vv, vf).sum(), rel=1e-3)
    # Same vertices (ours keep a 0.1 %-of-an-edge margin from grid points).
    cell = 2.0 / 40 * 1.4
    assert cKDTree(vv).query(mesh.vertices)[0].max() < 2 * EDGE_MARGIN * cell
    assert cKDTree(mesh.vertices).query(vv)[0].max() < 2 * EDGE_MARGIN * cell


def test_agrees_with_vtk_on_the_globe_shell():
    # A cloud-like field on a lat/lon sector (no seam, no pole: VTK has neither).
    lon = np.linspace(0, 90, 46)
    lat = np.linspace(-40, 40, 41)
    height = np.broadcast_to(np.linspace(0, 15000, 12)[:, None, None], (12, 41, 46))
    p = GlobeGrid(lon, lat, height).points().astype(np.float64)
    lam = np.deg2rad(lon)[None, None, :]
    phi = np.deg2rad(lat)[None, :, None]
    up = np.linspace(0, 1, 12)[:, None, None]
    v = np.sin(3 * lam) * np.cos(2 * phi) * np.cos(np.pi * up)
    mesh = isosurface(p, v, 0.3)
    vv, vf = vtk_contour(p, v, 0.3)
    assert abs(len(mesh.faces) / len(vf) - 1) < 0.01
    assert mesh.area() == pytest.approx(triangle_areas(vv, vf).sum(), rel=1e-3)


def test_agrees_with_skimage_on_a_regular_grid():
    measure = pytest.importorskip("skimage.measure")
    h = 0.05
    p = regular_points((40, 41, 42), spacing=(h, h, h))
    v = np.linalg.norm(p - [1.0, 1.02, 0.98], axis=-1)
    mesh = isosurface(p, v, 0.8)
    # skimage works in index space (k, j, i): spacing puts it back in place.
    sv, sf, _, _ = measure.marching_cubes(v, 0.8, spacing=(h, h, h))
    assert mesh.area() == pytest.approx(triangle_areas(sv, sf).sum(), rel=1e-3)
    assert abs(len(mesh.faces) / len(sf) - 1) < 0.01


@pytest.mark.parametrize("method", METHODS)
def test_real_grads_sample_with_poles_and_missing_values(shared_data, method):
    # The GrADS sample: pressure levels (NaN under the ground), rows at ±90°, periodic longitudes.
    from nephele.core.climate.readers import open_dataset

    ds = open_dataset(shared_data / "climate" / "model.ctl")
    grid = ds.grid
    cloud = ds.read("cloud", 1)
    assert np.isnan(cloud).any() and grid.lat[0] == -90.0 and grid.periodic_lon
    mesh = isosurface(grid.points(), cloud, 0.15, periodic_lon=True, close_poles=True, method=method,
                      attributes={"altitude": grid.height})
    assert len(mesh.faces) > 1000
    assert np.all(np.isfinite(mesh.vertices)) and np.all(np.isfinite(mesh.attributes["altitude"]))
    assert edge_counts(mesh.faces).max() == 2
    assert directed_edges_unique(mesh.faces)
    assert triangle_areas(mesh.vertices, mesh.faces).min() > 0
