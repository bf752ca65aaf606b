"""Clouds that change during the film (Fig. 6 in motion): evolving densities and their sequence of
scattering solves, each frame warm-started from the one before (:mod:`._warm`).

Two clouds: the paper's (:func:`..volume.cloud_density.cloud_density`) with its Perlin noise
drifting through the ellipsoids (:func:`drifting_cloud`), and a cloud cut from the demo climate's
hourly cloud field (:func:`climate_cloud`: 240 frames are its 10 days).  :func:`solve_frames` solves
either frame by frame; the first frame (and any frame of another grid) starts cold.
"""

from dataclasses import replace

import numpy as np

from ..errors import DataError
from ..volume import cloud_density as cd
from ._solve import solve

DRIFT = (0.25, 0.1, 0.02)  # box units the drifting cloud's noise moves over the whole film


def drifting_cloud(params, frame, frames, drift=DRIFT, extinction=40.0):
    """Extinction of frame ``frame`` of ``frames``: ``params``'s cloud (a
    :class:`..volume.cloud_density.CloudParams`) with its noise shifted by ``frame / frames``
    of ``drift`` (x, y, z box units): the texture moves through the cloud, the cloud stays."""
    if frames < 1 or not 0 <= frame < frames:
        raise DataError(f"frame {frame} is not one of {frames} frames", field="frame")
    f = frame / frames
    off = tuple(float(o) + f * float(d) for o, d in zip(params.noise_offset, drift))
    return float(extinction) * cd.cloud_density(replace(params, noise_offset=off))


CLIMATE_WINDOW = (150, 100, 48, 40)  # the demo's (column, row, columns, rows): the northern storm track


def climate_cloud(dataset, step, shape=(48, 64, 64), window=CLIMATE_WINDOW, extinction=40.0):
    """Extinction from the cloud fraction of ``dataset`` (e.g. :func:`..climate.synthetic.demo_dataset`)
    at time step ``step``, cut to ``window`` = (first column, first row, columns, rows) of its grid,
    all its levels, columns and rows resampled linearly to ``shape`` (layers, rows, columns), zero on
    the box's faces so the cloud ends inside the box."""
    c = np.asarray(dataset.read("cloud", step), np.float64)  # (levels, rows, columns)
    i0, j0, ni, nj = (int(v) for v in window)
    if c.ndim != 3 or j0 < 0 or i0 < 0 or j0 + nj > c.shape[1] or i0 + ni > c.shape[2]:
        raise DataError(f"window {window} is not inside the cloud field's {c.shape[2]}x{c.shape[1]} grid",
                        field="window")
    c = c[:, j0:j0 + nj, i0:i0 + ni]
    for ax, n in enumerate(int(n) for n in shape):  # linear along each axis, ends on the ends
        x = np.linspace(0.0, c.shape[ax] - 1.0, n)
        k = np.minimum(np.floor(x).astype(int), c.shape[ax] - 2)
        w = (x - k).reshape((-1,) + (1,) * (2 - ax))
        c = (1 - w) * np.take(c, k, axis=ax) + w * np.take(c, k + 1, axis=ax)
    out = np.clip(c, 0.0, 1.0)
    out[:, :, [0, -1]] = 0.0
    out[:, [0, -1], :] = 0.0
    out[[0, -1]] = 0.0
    return (float(extinction) * out).astype(np.float32)


def solve_frames(densities, size, warm=True, progress=None, **kw):
    """Solve each extinction grid of ``densities`` (an iterable) in turn, each frame started from
    the previous frame's solution when ``warm`` (:func:`._solve.solve` ``warm=``); yields
    ``(frame index, Solution)``.  ``progress(frame, Progress)`` after each step; ``kw`` go to every
    solve."""
    prev = None
    for i, sigma in enumerate(densities):
        step = None if progress is None else (lambda p, i=i: progress(i, p))
        sol = solve(sigma, size, step, warm=prev if warm else None, **kw)
        yield i, sol
        prev = sol


__all__ = ["CLIMATE_WINDOW", "DRIFT", "climate_cloud", "drifting_cloud", "solve_frames"]
