import json

import numpy as np
import pytest

from nephele.core.errors import DataError
from nephele.core.volume.transfer import ALTITUDE_COLORS, ColorMap, TransferFunction


def test_piecewise_linear_values_clamped_and_nan():
    tf = TransferFunction(points=((0.2, 0.0), (0.5, 1.0), (1.0, 0.5)))
    s = np.array([-1.0, 0.2, 0.35, 0.5, 0.75, 1.0, 3.0, np.nan])
    np.testing.assert_allclose(tf(s)[:-1], [0.0, 0.0, 0.5, 1.0, 0.75, 0.5, 0.5])
    assert np.isnan(tf(s)[-1])
    assert tf.max_opacity == 1.0


def test_support_is_where_opacity_can_be_nonzero():
    assert TransferFunction.ramp(0.3, 1.0).support() == (0.3, np.inf)
    band = TransferFunction(points=((0.0, 0.0), (0.2, 0.0), (0.4, 1.0), (0.6, 0.0)))
    assert band.support() == (0.2, 0.6)
    assert TransferFunction(points=((0.0, 0.0), (1.0, 0.0))).support() is None
    assert TransferFunction(points=((0.0, 0.5), (1.0, 1.0))).support() == (-np.inf, np.inf)


def test_antiderivative_matches_dense_quadrature():
    tf = TransferFunction(points=((0.1, 0.0), (0.3, 2.0), (0.3, 0.5), (0.8, 1.5)))  # with a step at 0.3
    s = np.linspace(-0.5, 1.5, 200001)
    y = tf(s)
    # Right-continuous step: the quadrature below is exact except in the one
    # interval that holds the step.
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(s))])
    F = tf.antiderivative(s) - tf.antiderivative(s[0])
    np.testing.assert_allclose(F, cum, atol=2e-5)
    # Closed form beyond the end: linear with the end opacity.
    assert tf.antiderivative(2.0) - tf.antiderivative(1.0) == pytest.approx(1.5)


def test_json_roundtrip_and_normalized_colormap():
    tf = TransferFunction.ramp(0.25, 0.9, 0.7)
    tf2 = TransferFunction.from_json(json.dumps(tf.to_dict()))
    assert tf2.points == tf.points
    cm = ColorMap.from_json(ALTITUDE_COLORS.to_json())
    assert cm.points == ALTITUDE_COLORS.points
    norm = cm.normalized()
    assert norm[0][0] == 0.0 and norm[-1][0] == 1.0
    np.testing.assert_allclose(cm(np.array([0.0, 12000.0, 1e6])), [cm.colors[0], cm.colors[-1], cm.colors[-1]])
    np.testing.assert_allclose(cm(0.5 * (cm.values[0] + cm.values[1])), 0.5 * (cm.colors[0] + cm.colors[1]))


@pytest.mark.parametrize(
    "points",
    [(), ((1.0, 0.0), (0.5, 1.0)), ((0.0, -1.0),), ((0.0, np.nan),), (("a", 1.0),)],
)
def test_bad_transfer_functions_raise_data_error(points):
    with pytest.raises(DataError):
        TransferFunction(points=points)


def test_bad_ramp_and_colormap():
    with pytest.raises(DataError, match="must exceed"):
        TransferFunction.ramp(0.5, 0.5)
    with pytest.raises(DataError, match="3 component"):
        ColorMap(points=((0.0, (1.0, 1.0)),))
    with pytest.raises(DataError, match="JSON"):
        TransferFunction.from_json("{not json")
