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
    def corner(i):
        return np.cos(ang[i])[..., None] * e1 + np.sin(ang[i])[..., None] * e2
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
            what = ("of the generator's points lie outside the velocity's domain" if where == "release"
                    else "velocities are missing")
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


def _hermite(x0, v0, x1, v1, h, s):
    """Cubic Hermite interpolation at fraction ``s`` (n,) of steps of length ``h`` (n,) between (x0, v0) and
    (x1, v1)."""
    s2, s3 = s * s, s * s * s
    w = [2 * s3 - 3 * s2 + 1, (s3 - 2 * s2 + s) * h, 3 * s2 - 2 * s3, (s3 - s2) * h]
    return w[0][:, None] * x0 + w[1][:, None] * v0 + w[2][:, None] * x1 + w[3][:, None] * v1


class Streams:
    """Streamlines of generator points in a steady flow, each integrated once and read at any age.

    In a steady flow the air released at time ``t`` is the generator carried for
    ``t_end - t``: every layer of the front lies on the same streamlines, so
    each generator point is integrated once from age 0 to ``duration``
    (``steps`` RK4 steps, positions and velocities kept) and a layer is read
    from them by cubic Hermite interpolation (Hultquist's stream tube).  With
    ``stop``, a streamline that leaves the domain during a step is followed by
    bisecting that step's length (``resolution`` in distance): ages up to the
    longest step that stays inside are read, older ones rest at the exit point.

    References
    ----------
    .. [1] J. P. M. Hultquist, "Constructing stream surfaces in steady 3D
       vector fields", Proc. Visualization '92, 171-178.
    """

    def __init__(self, velocity, duration, steps, stop, resolution):
        self.velocity, self.stop, self.resolution = velocity, stop, float(resolution)
        self.steps, self.h = int(steps), float(duration) / int(steps)
        self.x = np.zeros((0, self.steps + 1, 3))
        self.v = np.zeros((0, self.steps + 1, 3))
        self.last = np.zeros(0, dtype=np.int64)  # index of the last sample inside the domain
        self.tail = np.zeros(0)  # length of the part-step after it that stays inside
        self.tail_x, self.tail_v = np.zeros((0, 3)), np.zeros((0, 3))
        self.beyond = np.zeros((0, 3))  # a point outside past the tail (its exit lies between them)
        self.exit = None  # exit points, once found (:meth:`exits`)

    def _f(self, p, release=False):
        v = np.asarray(self.velocity(p, np.zeros(len(p))), dtype=np.float64).reshape(-1, 3)
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any() and (release or not self.stop):
            what = ("of the generator's points lie outside the velocity's domain" if release
                    else "velocities are missing")
            raise DataError(f"{int(bad.sum())} of {len(v)} {what} (NaN) along the flow volume", field="velocity")
        return v, bad

    def _step(self, x, k1, h):
        """One RK4 step of lengths ``h`` (n,) from ``x`` with its velocity ``k1``: end, its velocity, the
        first stage outside, out."""
        hc = h[:, None]
        s1 = x + 0.5 * hc * k1
        k2, b2 = self._f(s1)
        s2 = x + 0.5 * hc * np.where(b2[:, None], 0.0, k2)
        k3, b3 = self._f(s2)
        s3 = x + hc * np.where(b3[:, None], 0.0, k3)
        k4, b4 = self._f(s3)
        end = x + hc / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        bad = b2 | b3 | b4
        ve, be = self._f(np.where(bad[:, None], x, end))
        # first stage out
        outside = np.where(b2[:, None], s1, np.where(b3[:, None], s2, np.where(b4[:, None], s3, end)))
        return end, ve, outside, bad | be

    def add(self, points):
        """Integrate the streamlines of generator ``points`` (n, 3); their indices."""
        n, N, h = len(points), self.steps, self.h
        x = np.zeros((n, N + 1, 3))
        v = np.zeros((n, N + 1, 3))
        x[:, 0] = points
        v[:, 0] = self._f(x[:, 0], release=True)[0]
        last = np.full(n, N, dtype=np.int64)
        beyond = np.zeros((n, 3))
        live = np.arange(n)
        for i in range(N):
            if len(live) == 0:
                break
            end, ve, outside, bad = self._step(x[live, i], v[live, i], np.full(len(live), h))
            x[live, i + 1], v[live, i + 1] = end, ve
            last[live[bad]], beyond[live[bad]] = i, outside[bad]
            live = live[~bad]
        # Streamlines that left during a step: bisect the step's length, keeping the longest that stays inside.
        gone = np.nonzero(last < N)[0]
        tail, tail_x, tail_v = np.zeros(n), x[np.arange(n), last], v[np.arange(n), last]
        if len(gone):
            x0, k1 = tail_x[gone], tail_v[gone]
            lo, hi = np.zeros(len(gone)), np.full(len(gone), h)
            xin, vin, far = x0.copy(), k1.copy(), beyond[gone]
            speed = max(float(np.linalg.norm(k1, axis=1).max()), 1e-300)
            for _ in range(int(np.clip(np.ceil(np.log2(h * speed / self.resolution)), 0, 16))):
                mid = 0.5 * (lo + hi)
                end, ve, outside, bad = self._step(x0, k1, mid)
                lo, xin, vin = np.where(bad, lo, mid), np.where(bad[:, None], xin, end), np.where(bad[:, None], vin, ve)
                hi, far = np.where(bad, mid, hi), np.where(bad[:, None], outside, far)
            tail[gone], tail_x[gone], tail_v[gone], beyond[gone] = lo, xin, vin, far
        first = len(self.x)
        self.x, self.v = np.concatenate([self.x, x]), np.concatenate([self.v, v])
        self.last, self.tail = np.concatenate([self.last, last]), np.concatenate([self.tail, tail])
        self.tail_x, self.tail_v = np.concatenate([self.tail_x, tail_x]), np.concatenate([self.tail_v, tail_v])
        self.beyond = np.concatenate([self.beyond, beyond])
        self.exit = None
        return np.arange(first, first + n)

    def exits(self):
        """Exit point of every streamline that leaves the domain (on its tail end's segment to the point beyond)."""
        if self.exit is None:
            self.exit = self.tail_x.copy()
            gone = np.nonzero(self.last < self.steps)[0]
            a, b = self.tail_x[gone], self.beyond[gone]
            for _ in range(16 if len(gone) else 0):  # bisection to 2^-16 of the segment; ``a`` stays inside
                mid = 0.5 * (a + b)
                bad = self._f(mid)[1]
                a = np.where(bad[:, None], a, mid)
                b = np.where(bad[:, None], mid, b)
            self.exit[gone] = a
        return self.exit

    def sample(self, ids, ages):
        """Positions (m, 3) of streamlines ``ids`` at ``ages`` (m,) and whether they had left (resting at the tail end
        until :meth:`exits` has placed them on the boundary)."""
        ids, ages = np.asarray(ids), np.asarray(ages, dtype=np.float64)
        h, last = self.h, self.last[ids]
        i = (np.clip(np.floor(ages / h).astype(np.int64), 0, self.steps - 1) if h > 0
             else np.zeros(len(ids), dtype=np.int64))
        out = ages > last * h + self.tail[ids] + 1e-12 * max(h, 1e-300)
        inner = i < last
        pos = np.empty((len(ids), 3))
        k = np.nonzero(inner)[0]
        c, j = ids[k], i[k]
        pos[k] = _hermite(self.x[c, j], self.v[c, j], self.x[c, j + 1], self.v[c, j + 1], np.full(len(k), h),
                          (ages[k] - j * h) / h if h > 0 else np.zeros(len(k)))
        k = np.nonzero(~inner)[0]
        c, t = ids[k], self.tail[ids[k]]
        frac = np.clip((ages[k] - self.last[c] * h) / np.where(t > 0, t, 1.0), 0.0, 1.0)
        pos[k] = _hermite(self.x[c, self.last[c]], self.v[c, self.last[c]], self.tail_x[c], self.tail_v[c], t, frac)
        if out.any():
            pos[out] = (self.exit if self.exit is not None else self.tail_x)[ids[out]]
        return pos, out


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

    def __init__(self, velocity, center, e1, e2, radius, sides, rings, t0, duration, steps, layers=2, stop=False,
                 steady=False, resolution=None):
        self.velocity, self.center, self.e1, self.e2 = velocity, center, e1, e2
        self.radius, self.sides, self.rings = radius, sides, rings
        self.t_end, self.steps, self.stop = t0 + duration, steps, stop
        self.us = np.arange(sides, dtype=np.float64)
        # Release times start evenly spaced; ``layers`` from the expected spacing saves refinement rounds.
        self.taus = np.linspace(t0, t0 + duration, max(int(layers), 2))
        g = self._generator(self.us, True)
        # A steady flow: one streamline per generator point, every layer read from them (no per-layer integration).
        self.streams = (Streams(velocity, duration, steps, stop, resolution or radius / sides)
                        if steady and duration > 0
                        else None)
        if self.streams is not None:
            self.ids = self.streams.add(g)  # each lattice column's streamline
            alive = float((self.streams.last * self.streams.h + self.streams.tail).max())
            if alive < duration and len(self.taus) > 2:
                # All the generator's air has left before ``alive``: older layers would all rest at exits.
                # The layers are spread over the ages where some air is left (and one beyond), plus the oldest.
                gap = duration / (len(self.taus) - 1)
                n = int(np.ceil(alive / gap)) + 1
                self.taus = (np.concatenate([[t0], self.t_end - gap * np.arange(n, -1, -1)]) if n * gap < duration
                             else self.taus)
            self._sample()
            return
        x, out = advance(velocity, np.tile(g, (len(self.taus), 1)), np.repeat(self.taus, len(g)), self.t_end, steps,
                         stop)
        self.pos, self.out = x.reshape(len(self.taus), len(g), 3), out.reshape(len(self.taus), len(g))

    def _sample(self):
        K, G = len(self.taus), len(self.ids)
        x, out = self.streams.sample(np.tile(self.ids, K), np.repeat(self.t_end - self.taus, G))
        self.pos, self.out = x.reshape(K, G, 3), out.reshape(K, G)

    def settle(self):
        """Place the points that left the domain at their exit points (streamlines: found once, at the end)."""
        if self.streams is not None and self.out.any():
            self.streams.exits()
            self._sample()

    def _generator(self, us, centre):
        rho = np.arange(1, self.rings + 1) / self.rings
        pts = polygon_points(self.center, self.e1, self.e2, self.radius, self.sides, us[:, None] + 0 * rho,
                             rho + 0 * us[:, None])
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
        if self.streams is not None:  # new columns get their own streamlines; new layers are read from all
            cols = np.concatenate([self.ids[1:].reshape(J, R), self.streams.add(gc).reshape(len(new_us), R)])
            self.ids = np.concatenate([self.ids[:1], cols[order].reshape(-1)])
            self.us, self.taus = us[order], np.sort(np.concatenate([self.taus, new_taus]), kind="stable")
            self._sample()
            return
        gl = self._generator(us[order], centre=True)
        x, out = advance(self.velocity, np.concatenate([np.tile(gc, (K, 1)), np.tile(gl, (len(new_taus), 1))]),
                         np.concatenate([np.repeat(self.taus, len(gc)), np.repeat(new_taus, len(gl))]), self.t_end,
                         self.steps, self.stop)
        m = K * len(gc)

        def columns(old, new, shape):
            # Old and new columns of the old layers, in perimeter order.
            cols = np.concatenate([old[:, 1:].reshape((K, J, R) + shape), new.reshape((K, len(new_us), R) + shape)],
                                  axis=1)
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
        def g(jj, i):
            return 1 + jj * R + i
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
            target[layers[ks], 1 + j * R:1 + (j + 1) * R] = target[layers[ks][:, None],
                                                                   1 + keep[ks, None] * R + np.arange(R)]
            keep = np.where(merge, keep, j)
        return target.reshape(-1)
