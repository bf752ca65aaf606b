"""Order-independent compositing of constant-colour smoke against closed forms."""

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.flowvol import flow_volume
from nephele.core.flowvol.render import composite, ray_lengths
from nephele.core.flowvol.tets import orient, split_prisms


def cube_tets():
    """The unit cube as two prisms (six tetrahedra), min-index diagonals."""
    c = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.float64)
    prisms = np.array([[0, 1, 3, 4, 5, 7], [0, 3, 2, 4, 7, 6]])
    return c, orient(c, split_prisms(prisms))


def test_cube_gives_closed_form_on_every_ray():
    v, t = cube_tets()
    rng = np.random.default_rng(0)
    xy = rng.uniform(0.01, 0.99, (200, 2))
    origins = np.column_stack([xy, np.full(200, -1.0)])
    img = composite(v, t, origins, np.tile([0, 0, 1.0], (200, 1)), (0.8, 0.6, 0.4), 2.0)
    assert np.allclose(img, np.array([0.8, 0.6, 0.4]) * (1 - np.exp(-2.0)), atol=1e-12)
    # A slanted ray through opposite faces: L = |d| / d_z for a unit-z crossing.
    d = np.array([[0.2, 0.1, 1.0]])
    assert ray_lengths(v, t, [[0.3, 0.3, -1.0]], d)[0] == pytest.approx(np.linalg.norm(d), rel=1e-12)
    # Rays missing the cube and a ray starting inside it.
    assert ray_lengths(v, t, [[2.0, 2.0, -1.0]], [[0, 0, 1.0]])[0] == 0
    assert ray_lengths(v, t, [[0.5, 0.3, 0.25]], [[0, 0, 1.0]])[0] == pytest.approx(0.75, rel=1e-12)
    # Rays lying exactly in the inner diagonal face x = y count once, not twice.
    assert ray_lengths(v, t, [[0.5, 0.5, -1.0], [0.25, 0.25, -1.0]],
                       [[0, 0, 1.0]] * 2) == pytest.approx([1.0, 1.0], rel=1e-12)


def test_shuffled_order_gives_the_same_image():
    fv = flow_volume(lambda p, t: np.tile([0, 0, 1.0], (len(p), 1)), [0, 0, 0], 0.5, 2.0, sides=12)
    rng = np.random.default_rng(1)
    origins = np.column_stack([rng.uniform(-0.6, 0.6, (300, 2)), np.full(300, -1.0)])
    dirs = np.tile([0.05, 0.0, 1.0], (300, 1))
    a = composite(fv.vertices, fv.tets, origins, dirs, (1, 1, 1), 3.0)
    b = composite(fv.vertices, fv.tets[rng.permutation(len(fv.tets))], origins, dirs, (1, 1, 1), 3.0)
    assert np.allclose(a, b, atol=1e-12)
    assert a.max() > 0.9  # rays along the 2-unit tube are nearly opaque


def test_negative_tets_are_refused():
    v, t = cube_tets()
    with pytest.raises(DataError, match="positively"):
        ray_lengths(v, t[:, [0, 2, 1, 3]], [[0, 0, -1.0]], [[0, 0, 1.0]])
