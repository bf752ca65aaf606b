"""The poor-man's fractal texture: range, seam periodicity, the vector form and its parameters."""

import numpy as np
import pytest

from nephele.core.climate.grid import lonlat_to_xyz
from nephele.core.texture.fractal import Fractal, blend, terms, texture, texture_xyz


def test_range_and_contrast():
    lon, lat = np.meshgrid(np.linspace(-180, 180, 181), np.linspace(-89, 89, 90))
    t = texture(lon, lat, 3000.0)
    assert 0.0 <= t.min() and t.max() <= 1.0
    assert t.std() > 0.05  # a texture, not a constant


def test_periodic_across_the_seam():
    lat = np.linspace(-80, 80, 33)
    for alt in (0.0, 5000.0):
        np.testing.assert_allclose(texture(-180.0, lat, alt), texture(180.0, lat, alt), atol=1e-12)
        np.testing.assert_allclose(texture(-179.999, lat, alt), texture(180.001, lat, alt), atol=1e-9)


def test_vector_form_matches_and_ignores_length():
    rng = np.random.default_rng(3)
    lon, lat, alt = rng.uniform(-180, 180, 50), rng.uniform(-85, 85, 50), rng.uniform(0, 15000, 50)
    xyz = lonlat_to_xyz(lon, lat) * rng.uniform(0.5, 2.0, (50, 1))
    np.testing.assert_allclose(texture_xyz(xyz, alt), texture(lon, lat, alt), atol=1e-12)


def test_altitude_and_octaves_matter():
    lon, lat = np.meshgrid(np.linspace(-60, 60, 61), np.linspace(-40, 40, 41))
    assert np.abs(texture(lon, lat, 0.0) - texture(lon, lat, 3000.0)).max() > 0.05
    fine_lon, fine_lat = np.meshgrid(np.linspace(-10, 10, 401), np.linspace(-5, 5, 21))
    one = texture(fine_lon, fine_lat, 0.0, Fractal(octaves=1))
    many = texture(fine_lon, fine_lat, 0.0, Fractal(octaves=7))
    # more octaves add high-frequency detail: larger neighbour differences
    assert np.abs(np.diff(many, axis=1)).mean() > 2 * np.abs(np.diff(one, axis=1)).mean()


def test_terms_are_even_integers_and_amplitudes_sum_to_one():
    t = terms(Fractal())
    om = [x[0] for x in t]
    assert all(o == int(o) and int(o) % 2 == 0 for o in om)
    assert all(b > a for a, b in zip(om, om[1:]))
    assert sum(x[2] for x in t) == pytest.approx(1.0)


def test_bad_parameters_and_blend():
    for kw in ({"base": 3}, {"octaves": 0}, {"gain": 0.0}, {"alt_wavelength": -1.0}):
        with pytest.raises(ValueError):
            Fractal(**kw)
    a, b = np.array([0.2, 0.4]), np.array([0.6, 0.0])
    np.testing.assert_allclose(blend([a, b], [0.25, 0.75]), [0.5, 0.1])
