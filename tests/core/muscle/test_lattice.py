"""The unit cell against an independently generated hexagonal lattice and the helix closed forms."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.muscle import lattice as lat


@pytest.fixture(scope="module")
def cell():
    return lat.unit_cell()


def _hex_points(a, lo, hi, offset=(0.0, 0.0)):
    """Hexagonal lattice (rows of spacing a, alternate rows shifted a/2) inside [lo, hi), by brute force."""
    pts = []
    h = a * np.sqrt(3) / 2
    for row in range(-10, 11):
        for col in range(-10, 11):
            x = col * a + (row % 2) * a / 2 + offset[0]
            y = row * h + offset[1]
            if lo[0] - 1e-9 <= x < hi[0] - 1e-9 and lo[1] - 1e-9 <= y < hi[1] - 1e-9:
                pts.append((x, y))
    return np.array(sorted(pts))


def _sorted(p):
    p = np.round(np.asarray(p), 6)
    return p[np.lexsort(p.T[::-1])]


def test_counts_match_the_paper(cell):
    assert cell.thick_xy.shape == (3, 2) and cell.thin_xy.shape == (6, 2)
    assert cell.length == pytest.approx(214.5)
    assert cell.subunits_per_filament == 78 and cell.crowns_per_filament == 15
    assert len(lat.myosin_heads(cell)) == 3 * 15 * 3 * 2
    assert len(lat.actin_subunits(cell).origins) == 6 * 78
    # The cell is a third of the orthorhombic box's two-copy area: 3 primitive hexagonal cells.
    a = cell.spacing
    assert np.prod(cell.domain[:2]) == pytest.approx(3 * np.sqrt(3) / 2 * a * a)


def test_box_copies_are_the_hexagonal_lattice(cell):
    a = cell.spacing
    box = cell.box
    thick = cell.to_box(np.column_stack([cell.thick_xy, np.zeros(3)]))[:, :2]
    want = _hex_points(a, (0, 0), box[:2])
    assert len(want) == 6
    np.testing.assert_allclose(_sorted(thick), _sorted(want), atol=1e-6)
    thin = cell.to_box(np.column_stack([cell.thin_xy, np.zeros(6)]))[:, :2]
    tri = _hex_points(a, (0, 0), box[:2], offset=(a / 2, a / (2 * np.sqrt(3))))
    tri2 = _hex_points(a, (0, 0), box[:2], offset=(a, a / np.sqrt(3)))
    # Trigonal points from both sublattices, wrapped into the box.
    both = np.concatenate([tri, tri2,
                           _wrap2(_hex_points(a, (-a, -a), box[:2] + a, offset=(a / 2, a / (2 * np.sqrt(3)))), box),
                           _wrap2(_hex_points(a, (-a, -a), box[:2] + a, offset=(a, a / np.sqrt(3))), box)])
    both = np.unique(np.round(both, 6), axis=0)
    assert len(both) == 12
    np.testing.assert_allclose(_sorted(thin), _sorted(both), atol=1e-6)


def _wrap2(p, box):
    return np.mod(p, box[:2])


def test_every_thick_ringed_by_six_thin_and_thin_by_three_thick(cell):
    a = cell.spacing
    thick = np.column_stack([cell.thick_xy, np.zeros(3)])
    thin = np.column_stack([cell.thin_xy, np.zeros(6)])
    d = np.linalg.norm(cell.min_image(thick[:, None] - thin[None]), axis=2)
    # Nearest images only: each thin has 3 thick neighbours at a / sqrt(3) but a thick may see one thin twice.
    # Count neighbours over a ring of explicit images instead.
    imgs = _images(cell, 2)
    dd = np.linalg.norm(thick[:, None, None, :2] - (thin[None, :, None, :2] + imgs[None, None]), axis=3)
    near = np.isclose(dd, a / np.sqrt(3), atol=1e-6)
    assert np.all(near.sum(axis=(1, 2)) == 6)
    assert np.all(near.sum(axis=(0, 2)) == 3)
    assert d.min() == pytest.approx(a / np.sqrt(3))
    tt = np.linalg.norm(thick[:, None, None, :2] - (thick[None, :, None, :2] + imgs[None, None]), axis=3)
    assert np.all(np.isclose(tt, a, atol=1e-6).sum(axis=(1, 2)) == 6)


def _images(cell, n):
    b1, b2 = cell.shift[:2], np.array([0.0, cell.box[1]])
    return np.array([i * b1 + j * b2 for i in range(-n, n + 1) for j in range(-n, n + 1)])


def test_wrap_identifies_periodic_images(cell):
    rng = np.random.default_rng(1)
    p = rng.uniform(-300, 300, (500, 3))
    w = cell.wrap(p)
    assert np.all(w >= 0) and np.all(w < cell.domain)
    b2 = np.array([0.0, cell.box[1], 0.0])
    bz = np.array([0.0, 0.0, cell.length])
    for shift in (cell.shift, -cell.shift, b2, bz, 2 * cell.shift - 3 * b2 + bz, np.array([cell.box[0], 0, 0])):
        np.testing.assert_allclose(cell.wrap(p + shift), w, atol=1e-9)
    np.testing.assert_allclose(cell.wrap(w), w, atol=0)
    # Exactly on the domain's upper faces: wraps to the lower faces.
    edge = cell.wrap(np.array([cell.domain[0], 0.0, cell.length]))
    assert np.all(edge >= 0) and np.all(edge < cell.domain)


def test_min_image_is_the_shortest_image(cell):
    rng = np.random.default_rng(2)
    d = rng.uniform(-200, 200, (300, 3))
    got = np.linalg.norm(cell.min_image(d), axis=1)
    imgs = _images(cell, 4)
    best = np.full(len(d), np.inf)
    for k in (-2, -1, 0, 1, 2):
        for im in imgs:
            s = np.array([im[0], im[1], k * cell.length])
            best = np.minimum(best, np.linalg.norm(d + s, axis=1))
    np.testing.assert_allclose(got, best, rtol=1e-12)


def test_actin_helix_closes_after_one_cell(cell):
    assert 78 * lat.ACTIN_TWIST == pytest.approx(-36 * 2 * np.pi)
    assert 13 * lat.ACTIN_RISE == pytest.approx(35.75)
    assert 15 * lat.CROWN_TWIST % (2 * np.pi / 3) == pytest.approx(0, abs=1e-12)
    s = lat.actin_subunits(cell)
    # Consecutive subunits: rise 2.75 (mod L) and a -166.15 degree turn.
    r0, r1 = s.rotations[0], s.rotations[1]
    rel = r1 @ r0.T
    assert np.degrees(np.arctan2(rel[1, 0], rel[0, 0])) == pytest.approx(-360 * 6 / 13)
    dz = np.diff(s.origins[:78, 2])
    assert np.allclose(np.mod(dz, cell.length), 2.75)
    # Sliding by a whole cell length is the identity; by a rise, the helix maps onto itself shifted by one.
    slid = lat.actin_subunits(cell, slide=np.full(6, cell.length))
    np.testing.assert_allclose(slid.origins, s.origins, atol=1e-9)


def test_heads_on_crowns(cell):
    h = lat.myosin_heads(cell)
    axis = np.column_stack([cell.thick_xy[h.thick], h.pivots[:, 2]])
    assert np.allclose(np.linalg.norm(h.pivots - axis, axis=1), lat.PIVOT_RADIUS)
    assert np.allclose(np.linalg.norm(h.rest, axis=1), 1)
    z = h.pivots[h.thick == 0, 2]
    assert np.allclose(np.unique(np.round(z, 6)), np.arange(15) * 14.3)
    # The two heads of one molecule share their pivot; three molecules per crown, 120 degrees apart.
    mol = h.molecule
    assert np.all(np.bincount(mol) == 2)
    pair = h.pivots.reshape(-1, 2, 3)
    np.testing.assert_allclose(pair[:, 0], pair[:, 1])
    crown0 = h.radial[(h.thick == 0) & (h.crown == 0)][::2]
    cosines = crown0 @ crown0.T
    assert np.allclose(cosines[np.triu_indices(3, 1)], -0.5)
    # 40 degrees between successive crowns.
    c1 = h.radial[(h.thick == 0) & (h.crown == 1)][0]
    assert np.degrees(np.arccos(crown0[0] @ c1)) == pytest.approx(40)


@pytest.mark.parametrize("kw", [{"length": 200.0}, {"length": 0.0}, {"length": np.nan}, {"d10": 10.0}, {"d10": np.nan}])
def test_bad_cells_rejected(kw):
    with pytest.raises(DataError):
        lat.unit_cell(**kw)


def test_two_cells_long():
    c = lat.unit_cell(length=2 * lat.CELL_LENGTH)
    assert c.subunits_per_filament == 156 and c.crowns_per_filament == 30
