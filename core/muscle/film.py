"""The muscle film (Fig. 7): simulated cross-bridges turned into per-frame molecules and meshes.

A film is fully determined by a small JSON-able dict (:func:`film_params`):
seed, frame count, lattice spacing, Brownian time per frame.  The simulation
(:class:`.brownian.CrossBridges`) runs once per process for a given dict and
is kept in memory; every frame then places

* the actin subunits (4 fitted ellipsoids each, :func:`.molecules.actin_subunit`),
  turned so each subunit's centre faces its binding site, on the 13/6 helix
  and slid with its filament;
* the myosin heads (motor domain and lever, :func:`.molecules.myosin_head`) on
  their simulated hinge frames;
* the tails (S2, from the backbone to the hinge) and thick-filament backbones
  as cylinders;

for the unit cell and its copy shifted by the cell vector B1, so the
molecules fill the orthorhombic :attr:`.lattice.Lattice.box` and the blobby
mesh (one summed field: a bound head and its actin blend into one surface)
tiles space without cracks.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 7).
.. [2] N. Max, N. Hayashi and T. Wakabayashi, "Computer simulation and
   animation of muscle cross-bridge motion", J. Visualization and Computer
   Animation 1(1), 9-14 (1990).
"""

import json
from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..pipeline.registry import planner, task
from . import brownian as br
from . import lattice as lat
from .blobby import blobby_surface
from .molecules import (
    LEVEL,
    LEVER,
    LEVER_LENGTH,
    MOTOR,
    S2_RADIUS,
    Cylinders,
    Ellipsoids,
    actin_subunit,
    cylinder_mesh,
    myosin_head,
)

ACTIN, MOTOR_PART, LEVER_PART, TAIL, BACKBONE = 0, MOTOR, LEVER, 3, 4
"""Molecule ids written per vertex (attribute ``"molecule"``) for the materials."""

DEFAULTS = {"seed": 0, "frames": 240, "d10": lat.D10, "frame_time": 0.1, "spacing": 0.5}


def film_params(**kw):
    """Film parameters with defaults filled in and checked (a plain dict, JSON-able)."""
    unknown = set(kw) - set(DEFAULTS)
    if unknown:
        raise DataError(f"unknown film parameters {sorted(unknown)}", field="film")
    p = {**DEFAULTS, **{k: v for k, v in kw.items() if v is not None}}
    if not (int(p["frames"]) >= 1):
        raise DataError(f"must be >= 1, got {p['frames']}", field="frames")
    if not (np.isfinite(p["spacing"]) and p["spacing"] > 0):
        raise DataError(f"must be a positive grid spacing in nm, got {p['spacing']}", field="spacing")
    if not (np.isfinite(p["frame_time"]) and p["frame_time"] > 0):
        raise DataError(f"must be positive microseconds, got {p['frame_time']}", field="frame_time")
    p["seed"], p["frames"] = int(p["seed"]), int(p["frames"])
    p["d10"], p["frame_time"], p["spacing"] = float(p["d10"]), float(p["frame_time"]), float(p["spacing"])
    return p


_SIMS = {}


def simulate(params, upto=None):
    """The film's simulation, its first ``upto`` frames (default: all of them).

    Memoised per process on the parameters and extended on demand: a frame depends only on the
    steps before it, so the first ``upto`` frames are those of the whole film, and exporting or
    rendering frame 3 of 240 does not wait for the other 237.

    Returns
    -------
    lattice : Lattice
    frames : list of :class:`.brownian.Frame`
    """
    p = film_params(**params)
    n = p["frames"] if upto is None else max(0, min(int(upto), p["frames"]))
    key = json.dumps({k: p[k] for k in ("seed", "frames", "d10", "frame_time")}, sort_keys=True)
    if key not in _SIMS:
        cell = lat.unit_cell(d10=p["d10"])
        sim = br.CrossBridges(cell, br.with_params(frame_time=p["frame_time"]), seed=p["seed"])
        _SIMS.clear()  # keep one film in memory
        _SIMS[key] = (cell, sim, [])
    cell, sim, frames = _SIMS[key]
    if len(frames) < n:  # run() starts from the state it is in: the last frame already kept
        frames.extend(sim.run(n - len(frames) + 1)[1:] if frames else sim.run(n))
    return cell, frames[:n]


def _actin_model():
    """The actin subunit turned so its weighted centre lies on +x (where the binding site is)."""
    a = actin_subunit()
    c = (a.centers * a.weights[:, None]).sum(0) / a.weights.sum()
    phi = np.arctan2(c[1], c[0])
    return a.moved(lat.rot_z(-phi), np.zeros(3))


@dataclass
class Molecules:
    """One frame's molecules in the orthorhombic box (cell and its B1 copy)."""

    blobs: Ellipsoids  # actin and heads; ``part`` holds the molecule id
    cylinders: Cylinders  # tails and backbones
    box: np.ndarray  # (3,)
    states: np.ndarray  # (n_heads,) cycle state per head of the cell


def frame_molecules(lattice, frame):
    """Place every molecule of ``frame`` (a :class:`.brownian.Frame`) in the box."""
    actin = _actin_model()
    sub = lat.actin_subunits(lattice, frame.slide)
    m = len(sub.origins)
    a_rot = np.repeat(sub.rotations, len(actin), 0) @ np.tile(actin.rotations, (m, 1, 1))
    a_ctr = np.einsum("mij,kj->mki", sub.rotations,
                      actin.centers).reshape(-1, 3) + np.repeat(sub.origins, len(actin), 0)
    head = myosin_head()
    heads = lat.myosin_heads(lattice)
    h = len(heads)
    # Lever parts turn with the lever's frame about the hinge, motor parts with the motor domain's about the elbow.
    motor = head.part == MOTOR
    frames = np.where(motor[None, :, None, None], frame.motor[:, None], frame.rotations[:, None])  # (h, k, 3, 3)
    elbow = np.array([LEVER_LENGTH, 0.0, 0.0])
    origin = heads.pivots[:, None] + np.where(motor[None, :, None], LEVER_LENGTH * frame.rotations[:, None, :, 0], 0.0)
    local = head.centers - np.where(motor[:, None], elbow, 0.0)
    h_rot = (frames @ head.rotations[None]).reshape(-1, 3, 3)
    h_ctr = (np.einsum("hkij,kj->hki", frames, local) + origin).reshape(-1, 3)
    h_part = np.tile(head.part, h)  # MOTOR_PART and LEVER_PART are the models' own part ids
    ctr = np.concatenate([a_ctr, h_ctr])
    rot = np.concatenate([a_rot, h_rot])
    sig = np.concatenate([np.tile(actin.sigmas, (m, 1)), np.tile(head.sigmas, (h, 1))])
    w = np.concatenate([np.tile(actin.weights, m), np.tile(head.weights, h)])
    part = np.concatenate([np.full(len(a_ctr), ACTIN), h_part])
    shift = lattice.shift
    blobs = Ellipsoids(lattice.to_box(ctr), np.concatenate([rot, rot]),
                       np.concatenate([sig, sig]), np.concatenate([w, w]), np.concatenate([part, part]))
    # Tails: S2 from the backbone to the hinge; backbones: one cylinder through the cell per thick filament.
    mol = heads.pivots[::2]
    s2 = heads.s2_start[::2]
    thick = np.column_stack([lattice.thick_xy, np.zeros(3)])
    starts = np.concatenate([s2, thick])
    ends = np.concatenate([mol, thick + [0, 0, lattice.length]])
    radii = np.concatenate([np.full(len(mol), S2_RADIUS), np.full(3, lat.THICK_RADIUS)])
    part_c = np.concatenate([np.full(len(mol), TAIL), np.full(3, BACKBONE)])
    cs = np.concatenate([starts, starts + shift])
    ce = np.concatenate([ends, ends + shift])
    # Cylinders are not wrapped (they would be cut); those whose start falls outside the box move by whole box vectors.
    off = np.floor(cs / lattice.box) * lattice.box
    cyl = Cylinders(cs - off, ce - off, np.concatenate([radii, radii]), np.concatenate([part_c, part_c]))
    return Molecules(blobs, cyl, lattice.box.copy(), frame.states.copy())


def frame_meshes(params, index):
    """Blobby mesh (actin and heads, periodic in the box) and cylinder mesh of one film frame, nm.

    Returns
    -------
    dict of arrays
        ``vertices, faces, normals, molecule`` of the blobby surface and
        ``cyl_vertices, cyl_faces, cyl_normals, cyl_molecule`` of the cylinders, ``box``.
    """
    p = film_params(**params)
    if not 0 <= int(index) < p["frames"]:
        raise DataError(f"frame {index} outside 0..{p['frames'] - 1}", field="frame")
    cell, frames = simulate(p, upto=int(index) + 1)
    mol = frame_molecules(cell, frames[int(index)])
    b = mol.blobs
    mesh = blobby_surface(b.centers, b.rotations, b.sigmas, b.weights, LEVEL, p["spacing"], box=mol.box,
                          attributes={"molecule": b.part})
    cyl = cylinder_mesh(mol.cylinders)
    return {"vertices": mesh.vertices, "faces": mesh.faces, "normals": mesh.normals,
            "molecule": np.asarray(mesh.attributes["molecule"], np.int32),
            "cyl_vertices": cyl.vertices, "cyl_faces": cyl.faces, "cyl_normals": cyl.normals,
            "cyl_molecule": np.asarray(cyl.attributes["part"], np.int32), "box": mol.box}


@task("muscle_frame")
def _task_frame(params):
    """The ``"muscle_frame"`` task: film parameters plus ``"frame"`` (0-based)."""
    params = dict(params)
    index = params.pop("frame")
    return frame_meshes(params, index)


@planner("muscle")
def _plan(obj_params, frame):
    """A muscle-film object needs its frame's meshes (scene frame 1 is film frame 0, held at the ends)."""
    p = film_params(**obj_params.get("film", {}))
    index = int(np.clip(int(round(frame)) - int(obj_params.get("frame_start", 1)), 0, p["frames"] - 1))
    return [("muscle_frame", {**p, "frame": index})]
