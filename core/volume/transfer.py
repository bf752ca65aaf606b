"""Transfer functions as data: piecewise-linear opacity and colour maps.

A :class:`TransferFunction` maps a scalar (cloudiness) to an opacity
(extinction per unit length, relative to a material's extinction scale); a
:class:`ColorMap` maps a second scalar (temperature, altitude) to a colour.
Both are lists of control points, linear in between and constant beyond the
end points, JSON-serialisable, and drive both the core resampler and the
Blender material (Float Curve / Color Ramp nodes), so the picture and the
error measurements use the same definition.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization": "we set
   the opacity to zero until the cloudiness reached a threshold, leaving a
   large transparent volume which need not be processed."
.. [2] P. Williams and N. Max, "A Volume Density Optical Model", 1992
   Workshop on Volume Visualization.
"""

import json
from dataclasses import dataclass

import numpy as np

from ..errors import DataError


def _check_points(points, what, width):
    if points is None or len(points) < 1:
        raise DataError("needs at least one control point", field=what)
    try:
        values = np.array([float(p[0]) for p in points], dtype=np.float64)
        outs = np.array([np.asarray(p[1], dtype=np.float64).reshape(-1) for p in points], dtype=np.float64)
    except (TypeError, ValueError, IndexError) as exc:
        raise DataError(f"control points must be (value, output) pairs: {exc}", field=what) from None
    if outs.shape[1] != width:
        raise DataError(f"each output needs {width} component(s), got {outs.shape[1]}", field=what)
    if not (np.all(np.isfinite(values)) and np.all(np.isfinite(outs))):
        raise DataError("control points must be finite", field=what)
    if np.any(np.diff(values) < 0):
        raise DataError("control point values must be ascending", field=what)
    return values, outs


class _JsonRoundTrip:
    """``to_json``/``from_json`` on top of a class's ``to_dict``/``from_dict``."""

    _field = ""

    def to_json(self):
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text):
        try:
            return cls.from_dict(json.loads(text))
        except json.JSONDecodeError as exc:
            raise DataError(f"is not valid JSON: {exc}", field=cls._field) from None


@dataclass(frozen=True, eq=False)
class TransferFunction(_JsonRoundTrip):
    """Piecewise-linear opacity of a scalar.

    Parameters
    ----------
    points : sequence of (value, opacity)
        Control points with ascending values and opacities >= 0.  Between
        points the opacity is linear; below the first and above the last it
        stays at the end value.  Two points with the same value make a step.
    """

    _field = "transfer function"
    points: tuple

    def __post_init__(self):
        values, outs = _check_points(self.points, "transfer function", 1)
        if np.any(outs < 0):
            raise DataError("opacities must be >= 0", field="transfer function")
        object.__setattr__(self, "points", tuple((float(v), float(o)) for v, o in zip(values, outs[:, 0])))
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "opacities", outs[:, 0].copy())

    @classmethod
    def ramp(cls, threshold, full=1.0, opacity=1.0):
        """Zero up to ``threshold``, rising linearly to ``opacity`` at ``full``."""
        if not full > threshold:
            raise DataError(f"full value {full} must exceed the threshold {threshold}", field="transfer function")
        return cls(points=((threshold, 0.0), (full, opacity)))

    def __call__(self, s):
        """Opacity at scalar values ``s`` (NaN stays NaN)."""
        s = np.asarray(s, dtype=np.float64)
        v, o = self.values, self.opacities
        if v.size == 1:
            return np.where(np.isnan(s), np.nan, o[0])
        return np.where(np.isnan(s), np.nan, np.interp(s, v, o))

    @property
    def max_opacity(self):
        return float(self.opacities.max())

    def support(self):
        """``(lo, hi)``: opacity is zero for every value <= lo and >= hi.

        ``lo``/``hi`` are ``-inf``/``+inf`` where the end opacities are non-zero
        (the function stays non-zero beyond its end points).  Returns ``None``
        when the opacity is zero everywhere.
        """
        v, o = self.values, self.opacities
        nz = np.flatnonzero(o > 0)
        if nz.size == 0:
            return None
        first, last = nz[0], nz[-1]
        lo = -np.inf if first == 0 else v[first - 1]
        hi = np.inf if last == v.size - 1 else v[last + 1]
        return float(lo), float(hi)

    def antiderivative(self, s):
        """``F(s) = ∫ opacity`` from the first control point to ``s``, exact.

        Piecewise quadratic; linear beyond the end points.  Used by the
        Williams & Max integration of a linear scalar along a ray segment.
        """
        s = np.asarray(s, dtype=np.float64)
        v, o = self.values, self.opacities
        if v.size == 1:
            return o[0] * (s - v[0])
        # Cumulative integral at the control points (trapezoids are exact).
        cum = np.concatenate([[0.0], np.cumsum(np.diff(v) * 0.5 * (o[1:] + o[:-1]))])
        k = np.clip(np.searchsorted(v, s, side="right") - 1, 0, v.size - 2)
        v0, v1, o0, o1 = v[k], v[k + 1], o[k], o[k + 1]
        dv = v1 - v0
        slope = np.divide(o1 - o0, dv, out=np.zeros_like(dv), where=dv > 0)
        inside = (s >= v[0]) & (s <= v[-1])
        t = s - v0
        f_in = cum[k] + o0 * t + 0.5 * slope * t * t
        f_lo = o[0] * (s - v[0])
        f_hi = cum[-1] + o[-1] * (s - v[-1])
        return np.where(inside, f_in, np.where(s < v[0], f_lo, f_hi))

    def to_dict(self):
        return {"points": [list(p) for p in self.points]}

    @classmethod
    def from_dict(cls, d):
        if not isinstance(d, dict) or "points" not in d:
            raise DataError("needs a dict with 'points'", field="transfer function")
        return cls(points=tuple(tuple(p) for p in d["points"]))


@dataclass(frozen=True, eq=False)
class ColorMap(_JsonRoundTrip):
    """Piecewise-linear RGB colour of a scalar.

    Parameters
    ----------
    points : sequence of (value, (r, g, b))
        Ascending values; colours in linear RGB 0..1.
    """

    _field = "colour map"
    points: tuple

    def __post_init__(self):
        values, outs = _check_points(self.points, "colour map", 3)
        object.__setattr__(self, "points",
                           tuple((float(v), tuple(float(c) for c in rgb)) for v, rgb in zip(values, outs)))
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "colors", outs)

    def __call__(self, s):
        """RGB at ``s``: shape ``s.shape + (3,)``."""
        s = np.asarray(s, dtype=np.float64)
        return np.stack([np.interp(s, self.values, self.colors[:, c]) for c in range(3)], axis=-1)

    @property
    def range(self):
        return float(self.values[0]), float(self.values[-1])

    def normalized(self):
        """Control points with values mapped onto 0..1 (for a Color Ramp node)."""
        lo, hi = self.range
        span = hi - lo if hi > lo else 1.0
        return [((v - lo) / span, tuple(c)) for v, c in self.points]

    def to_dict(self):
        return {"points": [[v, list(c)] for v, c in self.points]}

    @classmethod
    def from_dict(cls, d):
        if not isinstance(d, dict) or "points" not in d:
            raise DataError("needs a dict with 'points'", field="colour map")
        return cls(points=tuple((p[0], tuple(p[1])) for p in d["points"]))


# Cloud colour (scattering albedo) by altitude in metres: warm grey low
# cloud, white in the middle, pale blue cirrus high up.
ALTITUDE_COLORS = ColorMap(points=((0.0, (0.85, 0.78, 0.7)), (5000.0, (0.97, 0.97, 0.97)),
                                   (12000.0, (0.75, 0.85, 1.0))))
# Cloud colour by temperature (K): white cold tops to warm grey-pink.
TEMPERATURE_COLORS = ColorMap(points=((210.0, (1.0, 1.0, 1.0)), (260.0, (0.85, 0.9, 1.0)), (300.0, (0.9, 0.7, 0.6))))

__all__ = ["ALTITUDE_COLORS", "TEMPERATURE_COLORS", "ColorMap", "TransferFunction"]
