"""The advancing front of a flow volume: the generator polygon released over time and carried by the flow.

Air released through the generator between ``t0`` and ``t0 + duration`` is
followed to ``t0 + duration``: a layer of the front is the generator released
at one time and carried forward (in a steady flow the stream tube, in an
unsteady one the streak volume).  The generator is the regular polygon with
``sides`` corners about ``center``, triangulated on ``rings`` concentric
copies.  Where neighbouring front points separate by more than ``tol``, a
new point is placed on the generator between them (a new column across every
layer) or a new release time between two layers, and integrated from the
generator (Hultquist's refinement: never interpolated on the front).

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
.. [2] J. P. M. Hultquist, "Constructing stream surfaces in steady 3D vector
   fields", Proc. Visualization '92, 171-178.
.. [3] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 5).
"""

import numpy as np

from ..errors import DataError


def perpendicular_frame(normal):
    """Two unit vectors completing the unit ``normal`` to a right-handed frame (e1, e2, n)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1), n


def polygon_points(center, e1, e2, radius, sides, u, rho):
    """Points of the generator at perimeter parameter ``u`` (0..sides, corners at integers) scaled by ``rho``.

    Intermediate ``u`` lie on the polygon's straight edges, so refinement never
    changes the generator's shape.
    """
    ang = 2 * np.pi * np.arange(sides + 1) / sides
    k = np.minimum(np.floor(u).astype(int), sides - 1)
    f = (u - k)[..., None]
    corner = lambda i: np.cos(ang[i])[..., None] * e1 + np.sin(ang[i])[..., None] * e2
    return center + (radius * np.asarray(rho, dtype=np.float64))[..., None] * ((1 - f) * corner(k) + f * corner(k + 1))


def advance(velocity, points, release, t_end, steps):
    """Carry ``points`` released at times ``release`` (n,) to ``t_end`` with ``steps`` RK4 steps each.

    Every point takes the same number of steps, of its own length, so all are
    integrated together; ``velocity(points, t)`` receives a time per point.
    """
    x = np.array(points, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(release, dtype=np.float64).reshape(-1).copy()
    h = ((t_end - t) / steps)[:, None]
    if len(x) == 0:
        return x

    def f(p, tt):
        v = np.asarray(velocity(p, tt), dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(v)):
            raise DataError(f"{int(np.sum(~np.isfinite(v).all(axis=1)))} of {len(v)} velocities are missing (NaN) along the flow volume", field="velocity")
        return v

    for _ in range(steps):
        k1 = f(x, t)
        k2 = f(x + 0.5 * h * k1, t + 0.5 * h[:, 0])
        k3 = f(x + 0.5 * h * k2, t + 0.5 * h[:, 0])
        k4 = f(x + h * k3, t + h[:, 0])
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t = t + h[:, 0]
    return x


def _splits(a, b, ratio, most=8):
    """Points splitting each interval (a, b) into ``ceil(ratio)`` equal parts (at most ``most``)."""
    parts = np.clip(np.ceil(ratio), 2, most).astype(int)
    k = np.concatenate([np.arange(1, n) for n in parts])
    start, end, n = np.repeat(a, parts - 1), np.repeat(b, parts - 1), np.repeat(parts, parts - 1)
    return start + (end - start) * k / n


class Front:
    """Front points on a (release time × generator column × ring) lattice plus the centre column.

    ``pos[k, 0]`` is the centre released at ``taus[k]``; ``pos[k, 1 + j * rings + i]``
    the point at perimeter parameter ``us[j]`` on ring ``(i + 1) / rings``.
    """

    def __init__(self, velocity, center, e1, e2, radius, sides, rings, t0, duration, steps, layers=2):
        self.velocity, self.center, self.e1, self.e2 = velocity, center, e1, e2
        self.radius, self.sides, self.rings = radius, sides, rings
        self.t_end, self.steps = t0 + duration, steps
        self.us = np.arange(sides, dtype=np.float64)
        # Release times start evenly spaced; ``layers`` from the expected spacing saves refinement rounds.
        self.taus = np.linspace(t0, t0 + duration, max(int(layers), 2))
        self.pos = self._integrate(self.taus, self.us, centre=True)

    def _generator(self, us, centre):
        rho = np.arange(1, self.rings + 1) / self.rings
        pts = polygon_points(self.center, self.e1, self.e2, self.radius, self.sides, us[:, None] + 0 * rho, rho + 0 * us[:, None])
        pts = pts.reshape(-1, 3)
        return np.vstack([self.center[None], pts]) if centre else pts

    def _integrate(self, taus, us, centre):
        g = self._generator(us, centre)
        release = np.repeat(taus, len(g))
        x = advance(self.velocity, np.tile(g, (len(taus), 1)), release, self.t_end, self.steps)
        return x.reshape(len(taus), len(g), 3)

    @property
    def generator(self):
        return self._generator(self.us, True)

    def ring(self):
        """Outer-ring positions (layers, columns, 3)."""
        r = self.rings
        return self.pos[:, 1 + (r - 1)::r]

    def refine(self, tol, max_points):
        """Insert columns and layers until neighbours are within ``tol`` (or ``max_points`` is reached)."""
        while self.pos.shape[0] * self.pos.shape[1] < max_points:
            ring = self.ring()
            gap = np.linalg.norm(np.roll(ring, -1, axis=1) - ring, axis=2).max(axis=0)
            cols = np.nonzero(gap > tol)[0]
            lay = np.linalg.norm(self.pos[1:] - self.pos[:-1], axis=2).max(axis=1)
            rows = np.nonzero(lay > tol)[0]
            if len(cols) == 0 and len(rows) == 0:
                return True
            # Split each long gap into ceil(gap / tol) parts at once (at most 8 a round): fewer rounds,
            # and every round re-reads the velocity for all the new points together.
            if len(cols):
                nxt = np.where(cols + 1 < len(self.us), self.us[(cols + 1) % len(self.us)], self.sides)
                self._add_columns(_splits(self.us[cols], nxt, gap[cols] / tol))
            if len(rows):
                self._add_layers(_splits(self.taus[rows], self.taus[rows + 1], lay[rows] / tol))
        return False

    def _add_columns(self, new_us):
        new = self._integrate(self.taus, new_us, centre=False).reshape(len(self.taus), len(new_us), self.rings, 3)
        old = self.pos[:, 1:].reshape(len(self.taus), len(self.us), self.rings, 3)
        us = np.concatenate([self.us, new_us])
        order = np.argsort(us, kind="stable")
        cols = np.concatenate([old, new], axis=1)[:, order].reshape(len(self.taus), -1, 3)
        self.us = us[order]
        self.pos = np.concatenate([self.pos[:, :1], cols], axis=1)

    def _add_layers(self, new_taus):
        new = self._integrate(new_taus, self.us, centre=True)
        taus = np.concatenate([self.taus, new_taus])
        order = np.argsort(taus, kind="stable")
        self.taus = taus[order]
        self.pos = np.concatenate([self.pos, new], axis=0)[order]

    def triangles(self):
        """Generator triangles (indices into one layer's points)."""
        J, R = len(self.us), self.rings
        j = np.arange(J)
        j2 = (j + 1) % J
        g = lambda jj, i: 1 + jj * R + i
        tris = [np.stack([np.zeros(J, dtype=np.int64), g(j, 0), g(j2, 0)], axis=1)]
        for i in range(R - 1):
            tris.append(np.stack([g(j, i), g(j, i + 1), g(j2, i + 1)], axis=1))
            tris.append(np.stack([g(j, i), g(j2, i + 1), g(j2, i)], axis=1))
        return np.concatenate(tris)

    def merge_targets(self, tol, fraction):
        """Where the front converged: for each lattice point, the point it is merged into (itself if kept).

        In each layer a column is merged into its previous kept column when
        the flow brought them closer than ``fraction * tol`` and than
        ``fraction`` times their distance on the generator (on every ring), and
        the kept column is within ``tol`` of the next one, so the front stays
        within ``tol`` (Hultquist's point removal, one layer at a time).  Where
        the flow did not converge nothing is merged, so uniform and shear flows
        stay exact.  Generator corners are kept in the newest layer, the
        generator itself.
        """
        K, J, R = len(self.taus), len(self.us), self.rings
        cols = self.pos[:, 1:].reshape(K, J, R, 3)
        target = np.arange(K * (1 + J * R)).reshape(K, 1 + J * R)
        gen = self._generator(self.us, False).reshape(J, R, 3)
        layers = np.arange(K)
        keep = np.zeros(K, dtype=np.int64)
        protect = np.zeros(K, dtype=bool)
        protect[-1] = True
        # Walk the columns once, every layer at a time: each layer keeps its own last kept column.
        for j in range(1, J):
            kept = cols[layers, keep]
            gap = np.linalg.norm(kept - cols[:, j], axis=-1).max(axis=-1)
            released = np.linalg.norm(gen[keep] - gen[j], axis=-1).max(axis=-1)
            near = (gap < fraction * tol) & (gap < fraction * released)
            bridge = np.linalg.norm(kept - cols[:, (j + 1) % J], axis=-1).max(axis=-1) < tol
            merge = near & bridge & ~(protect & (self.us[j] == np.round(self.us[j])))
            ks = np.nonzero(merge)[0]
            target[ks, 1 + j * R:1 + (j + 1) * R] = target[ks[:, None], 1 + keep[ks, None] * R + np.arange(R)]
            keep = np.where(merge, keep, j)
        return target.reshape(-1)
