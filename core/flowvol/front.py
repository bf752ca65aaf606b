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


def advance(velocity, points, release, t_end, steps, stop=False):
    """Carry ``points`` released at times ``release`` (n,) to ``t_end`` with ``steps`` RK4 steps each.

    Every point takes the same number of steps, of its own length, so all are
    integrated together; ``velocity(points, t)`` receives a time per point.
    With ``stop``, a point whose step meets a missing (NaN) velocity has left
    the field's domain (a wall, an outlet): it stays at its exit point, found
    by bisection between its last position inside and the first stage point
    outside, and is no longer moved.  A point released where the velocity is
    missing is always a :class:`DataError`.

    Returns
    -------
    x : (n, 3) array
    out : (n,) bool array
        The points that left the domain (``stop`` only).
    """
    x = np.array(points, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(release, dtype=np.float64).reshape(-1).copy()
    h = ((t_end - t) / steps)[:, None]
    out = np.zeros(len(x), dtype=bool)
    if len(x) == 0:
        return x, out

    def f(p, tt, where):
        v = np.asarray(velocity(p, tt), dtype=np.float64).reshape(-1, 3)
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any() and (not stop or where == "release"):
            what = "of the generator's points lie outside the velocity's domain" if where == "release" else "velocities are missing"
            raise DataError(f"{int(bad.sum())} of {len(v)} {what} (NaN) along the flow volume", field="velocity")
        v[bad] = 0.0
        return v, bad

    live = np.arange(len(x))  # indices of the points still moving
    who, inner, outer, when = [], [], [], []  # each exit's point, its last position inside, first outside, time
    prev = x.copy()
    for step in range(steps):
        xl, tl, hl = x[live], t[live], h[live]
        k1, b1 = f(xl, tl, "release" if step == 0 else "step")
        stages = [xl + 0.5 * hl * k1, xl + 0.5 * hl * k1, xl + hl * k1]
        k2, b2 = f(stages[0], tl + 0.5 * hl[:, 0], "step")
        stages[1] = xl + 0.5 * hl * k2
        k3, b3 = f(stages[1], tl + 0.5 * hl[:, 0], "step")
        stages[2] = xl + hl * k3
        k4, b4 = f(stages[2], tl + hl[:, 0], "step")
        new = xl + hl / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        gone = b1 | b2 | b3 | b4
        if gone.any():
            # The segment holding the exit: back to the last step's start when the step began outside.
            first = np.select([b1[:, None], b2[:, None], b3[:, None]], [xl, stages[0], stages[1]], stages[2])
            start = np.where(b1[:, None], prev[live], xl)
            who.append(live[gone])
            inner.append(start[gone])
            outer.append(first[gone])
            when.append(tl[gone])
            x[live[gone]] = start[gone]
            out[live[gone]] = True
        prev[live] = xl
        x[live[~gone]] = new[~gone]
        t[live] = tl + hl[:, 0]
        live = live[~gone]
        if len(live) == 0:
            break
    if stop and len(live):
        # The last step may end outside although its stages were inside: back to that step's start.
        _, gone = f(x[live], t[live], "step")
        if gone.any():
            who.append(live[gone])
            inner.append(prev[live[gone]])
            outer.append(x[live[gone]])
            when.append(t[live[gone]])
            x[live[gone]] = prev[live[gone]]
            out[live[gone]] = True
    if inner:
        a, b, tt = np.concatenate(inner), np.concatenate(outer), np.concatenate(when)
        for _ in range(16):  # bisection to 2^-16 of the segment; ``a`` stays inside
            mid = 0.5 * (a + b)
            _, bad = f(mid, tt, "step")
            a = np.where(bad[:, None], a, mid)
            b = np.where(bad[:, None], mid, b)
        x[np.concatenate(who)] = a
    return x, out


def _splits(a, b, ratio, most=8, margin=1.25):
    """Points splitting each interval (a, b) into ``ceil(margin * ratio)`` equal parts (at most ``most``).

    The margin anticipates that the flow keeps stretching a gap between the
    points found in a round: one refinement round fewer (one sweep of velocity
    reads) for about a quarter more points (demo winds: 3 -> 2 rounds).
    """
    parts = np.clip(np.ceil(margin * ratio), 2, most).astype(int)
    k = np.concatenate([np.arange(1, n) for n in parts])
    start, end, n = np.repeat(a, parts - 1), np.repeat(b, parts - 1), np.repeat(parts, parts - 1)
    return start + (end - start) * k / n


class Front:
    """Front points on a (release time × generator column × ring) lattice plus the centre column.

    ``pos[k, 0]`` is the centre released at ``taus[k]``; ``pos[k, 1 + j * rings + i]``
    the point at perimeter parameter ``us[j]`` on ring ``(i + 1) / rings``.
    ``out`` marks the points that left the velocity's domain (``stop``: they
    rest at their exit point).
    """

    def __init__(self, velocity, center, e1, e2, radius, sides, rings, t0, duration, steps, layers=2, stop=False):
        self.velocity, self.center, self.e1, self.e2 = velocity, center, e1, e2
        self.radius, self.sides, self.rings = radius, sides, rings
        self.t_end, self.steps, self.stop = t0 + duration, steps, stop
        self.us = np.arange(sides, dtype=np.float64)
        # Release times start evenly spaced; ``layers`` from the expected spacing saves refinement rounds.
        self.taus = np.linspace(t0, t0 + duration, max(int(layers), 2))
        g = self._generator(self.us, True)
        x, out = advance(velocity, np.tile(g, (len(self.taus), 1)), np.repeat(self.taus, len(g)), self.t_end, steps, stop)
        self.pos, self.out = x.reshape(len(self.taus), len(g), 3), out.reshape(len(self.taus), len(g))

    def _generator(self, us, centre):
        rho = np.arange(1, self.rings + 1) / self.rings
        pts = polygon_points(self.center, self.e1, self.e2, self.radius, self.sides, us[:, None] + 0 * rho, rho + 0 * us[:, None])
        pts = pts.reshape(-1, 3)
        return np.vstack([self.center[None], pts]) if centre else pts

    @property
    def generator(self):
        return self._generator(self.us, True)

    def ring(self):
        """Outer-ring positions (layers, columns, 3)."""
        r = self.rings
        return self.pos[:, 1 + (r - 1)::r]

    def refine(self, tol, max_points):
        """Insert columns and layers until neighbours are within ``tol`` (or ``max_points`` is reached).

        Neighbours of a point that left the domain are not refined: no tetrahedron uses it, and where
        the flow tears at a wall or an obstacle's edge the gap would never close.
        """
        r = self.rings
        while self.pos.shape[0] * self.pos.shape[1] < max_points:
            ring, ring_out = self.ring(), self.out[:, 1 + (r - 1)::r]
            d = np.linalg.norm(np.roll(ring, -1, axis=1) - ring, axis=2)
            d[ring_out | np.roll(ring_out, -1, axis=1)] = 0.0
            gap = d.max(axis=0)
            cols = np.nonzero(gap > tol)[0]
            d = np.linalg.norm(self.pos[1:] - self.pos[:-1], axis=2)
            d[self.out[1:] | self.out[:-1]] = 0.0
            lay = d.max(axis=1)
            rows = np.nonzero(lay > tol)[0]
            if len(cols) == 0 and len(rows) == 0:
                return True
            # Split each long gap into ceil(1.25 gap / tol) parts at once (at most 8 a round): fewer rounds.
            new_us = np.zeros(0)
            if len(cols):
                nxt = np.where(cols + 1 < len(self.us), self.us[(cols + 1) % len(self.us)], self.sides)
                new_us = _splits(self.us[cols], nxt, gap[cols] / tol)
            new_taus = _splits(self.taus[rows], self.taus[rows + 1], lay[rows] / tol) if len(rows) else np.zeros(0)
            self._insert(new_us, new_taus)
        return False

    def ended(self):
        """Points no tetrahedron may use (layers, points): those that left the domain and their lattice neighbours.

        Gaps next to a point that left are not refined, so the smoke ends one
        lattice step before the exits, where the front is still resolved.
        """
        K, J, R = len(self.taus), len(self.us), self.rings
        out = self.out
        end = out.copy()
        end[1:] |= out[:-1]
        end[:-1] |= out[1:]
        cols = out[:, 1:].reshape(K, J, R)
        near = np.roll(cols, 1, axis=1) | np.roll(cols, -1, axis=1)
        end[:, 1:] |= near.reshape(K, J * R)
        end[:, 0] |= cols[:, :, 0].any(axis=1)  # the centre's neighbours are the inner ring
        end[:, 1::R] |= out[:, :1]
        return end

    def _insert(self, new_us, new_taus):
        """Add columns at perimeter parameters ``new_us`` and layers at release times ``new_taus``.

        The new columns of the old layers and the new layers (all columns) are
        integrated together: one sweep of velocity reads per refinement round.
        """
        K, J, R = len(self.taus), len(self.us), self.rings
        us = np.concatenate([self.us, new_us])
        order = np.argsort(us, kind="stable")
        gc = self._generator(new_us, centre=False)
        gl = self._generator(us[order], centre=True)
        x, out = advance(self.velocity, np.concatenate([np.tile(gc, (K, 1)), np.tile(gl, (len(new_taus), 1))]),
                         np.concatenate([np.repeat(self.taus, len(gc)), np.repeat(new_taus, len(gl))]), self.t_end, self.steps, self.stop)
        m = K * len(gc)

        def columns(old, new, shape):
            # Old and new columns of the old layers, in perimeter order.
            cols = np.concatenate([old[:, 1:].reshape((K, J, R) + shape), new.reshape((K, len(new_us), R) + shape)], axis=1)
            return np.concatenate([old[:, :1], cols[:, order].reshape((K, -1) + shape)], axis=1)

        pos, was_out = columns(self.pos, x[:m], (3,)), columns(self.out, out[:m], ())
        taus = np.concatenate([self.taus, new_taus])
        layers = np.argsort(taus, kind="stable")
        self.us, self.taus = us[order], taus[layers]
        self.pos = np.concatenate([pos, x[m:].reshape(len(new_taus), len(gl), 3)])[layers]
        self.out = np.concatenate([was_out, out[m:].reshape(len(new_taus), len(gl))])[layers]

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
        # A layer's first merge is into the column just before: layers without such a near pair never merge.
        gap = np.linalg.norm(cols[:, 1:] - cols[:, :-1], axis=-1).max(axis=-1)
        released = np.linalg.norm(gen[1:] - gen[:-1], axis=-1).max(axis=-1)
        layers = np.nonzero(((gap < fraction * tol) & (gap < fraction * released)).any(axis=1))[0]
        if len(layers) == 0:
            return target.reshape(-1)
        cols = cols[layers]
        keep = np.zeros(len(layers), dtype=np.int64)
        protect = layers == K - 1
        rows = np.arange(len(layers))
        # Walk the columns once, every layer at a time: each layer keeps its own last kept column.
        for j in range(1, J):
            kept = cols[rows, keep]
            gap = np.linalg.norm(kept - cols[:, j], axis=-1).max(axis=-1)
            released = np.linalg.norm(gen[keep] - gen[j], axis=-1).max(axis=-1)
            near = (gap < fraction * tol) & (gap < fraction * released)
            bridge = np.linalg.norm(kept - cols[:, (j + 1) % J], axis=-1).max(axis=-1) < tol
            merge = near & bridge & ~(protect & (self.us[j] == np.round(self.us[j])))
            ks = np.nonzero(merge)[0]
            target[layers[ks], 1 + j * R:1 + (j + 1) * R] = target[layers[ks][:, None], 1 + keep[ks, None] * R + np.arange(R)]
            keep = np.where(merge, keep, j)
        return target.reshape(-1)
