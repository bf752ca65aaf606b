"""Perlin's improved noise against the reference implementation's known values."""

import numpy as np
import pytest

from nephele.core.texture.noise import improved_noise, turbulence


def test_reference_value():
    # Perlin's Java reference code gives noise(3.14, 42, 7) = 0.13691995878400012
    assert improved_noise(3.14, 42.0, 7.0) == pytest.approx(0.13691995878400012, abs=1e-15)


def test_zero_on_lattice_and_periodic():
    i = np.arange(-5, 6, dtype=float)
    x, y, z = np.meshgrid(i, i + 3, i - 7, indexing="ij")
    assert np.all(improved_noise(x, y, z) == 0.0)
    p = np.random.default_rng(1).uniform(0, 50, (3, 200))
    np.testing.assert_allclose(improved_noise(*p), improved_noise(p[0] + 256, p[1], p[2] - 256), atol=1e-12)


def test_range_and_smoothness():
    p = np.random.default_rng(2).uniform(-100, 100, (3, 20000))
    n = improved_noise(*p)
    assert np.abs(n).max() <= 1.05 and n.std() > 0.1
    # continuous: a tiny step changes the value by at most gradient * step
    d = improved_noise(p[0] + 1e-6, p[1], p[2]) - n
    assert np.abs(d).max() < 1e-5


def test_broadcast_and_bad_input():
    a = improved_noise(np.linspace(0, 3, 7)[:, None], np.linspace(0, 2, 5)[None, :], 0.5)
    assert a.shape == (7, 5)
    with pytest.raises(ValueError):
        improved_noise(np.nan, 0, 0)
    with pytest.raises(ValueError):
        turbulence(0, 0, 0, octaves=0)


def test_turbulence_octaves_add_detail():
    x = np.linspace(0, 4, 401)
    one = turbulence(x, 0.3, 0.7, octaves=1)
    four = turbulence(x, 0.3, 0.7, octaves=4)
    np.testing.assert_allclose(one, improved_noise(x, 0.3, 0.7))
    assert np.abs(np.diff(four, 2)).mean() > 2 * np.abs(np.diff(one, 2)).mean()
