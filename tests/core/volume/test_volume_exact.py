"""Williams & Max exact segment integration and the reference ray caster."""

import numpy as np
import pytest

from nephele.core.climate.grid import GlobeGrid, globe_radius
from nephele.core.errors import DataError
from nephele.core.volume.exact_ray import opacity, reference_optical_depth, segment_optical_depth, sphere_span
from nephele.core.volume.sparse import CurvilinearField
from nephele.core.volume.transfer import TransferFunction


def test_segment_crossing_threshold_closed_form():
    # s from 0 to 1 over length 2; opacity 0 below 0.5 rising to 1 at 1:
    # tau(t) = max(0, t - 1) on [0, 2] -> integral 0.5.
    tf = TransferFunction.ramp(0.5, 1.0)
    assert segment_optical_depth(tf, 0.0, 1.0, 2.0) == pytest.approx(0.5, abs=1e-15)
    assert segment_optical_depth(tf, 1.0, 0.0, 2.0) == pytest.approx(0.5, abs=1e-15)
    # Constant scalar: opacity times length.
    assert segment_optical_depth(tf, 0.75, 0.75, 4.0) == pytest.approx(2.0)
    # Nearly constant, no cancellation trouble.
    assert segment_optical_depth(tf, 0.75, 0.75 + 1e-13, 4.0) == pytest.approx(2.0, rel=1e-9)
    # Missing data contributes nothing.
    assert segment_optical_depth(tf, np.nan, 0.9, 1.0) == 0.0


def test_segments_match_fine_quadrature_through_many_breakpoints():
    rng = np.random.default_rng(0)
    tf = TransferFunction(points=((0.1, 0.0), (0.3, 2.0), (0.45, 0.2), (0.7, 0.2), (0.9, 3.0)))
    s0, s1 = rng.uniform(-0.2, 1.2, (2, 300))
    L = rng.uniform(0.0, 2.0, 300)
    exact = segment_optical_depth(tf, s0, s1, L)
    t = np.linspace(0.0, 1.0, 20001)
    y = tf(s0[:, None] + (s1 - s0)[:, None] * t[None])
    quad = L * (0.5 * (y[:, 1:] + y[:, :-1]) * np.diff(t)).sum(axis=1)
    np.testing.assert_allclose(exact, quad, atol=5e-8 * 3)


def test_bad_segment_input():
    with pytest.raises(DataError):
        segment_optical_depth(TransferFunction.ramp(0, 1), 0.0, 1.0, -1.0)
    with pytest.raises(DataError):
        segment_optical_depth([(0, 0)], 0.0, 1.0, 1.0)


def test_sphere_span_stops_at_the_ground():
    o = np.array([[3.0, 0, 0], [3.0, 0, 0], [3.0, 5.0, 0]])
    d = np.array([[-1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0]])
    t0, t1 = sphere_span(o, d, 2.0, 1.0)
    np.testing.assert_allclose(t0[:2], [1.0, 0.0])
    np.testing.assert_allclose(t1[:2], [2.0, 0.0])
    assert t0[2] == t1[2]  # a miss: empty span


def shell_grid(ni=36, nj=18, nk=5, top=10000.0):
    lon = np.arange(ni) * 360.0 / ni
    lat = -90 + (np.arange(nj) + 0.5) * 180.0 / nj
    h = np.linspace(0.0, top, nk)[:, None, None] + np.zeros((nk, nj, ni))
    return GlobeGrid(lon, lat, h)


def test_reference_caster_gives_chord_lengths_of_a_uniform_shell():
    g = shell_grid()
    field = CurvilinearField.from_grid(g, {"v": np.ones(g.shape)})
    tf = TransferFunction(points=((0.0, 1.0),))
    r0, r1 = 1.0, float(globe_radius(10000.0))
    # A radial ray down to the ground through a pole (the closed cap) and
    # the seam; a tangent-ish ray that misses the ground.
    o = np.array([[0.0, 0.0, 3.0], [3.0, 0.0, 0.0], [-3.0, 1.001, 0.2]])
    d = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    tau, t0, t1 = reference_optical_depth(field, "v", tf, o, d, step=1e-4)
    b = np.hypot(1.001, 0.2)
    chord = 2 * np.sqrt(r1**2 - b**2)
    np.testing.assert_allclose(tau, [r1 - r0, r1 - r0, chord], rtol=2e-3)
    assert opacity(tau, 0.0).max() == 0.0
