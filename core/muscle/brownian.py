"""Brownian dynamics of the cross-bridges: heads hinged to the thick filaments, driven through the cycle.

Units: nanometres, microseconds, piconewtons (so energies are pN nm; kT at
300 K is 4.142 pN nm and water's viscosity 1 mPa s is 1e-3 pN us / nm^2).

* **Brownian impulses** (overdamped Langevin, Euler-Maruyama): a body of
  translational drag ``g`` moves ``F / g dt + sqrt(2 kT / g dt) xi`` per step
  and turns by the rotation vector ``tau / g_r dt + sqrt(2 kT / g_r dt) xi``
  (Stokes drags ``6 pi eta r`` and ``8 pi eta r^3``; a head is a chain of
  spheres turning about its hinge, ``sum 6 pi eta r s^2 + 8 pi eta r^3``).
* **Two hinges per head**: the lever turns about its hinge on the thick
  filament (spring :attr:`Params.hinge_stiffness`, drag of the whole head)
  and the motor domain about the elbow at the lever's end (spring
  :attr:`Params.elbow_stiffness`, drag of the motor domain's spheres about
  the elbow); the two springs are independent, so each hinge samples its own
  Boltzmann distribution (:func:`hinge_velocities`, :func:`turn_hinges`).
  Euler-Maruyama on a spring of stiffness ``k`` is stable only for
  ``k dt / g < 2`` and inflates the sampled variance by ``1 / (1 - k dt / 2g)``;
  :func:`check_step` refuses ``k dt / g > MAX_RELAXATION``.
* **Elastic collisions**: free hard spheres move, and pairs that would
  overlap exchange their pseudo-velocities ``dx / dt`` elastically at contact
  (Strating 1999), conserving momentum and kinetic energy.  Heads, which turn
  about their hinges, bounce the same way: a head whose move would overlap an
  actin filament, a thick-filament backbone or another head collides as a
  chain of hinged rigid links (:func:`hinged_collision`, the hinged case of
  :func:`rigid_collision`; pseudo angular velocities ``dw / dt``, inertias =
  the hinges' rotational drags, the hinges taking up the linear momentum,
  filaments immovable across their axes).
  The few moves a bounce cannot clear within a step are refused, so no two
  bodies ever overlap.
* **The cross-bridge cycle** (Lymn-Taylor) is a Markov chain over
  M.ATP (detached, lever down) -> M.ADP.Pi (hydrolysis and recovery stroke,
  lever up) -> A.M.ADP.Pi (weak binding) -> A.M.ADP (Pi release, power
  stroke) -> A.M (ADP release, rigor) -> M.ATP (ATP binding, detachment).
  Each step advances it with the exact transition matrix ``expm(Q dt)``, so
  its occupancies converge to ``Q``'s steady state for any step.  Binding
  needs a free actin site within :attr:`Params.capture` of the head's tip.
* **Animation forces** (the paper's "fake" forces): the state sets the
  lever hinge's rest pose (detached: lever up after the recovery stroke, down
  after detachment; weakly bound: the pose it bound in, so binding strains
  nothing; after Pi release: that pose swung by the power stroke,
  ``pre_stroke - post_stroke`` = 80 degrees, tip towards the M line at -z)
  and the elbow's (straight when detached, the bend it bound with when
  bound), and a bound tip is held to its actin site by a spring; the thin filaments
  slide under the reaction of those springs (contraction towards -z).
* **Time scale**: the Brownian motion runs at its real speed (one film frame
  is :attr:`Params.frame_time` = 0.1 us of it) while the chemistry runs
  :attr:`Params.speedup` = 2e4 times faster than in muscle (a cycle of about
  40 ms then takes about 20 frames), as the original film accelerated the
  cycle with animation forces.

The parts: :mod:`.dynamics` (drags, steps, rotations), :mod:`.collisions`
(elastic bounces of spheres and hinged heads), :mod:`.cycle` (the Markov
chain) and :mod:`.crossbridges` (the heads in the lattice); their public names
are all importable from here.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (random
   Brownian impulse forces, elastic bounces, fake animation forces).
.. [2] N. Max, N. Hayashi and T. Wakabayashi, "Computer simulation and
   animation of muscle cross-bridge motion", J. Visualization and Computer
   Animation 1(1), 9-14 (1990).
.. [3] D. L. Ermak and J. A. McCammon, "Brownian dynamics with hydrodynamic
   interactions", J. Chem. Phys. 69, 1352 (1978).
.. [4] P. Strating, "Brownian dynamics simulation of a hard-sphere
   suspension", Phys. Rev. E 59, 2175 (1999) (elastic collisions of
   pseudo-velocities).
.. [5] R. W. Lymn and E. W. Taylor, "Mechanism of adenosine triphosphate
   hydrolysis by actomyosin", Biochemistry 10, 4617-4624 (1971).
.. [6] J. Howard, "Mechanics of Motor Proteins and the Cytoskeleton",
   Sinauer 2001, chapters 2, 13-14 (drag coefficients, myosin II rates).
"""

from .collisions import elastic_collision, hinge_velocities, hinged_collision, rigid_collision, sphere_step, turn_hinges
from .crossbridges import (
    ELBOW,
    HEAD_SPHERE_RADIUS,
    HEAD_SPHERES,
    MAX_BOUND_PER_FILAMENT,
    MOTOR_SPHERE,
    TIP_REACH,
    CrossBridges,
    Frame,
    Params,
    with_params,
)
from .cycle import (
    AM,
    AM_ADP,
    AM_ADP_PI,
    BOUND,
    M_ADP_PI,
    M_ATP,
    RATES,
    STATE_NAMES,
    cycle_generator,
    cycle_step,
    steady_state,
    transition_matrix,
)
from .dynamics import (
           KT_300,
    MAX_RELAXATION,
    WATER_VISCOSITY,
    brownian_step,
    check_step,
    rotation_matrix,
    rotation_vector,
    rotational_drag,
    translational_drag,
)

__all__ = ["AM", "AM_ADP", "AM_ADP_PI", "BOUND", "ELBOW", "HEAD_SPHERES", "HEAD_SPHERE_RADIUS", "KT_300",
           "MAX_BOUND_PER_FILAMENT", "MAX_RELAXATION", "MOTOR_SPHERE", "M_ADP_PI", "M_ATP", "RATES", "STATE_NAMES",
           "TIP_REACH", "WATER_VISCOSITY", "CrossBridges", "Frame", "Params", "brownian_step", "check_step",
           "cycle_generator", "cycle_step", "elastic_collision", "hinge_velocities", "hinged_collision",
           "rigid_collision", "rotation_matrix", "rotation_vector", "rotational_drag", "sphere_step", "steady_state",
           "transition_matrix", "translational_drag", "turn_hinges", "with_params"]
