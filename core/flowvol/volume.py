"""Flow volumes: the air that flowed through a generator polygon, as tetrahedra (Fig. 5).

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
.. [2] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 5:
   simulated smoke in global air circulation).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..memory import check_memory
from ..surface.mesh import Mesh, vertex_normals
from .climate import ClimateVelocity
from .front import Front, perpendicular_frame
from .tets import boundary_faces, merge_vertices, orient, signed_volumes, split_prisms
from .unstructured import UnstructuredVelocity


@dataclass
class FlowVolume:
    """Tetrahedra of the air released through a generator.

    Parameters
    ----------
    vertices : (n, 3) float64 array
    tets : (m, 4) int64 array
        Positively oriented (signed volume >= 0).
    surface : Mesh
        The closed boundary of the tetrahedra, facing out.
    release : (n,) array
        Time each vertex's air passed the generator.
    age : (n,) array
        ``t_end - release``.
    generator : (g, 3) array
        The generator's points (centre first), in the plane of ``normal``.
    normal : (3,) array
    complete : bool
        False when refinement stopped at ``max_points`` before reaching ``tol``.
    exited : (n,) bool array
        Vertices whose air left the velocity's domain (a wall or an outlet of
        an unstructured grid) before ``t_end``: they rest at their exit point
        and no tetrahedron uses them, so the smoke ends there.
    """

    vertices: np.ndarray
    tets: np.ndarray
    surface: Mesh
    release: np.ndarray
    age: np.ndarray
    generator: np.ndarray
    normal: np.ndarray
    complete: bool = True
    exited: np.ndarray = None

    @property
    def volume(self):
        """Total volume of the tetrahedra."""
        return float(signed_volumes(self.vertices, self.tets).sum()) if len(self.tets) else 0.0


def _as_velocity(velocity):
    if callable(velocity):
        return velocity
    if isinstance(velocity, (str, Path)) and str(velocity).endswith(".vtu"):
        return UnstructuredVelocity(velocity)
    if hasattr(velocity, "grid") and hasattr(velocity, "hours"):
        return ClimateVelocity(velocity)
    raise DataError("velocity must be a callable velocity(points, t) or a climate dataset, got "
                    f"{type(velocity).__name__}", field="velocity")


def flow_volume(velocity, center, radius, duration, *, normal=None, sides=32, rings=2, t0=0.0, tol=None, merge=0.5,
                steps=16, max_points=200_000, steady=None):
    """The air released through a generator polygon during ``duration``, carried to ``t0 + duration``.

    Parameters
    ----------
    velocity : callable or Dataset
        ``velocity(points (n, 3), t (n,)) -> (n, 3)``, or a climate dataset with
        ``u``/``v`` winds (scene units on a unit globe, hours; see
        :class:`~nephele.core.flowvol.climate.ClimateVelocity` for the
        exaggeration), a :class:`ClimateVelocity`, or the path of a ``.vtu``
        unstructured grid with point vectors ``uvw`` (:class:`UnstructuredVelocity`).
    center : (3,) array
    radius : float
        Circumradius of the regular ``sides``-gon generator.
    duration : float
        Release window (time units of ``velocity``).  0 gives no tetrahedra.
    normal : (3,) array, optional
        Generator normal; default: the flow direction at ``center`` at ``t0``.
    rings : int
        Concentric copies of the polygon triangulating its interior.
    tol : float, optional
        Largest distance between neighbouring front points (default: the
        generator's edge length).
    merge : float
        Where the front converges, neighbours closer than ``merge * tol`` are
        merged (0: keep every point); every point is still integrated, but the
        tetrahedra and the surface use only the kept ones.
    steps : int
        RK4 steps along each trajectory.
    max_points : int
        Refinement stops (``complete=False``) beyond this many front points.
    steady : bool, optional
        The velocity does not depend on time (default: its ``steady``
        attribute, e.g. :class:`UnstructuredVelocity`): each generator point's
        streamline is integrated once (``steps`` RK4 steps over ``duration``)
        and every layer is read from them (Hultquist's stream tube) instead of
        integrating each layer on its own; with a ``cell_size`` (a grid's
        typical cell) the streamline takes at least two steps per cell
        crossed at the centre's speed.

    Returns
    -------
    FlowVolume

    References
    ----------
    .. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive
       vector field visualization", Proc. Visualization '93, 19-24.
    """
    center = np.asarray(center, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(center)):
        raise DataError(f"generator centre {center.tolist()} is not finite", field="center")
    if not (np.isfinite(radius) and radius > 0):
        raise DataError(f"generator radius must be positive, got {radius}", field="radius")
    if not (np.isfinite(duration) and duration >= 0):
        raise DataError(f"duration must be >= 0, got {duration}", field="duration")
    if int(sides) < 3 or int(rings) < 1 or int(steps) < 1:
        raise DataError(f"need sides >= 3, rings >= 1, steps >= 1 (got {sides}, {rings}, {steps})", field="sides")
    sides, rings, steps = int(sides), int(rings), int(steps)
    if not 0 <= merge < 1:
        raise DataError(f"merge must be in [0, 1), got {merge}", field="merge")
    velocity = _as_velocity(velocity)
    v = np.asarray(velocity(center[None], np.array([float(t0)])), dtype=np.float64).reshape(3)
    if normal is None:
        if not np.all(np.isfinite(v)):
            raise DataError(f"the velocity at the generator centre {center.tolist()} is missing (NaN)",
                            field="velocity")
        if not np.linalg.norm(v) > 0:
            raise DataError(f"calm air at the generator centre {center.tolist()}: no flow direction to face; give a "
                            "normal", field="normal")
        normal = v
    normal = np.asarray(normal, dtype=np.float64).reshape(3)
    if not np.linalg.norm(normal) > 0:
        raise DataError("the generator normal is zero", field="normal")
    e1, e2, n = perpendicular_frame(normal)
    tol = 2 * radius * np.sin(np.pi / sides) if tol is None else float(tol)
    if not tol > 0:
        raise DataError(f"tol must be positive, got {tol}", field="tol")
    # Layers spaced about tol apart at the centre's speed: fewer refinement rounds (each re-reads the winds).
    G = 1 + sides * rings
    speed = float(np.linalg.norm(v)) if np.all(np.isfinite(v)) else 0.0
    # The front's points with their trajectories, tets and merge tables: ~1.8 kB per point at the peak
    # (tracemalloc: 489 MB for 268,308 vertices of an ABC-flow volume with max_points 200,000).
    check_memory(2500 * int(max_points), f"a flow volume of up to {int(max_points):,} points",
                 hint="lower max_points (coarser) or the duration", field="max_points")
    layers = int(min(np.ceil(speed * float(duration) / tol), max_points // G)) + 1
    # A velocity with a bounded domain (NaN outside, e.g. a room's grid): air that leaves it stops there.
    stop = bool(getattr(velocity, "bounded", False))
    steady = bool(getattr(velocity, "steady", False)) if steady is None else bool(steady)
    if steady and getattr(velocity, "cell_size", None):
        # A streamline serves every age: its steps are kept to half a cell of the grid at the centre's speed
        # (a layer's own integration took ``steps`` steps of age / steps each; a cell per step left the fire's
        # 1 s tube 2.7% too large, half a cell 0.1%).
        steps = max(steps, int(np.ceil(2.0 * float(duration) * speed / velocity.cell_size)))
    front = Front(velocity, center, e1, e2, float(radius), sides, rings, float(t0), float(duration), steps, layers,
                  stop, steady, tol / 4)
    complete = True if duration == 0 else front.refine(tol, max_points)
    front.settle()
    if stop and hasattr(velocity, "bounds"):
        # Exit points lie on the grid's boundary up to the cell search's tolerance: keep them inside its box.
        front.pos[front.out] = np.clip(front.pos[front.out], velocity.bounds[:, 0], velocity.bounds[:, 1])
    return _assemble(front, n, complete, tol, float(merge))


def _assemble(front, normal, complete, tol, merge):
    K, G = front.pos.shape[:2]
    vertices = front.pos.reshape(-1, 3)
    release = np.repeat(front.taus, G)
    tris = front.triangles()
    moved = np.linalg.norm(front.pos[-1] - front.pos[0], axis=1).max() > 0
    if K < 2 or not moved:
        tets = np.zeros((0, 4), dtype=np.int64)
    else:
        base = np.arange(K - 1)[:, None, None] * G
        prisms = np.concatenate([tris[None] + base, tris[None] + base + G], axis=2).reshape(-1, 6)
        # Orient by the same lattice swept straight along the normal: a tet flattened by the
        # flow (a stagnation point, calm air) keeps the winding of its neighbours.
        ages = np.repeat(front.t_end - front.taus, G)
        reference = np.tile(front.generator, (K, 1)) + ages[:, None] * normal
        tets = split_prisms(prisms)
        target = front.merge_targets(tol, merge) if merge > 0 else np.arange(len(vertices))
        merged = np.any(target != np.arange(len(target)))
        ended = front.ended().reshape(-1) if front.out.any() else None
        if ended is not None:
            # The smoke ends where its air left the domain.  Tets with a vertex that ends both before and
            # after merging are dropped first: where most of the air left, most of the lattice goes unused.
            tets = tets[~(ended & ended[target])[tets].any(axis=1)]
        tets = orient(reference, tets)
        if merged:
            tets = merge_vertices(tets, target, reference)
        if ended is not None:
            tets = tets[~ended[tets].any(axis=1)]
    faces = boundary_faces(tets)
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    sv = vertices[used]
    sf = remap[faces]
    surface = Mesh(sv, sf, vertex_normals(sv, sf), {"age": (front.t_end - release[used]).astype(np.float32)})
    return FlowVolume(vertices, tets, surface, release, front.t_end - release, front.generator, normal, complete,
                      front.out.reshape(-1).copy())
