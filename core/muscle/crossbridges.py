"""The cross-bridges in the filament lattice: hinged heads driven through the cycle, thin filaments sliding.

:class:`CrossBridges` puts the pieces together (:mod:`.dynamics`, :mod:`.collisions`,
:mod:`.cycle`); the model is described in :mod:`.brownian`.

References
----------
.. [1] N. Max, N. Hayashi and T. Wakabayashi, "Computer simulation and
   animation of muscle cross-bridge motion", J. Visualization and Computer
   Animation 1(1), 9-14 (1990).
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import DataError
from . import lattice as lat
from .collisions import hinge_velocities, hinged_collision, turn_hinges
from .cycle import (
    AM_ADP_PI,
    BOUND,
    M_ADP_PI,
    RATES,
    cycle_generator,
    cycle_step,
    transition_matrix,
)
from .dynamics import (
    KT_300,
    WATER_VISCOSITY,
    _kT,
    check_step,
    rotation_matrix,
    rotational_drag,
    translational_drag,
)
from .molecules import LEVER_LENGTH

HEAD_SPHERES = np.array([3.0, 8.5, 14.0])
"""Distances of a head's collision spheres from its hinge along the straight head (S1 is 16.5 nm long)."""

ELBOW = LEVER_LENGTH
"""Distance of the elbow (the converter, where the motor domain turns on the lever) from the hinge, nm."""

MOTOR_SPHERE = HEAD_SPHERES >= ELBOW
"""Which collision spheres belong to the motor domain (they turn about the elbow too)."""

HEAD_SPHERE_RADIUS = 2.5

MAX_BOUND_PER_FILAMENT = 20
"""Bound heads per thin filament assumed by the sliding time-step check."""

TIP_REACH = HEAD_SPHERES[-1]


@dataclass(frozen=True)
class Params:
    """Simulation settings (nm, us, pN).

    Attributes
    ----------
    dt : float
        Brownian time step, us.
    frame_time : float
        Brownian time per film frame, us.
    speedup : float
        Factor by which the chemistry runs faster than in muscle.
    kT, viscosity : float
    hinge_stiffness : float
        Angular spring of the hinge, pN nm / rad^2 (20 kT: about 13 degrees rms).
    elbow_stiffness : float
        Angular spring between lever and motor domain, pN nm / rad^2 (5 kT: about 26 degrees rms; stiffer
        needs a shorter ``dt``, as the motor domain's own drag about the elbow is small).
    bind_stiffness : float
        Spring holding a bound tip to its site, pN / nm.
    capture : float
        A detached, primed head binds a free site within this distance of its tip, nm.
    pre_stroke, post_stroke : float
        Hinge rest tilt towards +z (away from the M line) before and after the power stroke, radians.
    filament_drag : float
        Drag of a thin filament sliding along its axis, pN us / nm (slender body, 1 um long, in water).
    load : float
        Force opposing each thin filament's sliding, pN.
    rates : dict
        Cycle rate constants, 1/s (see :data:`RATES`).
    """

    dt: float = 0.01
    frame_time: float = 0.1
    speedup: float = 2e4
    kT: float = KT_300
    viscosity: float = WATER_VISCOSITY
    hinge_stiffness: float = 20 * KT_300
    elbow_stiffness: float = 5 * KT_300
    bind_stiffness: float = 0.5
    capture: float = 4.0
    pre_stroke: float = np.deg2rad(50.0)
    post_stroke: float = np.deg2rad(-30.0)
    filament_drag: float = 2 * np.pi * WATER_VISCOSITY * 1000.0 / (np.log(1000.0 / 9.0) - 0.2)
    load: float = 0.0
    rates: dict = field(default_factory=lambda: dict(RATES))

    @property
    def head_drag(self):
        """Rotational drag of a head about its hinge (its spheres, Stokes), pN nm us."""
        r = HEAD_SPHERE_RADIUS
        return float(
            np.sum(translational_drag(r, self.viscosity) * HEAD_SPHERES**2) + 3 * rotational_drag(r, self.viscosity)
        )

    @property
    def elbow_drag(self):
        """Rotational drag of a motor domain about the elbow (its spheres, Stokes), pN nm us."""
        r, s = HEAD_SPHERE_RADIUS, HEAD_SPHERES[MOTOR_SPHERE] - ELBOW
        return float(np.sum(translational_drag(r, self.viscosity) * s**2) + len(s) * rotational_drag(r, self.viscosity))

    @property
    def steps_per_frame(self):
        return max(1, int(round(self.frame_time / self.dt)))

@dataclass
class Frame:
    """The state of the cell at one film frame."""

    rotations: np.ndarray  # (n, 3, 3) lever frames (column 0: along the lever, from hinge to elbow)
    states: np.ndarray  # (n,) cycle state
    sites: np.ndarray  # (n,) bound actin subunit or -1
    slide: np.ndarray  # (6,) thin filament displacement, nm
    time: float  # Brownian time, us
    motor: np.ndarray  # (n, 3, 3) motor domain frames in the lab (column 0: from the elbow to the tip)

def _tilt_frames(heads, tilt):
    """Head frames: x along the head (its rest direction tilted by ``tilt`` towards +z), z near the fibre axis."""
    x0 = heads.rest
    ez = np.array([0.0, 0.0, 1.0])
    t = np.broadcast_to(np.asarray(tilt, np.float64), (len(x0),))
    x = np.cos(t)[:, None] * x0 + np.sin(t)[:, None] * ez
    y = np.cross(ez, x0)
    y /= np.linalg.norm(y, axis=1)[:, None]
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=2)

class CrossBridges:
    """Myosin heads of one unit cell through Brownian motion and the cross-bridge cycle.

    Parameters
    ----------
    lattice : Lattice
    params : Params
    seed : int
        Seeds every random number (same seed, same film).
    """

    def __init__(self, lattice, params=None, seed=0):
        self.lattice = lattice
        self.p = params or Params()
        p = self.p
        self.kT = _kT(p.kT)
        self.drag, self.elbow_drag = p.head_drag, p.elbow_drag
        check_step(p.dt, self.drag, p.hinge_stiffness + p.bind_stiffness * TIP_REACH**2)
        check_step(p.dt, self.elbow_drag, p.elbow_stiffness + p.bind_stiffness * (TIP_REACH - ELBOW) ** 2)
        check_step(p.dt, p.filament_drag, p.bind_stiffness * MAX_BOUND_PER_FILAMENT, what="dt (filament sliding)")
        self.rng = np.random.default_rng(seed)
        self.heads = lat.myosin_heads(lattice)
        n = len(self.heads)
        self._pairs = self._sphere_pairs()
        q = cycle_generator(p.rates)
        chem_dt = p.dt * 1e-6 * p.speedup
        self.P = transition_matrix(q, chem_dt)
        qb = q.copy()
        qb[M_ADP_PI, AM_ADP_PI] = 0
        qb[np.diag_indices(5)] = 0
        qb[np.diag_indices(5)] = -qb.sum(axis=1)
        self.P_blocked = transition_matrix(qb, chem_dt)
        self.slide = np.zeros(6)
        self.time = 0.0
        self.collisions = self.rejected = 0  # of the last step: bounces resolved, moves refused
        # Filament axes in the orthorhombic box (both copies of the cell): xy distances need only box rounding.
        self._axes = [(lattice.to_box(np.column_stack([xy, np.zeros(len(xy))]))[:, :2], rad)
                      for xy, rad in ((lattice.thin_xy, lat.THIN_RADIUS), (lattice.thick_xy, lat.THICK_RADIUS))]
        # Start primed and detached (lever up): that pose clears the thin filaments.
        self.states = np.full(n, M_ADP_PI)
        self.sites = np.full(n, -1)
        self.Q = np.tile(np.eye(3), (n, 1, 1))  # straight heads
        self.Q_bind = self.Q.copy()
        self.R = self._place(_tilt_frames(self.heads, self._rest_tilt(self.states)))
        self.R_bind = self.R.copy()
        # The power stroke turns the head about ez x rest, swinging its tip towards -z (the M line).
        axis = np.cross([0.0, 0.0, 1.0], self.heads.rest)
        self._stroke_axis = axis / np.linalg.norm(axis, axis=1)[:, None]

    # geometry --------------------------------------------------------------------

    def _rest_tilt(self, states):
        return np.where(np.isin(states, (M_ADP_PI, AM_ADP_PI)), self.p.pre_stroke, self.p.post_stroke)

    def spheres(self, R=None, Q=None):
        """(n, 3, 3) collision sphere centres of every head (lever frames ``R``, motor domains ``Q`` on them)."""
        R = self.R if R is None else R
        Q = self.Q if Q is None else Q
        lever, motor = R[:, None, :, 0], (R @ Q)[:, None, :, 0]
        s = HEAD_SPHERES[None, :, None]
        along = np.where(MOTOR_SPHERE[None, :, None], ELBOW * lever + (s - ELBOW) * motor, s * lever)
        return self.heads.pivots[:, None, :] + along

    def tips(self, R=None, Q=None):
        """(n, 3) centres of the heads' tip spheres (the actin-binding end of the motor domain)."""
        return self.spheres(R, Q)[:, -1]

    def site_positions(self, slide=None):
        """(m, 3) binding sites: one per actin subunit, where a bound tip sphere's centre sits."""
        sub = lat.actin_subunits(self.lattice, self.slide if slide is None else slide)
        r = lat.THIN_RADIUS + HEAD_SPHERE_RADIUS + 0.05
        return sub.origins + r * sub.rotations[:, :, 0], sub.filament

    def overlaps(self, R=None, Q=None):
        """Per head: does any of its spheres overlap a thin filament, a thick backbone or another head?

        The tip sphere of a bound head is exempt from the thin filaments (its
        spring holds it at its site); the first spheres of a molecule's two
        heads share the hinge and may touch.
        """
        head, other = self._contacts(R, Q, R, Q)[:2]
        bad = np.zeros(len(self.heads), bool)
        bad[head] = True
        bad[other[other >= 0]] = True
        return bad

    def _contacts(self, R, Q, R0, Q0):
        """Overlaps of the heads in frames ``R, Q``, as collisions to resolve from frames ``R0, Q0``.

        Returns one row per overlapping head sphere and filament, or pair of
        head spheres: arrays ``head``, ``other`` (the other head, or -1 for a
        filament), ``arm``, ``other_arm`` ((m, 2, 3): sphere centre minus the
        hinge and minus the elbow, zero for a lever sphere, in ``R0, Q0``),
        ``normal`` (unit, from the other body towards the head, in ``R0, Q0``)
        and ``depth`` (nm).
        """
        R0 = self.R if R0 is None else R0
        c, c0 = self.spheres(R, Q), self.spheres(R0, Q0)
        n = len(c)
        flat, flat0 = c.reshape(-1, 3), c0.reshape(-1, 3)
        lt = self.lattice
        box = lt.box[:2]
        xy, xy0 = lt.wrap(flat)[:, None, :2], lt.wrap(flat0)[:, None, :2]
        out = []
        for k, (axes, rad) in enumerate(self._axes):
            d = xy - axes[None]
            d -= np.round(d / box) * box
            r2 = np.einsum("nak,nak->na", d, d)
            hit = r2 < (rad + HEAD_SPHERE_RADIUS - 1e-9) ** 2
            if k == 0:  # a bound head's tip rests on its actin: it may press into the thin filament
                hit.reshape(n, 3, -1)[:, -1] &= (self.sites < 0)[:, None]
            s, a = np.nonzero(hit)
            d0 = xy0[s, 0] - axes[a]
            d0 -= np.round(d0 / box) * box
            out.append((s, np.full(len(s), -1), np.column_stack([d0, np.zeros(len(s))]),
                        rad + HEAD_SPHERE_RADIUS - np.sqrt(r2[s, a])))
        i, j, shift = self._pairs
        d = flat[i] - flat[j] + shift
        dist = np.sqrt(np.einsum("nk,nk->n", d, d))
        hit = dist < 2 * HEAD_SPHERE_RADIUS - 1e-9
        out.append((i[hit], j[hit], flat0[i[hit]] - flat0[j[hit]] + shift[hit], 2 * HEAD_SPHERE_RADIUS - dist[hit]))
        s = np.concatenate([o[0] for o in out])
        o = np.concatenate([o[1] for o in out])
        nrm = np.concatenate([o[2] for o in out]).reshape(-1, 3)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-12)[:, None]
        pivots = self.heads.pivots
        elbows = pivots + ELBOW * R0[:, :, 0]

        def arms(sphere, h):
            c = flat0[sphere]
            return np.stack([c - pivots[h], np.where(MOTOR_SPHERE[sphere % 3, None], c - elbows[h], 0.0)], axis=1)

        head, other = s // 3, np.where(o >= 0, o // 3, -1)
        other_arm = np.where((o >= 0)[:, None, None], arms(np.maximum(o, 0), np.maximum(other, 0)), 0.0)
        return head, other, arms(s, head), other_arm, nrm, np.concatenate([o[3] for o in out])

    def _sphere_pairs(self):
        """Head sphere pairs that can ever touch, with the period that brings them together.

        Hinges are fixed, so sphere ``a`` of one head and ``b`` of another can
        touch only if their hinges (in that periodic image) are closer than
        ``s_a + s_b + 2 r``.  Returns flat sphere indices ``i``, ``j`` and the
        (m, 3) period vectors to add to ``c_i - c_j``.
        """
        from scipy.spatial import cKDTree

        lt, piv = self.lattice, self.heads.pivots
        n = len(piv)
        reach = 2 * (HEAD_SPHERES[-1] + HEAD_SPHERE_RADIUS)
        if 2 * reach >= lt.box.min():
            raise DataError(f"the cell ({lt.box.min():.3g} nm across) is too small for heads {reach / 2:.3g} nm long",
                            field="d10")
        both = lt.to_box(piv)
        pq = cKDTree(both, boxsize=lt.box).query_pairs(reach, output_type="ndarray")
        hi, hj = pq[:, 0] % n, pq[:, 1] % n
        d = both[pq[:, 0]] - both[pq[:, 1]]
        d -= np.round(d / lt.box) * lt.box
        t = d - (piv[hi] - piv[hj])
        swap = hi > hj
        hi, hj = np.where(swap, hj, hi), np.where(swap, hi, hj)
        t = np.where(swap[:, None], -t, t)
        keep = hi != hj
        hi, hj, t = hi[keep], hj[keep], t[keep]
        _, first = np.unique(np.column_stack([hi, hj, np.round(t / 1e-3)]), axis=0, return_index=True)
        hi, hj, t = hi[first], hj[first], t[first]
        a, b = (x.reshape(-1) for x in np.meshgrid(np.arange(3), np.arange(3), indexing="ij"))
        hi, hj, t = np.repeat(hi, 9), np.repeat(hj, 9), np.repeat(t, 9, axis=0)
        a, b = np.tile(a, len(first)), np.tile(b, len(first))
        gap = np.linalg.norm(piv[hi] - piv[hj] + t, axis=1)
        sib = (self.heads.molecule[hi] == self.heads.molecule[hj]) & (a == 0) & (b == 0)
        keep = (gap < HEAD_SPHERES[a] + HEAD_SPHERES[b] + 2 * HEAD_SPHERE_RADIUS) & ~sib
        return 3 * hi[keep] + a[keep], 3 * hj[keep] + b[keep], t[keep]

    def _bounce(self, w_lever, w_elbow, passes=4):
        """Elastic collisions of the hinged heads: reflect the pseudo angular velocities of colliding heads.

        ``w_lever``, ``w_elbow`` (n, 3) are each head's rotation vectors of its
        two hinges for this step divided by ``dt`` (Strating's pseudo-velocity).  Each pass finds the heads whose
        trial frames overlap, takes each head's deepest contact, and applies
        :func:`hinged_collision` with the contact normal of the current frames
        (inertias: the hinges' drags; the hinges take up the momentum;
        filaments are immovable across their axes).  Returns the new pseudo
        angular velocities and the number of bounces (approaching contacts).

        Momentum is not a state variable of overdamped Brownian dynamics; as
        in Strating's hard-sphere method, each body's displacement over the
        step divided by ``dt`` stands for its velocity and its drag for its
        mass, so the collision is the inertial rigid-body collision of those
        pseudo-velocities.  The bounce is applied to the whole step (the
        contact normal is taken in the start frames), an error of order one
        step in where the bounce happens; moves still overlapping after the
        passes are refused by the caller.
        """
        dt, inv_i = self.p.dt, np.array([1.0 / self.drag, 1.0 / self.elbow_drag])
        w = np.stack([w_lever, w_elbow], axis=1)
        hits = 0
        for _ in range(passes):
            head, other, arm, oarm, nrm, depth = self._contacts(*turn_hinges(self.R, self.Q, w[:, 0], w[:, 1], dt),
                                                                self.R, self.Q)
            if not len(head):
                break
            # One collision per head per pass, the deepest first.
            used = np.zeros(len(w) + 1, bool)
            pick = []
            for k in np.argsort(-depth, kind="stable").tolist():
                a, b = head[k], other[k]
                if not (used[a] or used[b]):
                    used[a] = used[b] = True
                    used[-1] = False  # index -1: a filament, which takes any number of collisions
                    pick.append(k)
            k = np.array(pick, np.int64)
            a, b = head[k], other[k]
            wall = b < 0
            wa, wb = hinged_collision(
                w[a],
                np.where(wall[:, None, None], 0.0, w[b]),
                np.broadcast_to(inv_i, (len(k), 2)),
                np.where(wall[:, None], 0.0, inv_i),
                arm[k],
                oarm[k],
                nrm[k],
            )
            hits += int(np.any(wa != w[a], axis=(1, 2)).sum())
            w[a] = wa
            w[b[~wall]] = wb[~wall]
        return w[:, 0], w[:, 1], hits

    def _place(self, R):
        """Start frames free of overlaps: tilt overlapping heads further until they are free."""
        R = R.copy()
        bad = self.overlaps(R)
        for tries in range(1, 60):
            if not bad.any():
                return R
            idx = np.flatnonzero(bad)
            w = self.rng.normal(0, 0.15 * tries, (len(idx), 3))
            R[idx] = rotation_matrix(w) @ R[idx]
            bad = self.overlaps(R)
        raise DataError("cannot place the myosin heads without overlaps; the lattice is too tight", field="d10")

    # dynamics ---------------------------------------------------------------------

    def _free_site(self, tips, k=6):
        """Nearest free binding site within ``capture`` of each tip, or -1."""
        from scipy.spatial import cKDTree

        sites, _ = self.site_positions()
        m = len(sites)
        tree = cKDTree(self.lattice.to_box(sites), boxsize=self.lattice.box)
        d, idx = tree.query(self.lattice.wrap(tips), k=k, distance_upper_bound=self.p.capture)
        taken = np.zeros(m + 1, bool)
        taken[self.sites[self.sites >= 0]] = True
        taken[m] = True  # "no neighbour" comes back as index 2m
        site = np.where(idx >= 2 * m, m, idx % m)
        ok = ~taken[site]
        first = np.where(ok.any(axis=1), ok.argmax(axis=1), -1)
        return np.where(first >= 0, site[np.arange(len(tips)), np.maximum(first, 0)], -1)

    def _rest_frames(self):
        """Hinge rest frames: detached heads at the global pre/post-stroke tilts; a weakly bound head at the
        pose it bound in (binding strains nothing); after Pi release that pose swung by the power stroke."""
        R_eq = _tilt_frames(self.heads, self._rest_tilt(self.states))
        weak = self.states == AM_ADP_PI
        R_eq[weak] = self.R_bind[weak]
        strong = BOUND[self.states] & ~weak
        if strong.any():
            stroke = (self.p.pre_stroke - self.p.post_stroke) * self._stroke_axis[strong]
            R_eq[strong] = rotation_matrix(stroke) @ self.R_bind[strong]
        # The elbow rests straight, or, bound, at the bend it bound with.
        Q_eq = np.where(BOUND[self.states][:, None, None], self.Q_bind, np.eye(3))
        return R_eq, Q_eq

    def _tip_in_actin(self, idx):
        """(len(idx),) whether each head's tip sphere overlaps a thin filament, and the outward directions."""
        box = self.lattice.box[:2]
        thin = self._axes[0][0]
        tip = self.lattice.wrap(self.tips()[idx])[:, :2]
        d = tip[:, None] - thin[None]
        d -= np.round(d / box) * box
        r2 = np.einsum("nak,nak->na", d, d)
        k = np.argmin(r2, axis=1)
        inside = r2[np.arange(len(idx)), k] < (lat.THIN_RADIUS + HEAD_SPHERE_RADIUS) ** 2
        return inside, np.column_stack([d[np.arange(len(idx)), k], np.zeros(len(idx))])

    def _push_out(self, idx, step=0.05, tries=30):
        """Turn released heads whose tips pressed into the actin out of it about their hinges (the bounce).

        Returns the heads that could not be freed without an overlap; they are put back as they were.
        """
        R0 = self.R[idx].copy()
        todo = idx
        for _ in range(tries):
            inside, out = self._tip_in_actin(todo)
            todo, out = todo[inside], out[inside]
            if not len(todo):
                break
            u = self.tips()[todo] - self.heads.pivots[todo]
            w = np.cross(u, out)
            w *= step / np.maximum(np.linalg.norm(w, axis=1), 1e-12)[:, None]
            self.R[todo] = rotation_matrix(w) @ self.R[todo]
        stuck = idx[self.overlaps()[idx]]
        self.R[stuck] = R0[np.isin(idx, stuck)]
        return stuck

    def _binding_torques(self):
        """Torques of the binding springs about the hinges and elbows, and their pull on each thin filament."""
        n = len(self.heads)
        t1, t2, pull = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(6)
        bound = self.sites >= 0
        if bound.any():
            sites, fil = self.site_positions()
            tip = self.tips()[bound]
            d = self.lattice.min_image(sites[self.sites[bound]] - tip)
            f = self.p.bind_stiffness * d  # on the tip; the reaction pulls the filament
            t1[bound] = np.cross(tip - self.heads.pivots[bound], f)
            t2[bound] = np.cross(tip - (self.heads.pivots[bound] + ELBOW * self.R[bound, :, 0]), f)
            np.add.at(pull, fil[self.sites[bound]], -f[:, 2])
        return t1, t2, pull

    def step(self):
        """One Brownian step: cycle transitions, hinge and binding torques, collisions, sliding."""
        p, rng = self.p, self.rng
        n = len(self.heads)
        # Chemistry: binding needs a free site in reach of the tip (only primed, detached heads look).
        nearest = np.full(n, -1)
        look = np.flatnonzero(self.states == M_ADP_PI)
        if len(look):
            nearest[look] = self._free_site(self.tips()[look])
        reach = nearest >= 0
        new = cycle_step(self.states, self.P, rng, self.P_blocked, ~reach)
        # expm(Q dt) may chain steps (M.ATP -> M.ADP.Pi -> A.M.ADP.Pi): any head newly bound needs a site.
        binding = BOUND[new] & ~BOUND[self.states]
        new[binding & ~reach] = M_ADP_PI
        idx = np.flatnonzero(binding & reach)
        # Two heads reaching for one site: the first keeps it, the other stays detached.
        _, first = np.unique(nearest[idx], return_index=True)
        lose = np.setdiff1d(idx, idx[first])
        new[lose] = M_ADP_PI
        self.sites[idx[first]] = nearest[idx[first]]
        self.R_bind[idx[first]] = self.R[idx[first]]
        self.Q_bind[idx[first]] = self.Q[idx[first]]
        released = np.flatnonzero((self.sites >= 0) & ~BOUND[new])
        old_sites, old_states = self.sites[released], self.states[released]
        self.sites[~BOUND[new]] = -1
        self.states = new
        if len(released):
            stuck = self._push_out(released)
            # A tip that cannot get out of the actin without hitting something stays bound this step.
            keep = np.isin(released, stuck)
            self.sites[released[keep]] = old_sites[keep]
            self.states[released[keep]] = old_states[keep]
        # Mechanics.
        t1, t2, pull = self._binding_torques()
        w1, w2 = hinge_velocities(self.R, self.Q, *self._rest_frames(), p.hinge_stiffness, p.elbow_stiffness, self.drag,
                                  self.elbow_drag, p.dt, rng, self.kT, t1, t2)
        w1, w2, self.collisions = self._bounce(w1, w2)
        R, Q = turn_hinges(self.R, self.Q, w1, w2, p.dt)
        moved = np.ones(n, bool)
        while True:  # moves the bounces could not clear are refused; the old frames overlap nothing
            bad = self.overlaps(R, Q) & moved
            if not bad.any():
                break
            R[bad], Q[bad] = self.R[bad], self.Q[bad]
            moved[bad] = False
        self.rejected = int(n - moved.sum())
        self.R, self.Q = R, Q
        noise = np.sqrt(2 * self.kT * p.dt / p.filament_drag) * rng.standard_normal(6)
        self.slide = self.slide + (pull - p.load) * p.dt / p.filament_drag + noise
        self.time += p.dt

    def frame(self):
        return Frame(
            self.R.copy(), self.states.copy(), self.sites.copy(), self.slide.copy(), self.time, self.R @ self.Q
        )

    def run(self, frames):
        """Simulate ``frames`` film frames; returns the list of :class:`Frame` (the first is the start)."""
        frames = int(frames)
        if frames < 0:
            raise DataError(f"must be >= 0, got {frames}", field="frames")
        out = [self.frame()]
        for _ in range(frames - 1):
            for _ in range(self.p.steps_per_frame):
                self.step()
            out.append(self.frame())
        return out[:frames] if frames else []

def with_params(**kw):
    """:class:`Params` with some fields changed (for the CLI and the add-on)."""
    return replace(Params(), **kw)
