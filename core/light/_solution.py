"""What a scattering solve returns (:class:`Solution`, :class:`Progress`), a slab's R and T,
and solutions as plain arrays and files (.npz with JSON metadata, no pickle)."""

import json
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import DataError
from ..files import atomic_write
from . import phase


@dataclass
class Progress:
    """What :func:`solve_steps` yields: ``pass_index`` (0 = sun and sky), bins
    done in this pass, and ``residual`` = unshot / power that entered the cloud (in the
    last step after an extrapolated tail: that extrapolation's error bound, :class:`_Tail`)."""

    pass_index: int
    group: int
    groups: int
    residual: float


@dataclass
class Solution:
    """Result of :func:`solve` (float32 arrays).

    ``sigma`` covers the whole grid (nz, ny, nx); the flux arrays ``(…, mz, my, mx)`` only
    the box of non-empty voxels that was solved, ``sigma[sol.box]`` (``origin``: the box's
    first voxel, z y x), since no light is caught outside it (at 128x128x96 the full-grid
    copies were 3 GB and 4.6 s).  :meth:`grid` puts one on the whole grid.

    Attributes
    ----------
    sigma : extinction per unit length.
    size : box size (Lx, Ly, Lz).
    received : (nb, …) power intercepted per bin from scattered light and sky; ``nb = 6 n^2``
        bins, ``n`` = :attr:`bins_per_face` (derived from this array's length).
    total : (nb, …) power passing through each voxel per bin (the paper's 'total' flux), or None
        (summed only on request: ``solve(total=True)``).
    received_sun : power intercepted from the direct sun beam.
    received_peaked : (2, nb, …) the parts of ``received`` scattered once and twice (sun light).
    peaked_weights : (2, nb, s*s) how those are distributed over the sub-directions of each bin.
    unshot : (nb, …) scattered power left unpropagated when the solve stopped (zero when
        the passes' tail was extrapolated).
    exit_flux : (nb,) power leaving the solved box (the grid, less empty margins on
        non-periodic axes) through the far face of each bin's sweep.
    sun_exit : direct sun power leaving through the far face of the sun sweep (same box).
    injected : power that entered the cloud (first interception of sun and sky).
    passes, residual, converged, history : the convergence report (``history``: the unshot
        residual after each pass; ``residual``: the last one, or the extrapolation's error).
    warm : whether the solve started from a previous frame's solution (:mod:`._warm`).
    moments_binned : where inside their voxels the scattering of the binned light (after the
        peaked orders, and the sky) sits: its first (and second) moments per sweep group of bins,
        (sets, 1 or 2, 3, …) float32, or None (no source profiles); a warm start's profiles.
    albedo_binned, g_binned, delta_f : albedo, asymmetry and delta-M fraction of the
        scaled medium the binned flux was transported in; ``received`` is in that medium,
        except the first ``real_orders`` of ``received_peaked``, caught in the real medium.
    """

    sigma: np.ndarray
    size: tuple
    albedo: float
    g: float
    sun_dir: tuple
    sun_irradiance: float
    sky_radiance: object  # float (uniform, downward) or read-only (nb,) float64 per bin
    received: np.ndarray
    total: object  # float32 (nb, …) or None
    received_sun: np.ndarray
    received_peaked: np.ndarray
    peaked_weights: np.ndarray
    unshot: np.ndarray
    exit_flux: np.ndarray
    sun_exit: float
    injected: float
    passes: int
    residual: float
    converged: bool
    history: list = field(default_factory=list)
    sub: int = 2
    periodic: tuple = (False, False, False)
    albedo_binned: float = 0.0
    g_binned: float = 0.0
    delta_f: float = 0.0
    real_orders: int = 0
    origin: tuple = (0, 0, 0)
    warm: bool = False
    moments_binned: object = None  # float32 (sets, order, 3, …) or None

    @property
    def bins_per_face(self):
        """The bin layout (:func:`.phase.bins`): ``n`` of the ``6 n^2`` bins of ``received``."""
        return phase.per_face_of(len(self.received))

    @property
    def box(self):
        """Slices (z, y, x) of ``sigma`` that the flux arrays cover."""
        return tuple(slice(int(o), int(o) + n) for o, n in zip(self.origin, self.received_sun.shape))

    def grid(self, name):
        """The flux array ``name`` (e.g. ``"received"``) on the whole grid, zero outside the box."""
        a = getattr(self, name)
        out = np.zeros(a.shape[:a.ndim - 3] + self.sigma.shape, a.dtype)
        out[(Ellipsis,) + self.box] = a
        return out

    @property
    def report(self):
        """One line: passes, residual, converged or stopped at the pass limit."""
        state = "converged" if self.converged else "stopped at the pass limit (not converged)"
        start = ", from the previous frame" if self.warm else ""
        return f"{self.passes} passes{start}, residual {self.residual:.3g} of the entered power: {state}"


def _check_sky(sky_radiance, nb):
    """The sky as a float (uniform, travelling downward) or a read-only (nb,) float64 array."""
    if np.ndim(sky_radiance) == 0:
        if not (np.isfinite(sky_radiance) and sky_radiance >= 0):
            raise DataError(f"sky radiance must be finite and >= 0, got {sky_radiance}", field="sky_radiance")
        return float(sky_radiance)
    sky = np.array(sky_radiance, dtype=np.float64)
    if sky.shape != (nb,):
        raise DataError(f"sky radiance must be a number or {nb} per-bin values (the solve's bins), "
                        f"got shape {sky.shape}", field="sky_radiance")
    if not np.all(np.isfinite(sky)) or np.any(sky < 0):
        raise DataError("per-bin sky radiance must be finite and >= 0", field="sky_radiance")
    sky.setflags(write=False)
    return sky



def slab_reflectance(sol):
    """(R, T) of a periodic slab lit from +z (sun overhead): diffuse power leaving the
    top, and diffuse plus unscattered power leaving the bottom, per incident power.

    Only meaningful for grids periodic in x and y (nothing leaves sideways).
    """
    cen = phase.bins(1, sol.bins_per_face)[0]
    s = np.asarray(sol.sun_dir)
    nz, ny, nx = sol.sigma.shape
    incident = sol.sun_irradiance * abs(s[2]) * sol.size[0] * sol.size[1]
    up = cen[:, 2] > 0
    r = sol.exit_flux[up].sum() / incident
    t = (sol.exit_flux[~up].sum() + sol.sun_exit) / incident
    return float(r), float(t)


_ARRAYS = ("sigma", "received", "received_sun", "received_peaked", "peaked_weights", "unshot", "exit_flux")
_OPTIONAL = ("total", "moments_binned")  # saved where not None; files without them load with None


def json_plain(value):
    """JSON form of NumPy values: arrays as lists (the per-bin sky), scalars as floats."""
    return value.tolist() if isinstance(value, np.ndarray) else float(value)


def solution_arrays(sol):
    """A :class:`Solution` as a dict of plain arrays (metadata as a JSON string array)."""
    meta = {k: getattr(sol, k) for k in sol.__dataclass_fields__ if k not in _ARRAYS + _OPTIONAL}
    meta = json.loads(json.dumps(meta, default=json_plain))
    extra = {k: getattr(sol, k) for k in _OPTIONAL if getattr(sol, k) is not None}
    return {"meta": np.array(json.dumps(meta)), **{k: getattr(sol, k) for k in _ARRAYS}, **extra}


def solution_from_arrays(arrays):
    """Inverse of :func:`solution_arrays`."""
    meta = json.loads(str(arrays["meta"]))
    for k in ("size", "sun_dir", "periodic", "origin"):
        if k in meta:
            meta[k] = tuple(meta[k])
    meta["sky_radiance"] = _check_sky(meta.get("sky_radiance", 0.0), len(arrays["received"]))
    extra = {k: np.asarray(arrays[k]) if k in arrays else None for k in _OPTIONAL}
    return Solution(**{k: np.asarray(arrays[k]) for k in _ARRAYS}, **extra, **meta)


def save_solution(sol, path):
    """Write a :class:`Solution` to ``path`` (.npz: plain arrays + JSON metadata, no pickle), atomically."""
    path = os.fspath(path)
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **solution_arrays(sol))
    return path


def load_solution(path):
    """Read a :class:`Solution` written by :func:`save_solution`."""
    try:
        z = np.load(path, allow_pickle=False)
        return solution_from_arrays({k: z[k] for k in ("meta",) + _ARRAYS + _OPTIONAL if k in z.files
                                     or k not in _OPTIONAL})
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise DataError(f"not a scattering solution file ({exc})", path=path) from exc
