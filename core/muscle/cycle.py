"""The cross-bridge cycle (Lymn-Taylor) as a Markov chain over five states, advanced exactly per step.

M.ATP (detached, lever down) -> M.ADP.Pi (hydrolysis and recovery stroke,
lever up) -> A.M.ADP.Pi (weak binding) -> A.M.ADP (Pi release, power stroke)
-> A.M (ADP release, rigor) -> M.ATP (ATP binding, detachment).  Each step
uses the exact transition matrix ``expm(Q dt)``, so the occupancies converge
to ``Q``'s steady state for any step.

References
----------
.. [1] R. W. Lymn and E. W. Taylor, "Mechanism of adenosine triphosphate
   hydrolysis by actomyosin", Biochemistry 10, 4617 (1971).
.. [2] J. Howard, "Mechanics of Motor Proteins and the Cytoskeleton", Sinauer (2001).
"""

import numpy as np

from ..errors import DataError

# Cycle states.
M_ATP, M_ADP_PI, AM_ADP_PI, AM_ADP, AM = range(5)
STATE_NAMES = ("M.ATP", "M.ADP.Pi", "A.M.ADP.Pi", "A.M.ADP", "A.M")

BOUND = np.array([False, False, True, True, True])

RATES = {
    (M_ATP, M_ADP_PI): 100.0,  # hydrolysis + recovery stroke
    (M_ADP_PI, M_ATP): 10.0,  # its reversal (hydrolysis equilibrium constant about 10)
    (M_ADP_PI, AM_ADP_PI): 200.0,  # weak binding (when a site is in reach)
    (AM_ADP_PI, M_ADP_PI): 100.0,  # weak detachment
    (AM_ADP_PI, AM_ADP): 50.0,  # Pi release and power stroke (rate-limiting)
    (AM_ADP, AM): 500.0,  # ADP release
    (AM, M_ATP): 1000.0,  # ATP binding and detachment (about 2 mM ATP)
}
"""Rate constants in 1/s for fast skeletal myosin II, representative values after Howard (2001)."""


def cycle_generator(rates=None):
    """Generator matrix ``Q`` (5, 5) in 1/s of the cycle (rows sum to zero)."""
    rates = RATES if rates is None else rates
    q = np.zeros((5, 5))
    for (a, b), k in rates.items():
        if not (np.isfinite(k) and k >= 0):
            raise DataError(f"rate {STATE_NAMES[a]} -> {STATE_NAMES[b]} must be >= 0 1/s, got {k}", field="rates")
        q[a, b] = k
    q[np.diag_indices(5)] = -q.sum(axis=1)
    return q

def steady_state(q):
    """Stationary occupancies ``p`` with ``p Q = 0``, ``sum p = 1``."""
    q = np.asarray(q, np.float64)
    a = np.vstack([q.T, np.ones(len(q))])
    b = np.zeros(len(q) + 1)
    b[-1] = 1
    return np.linalg.lstsq(a, b, rcond=None)[0]

def transition_matrix(q, dt):
    """Exact one-step transition probabilities ``expm(Q dt)`` (dt in seconds)."""
    from scipy.linalg import expm

    p = expm(np.asarray(q, np.float64) * float(dt))
    p = np.clip(p, 0, None)
    return p / p.sum(axis=1, keepdims=True)

def cycle_step(states, p, rng, p_blocked=None, blocked=None):
    """Advance every head's state one step with transition matrix ``p``.

    Heads with ``blocked`` True (no actin site in reach) use ``p_blocked`` instead.
    """
    s = np.asarray(states)
    cum = np.cumsum(p, axis=1)
    cum[:, -1] = 1.0  # no rounding gap above the last state
    cum = cum[s]
    if blocked is not None and p_blocked is not None:
        cb = np.cumsum(p_blocked, axis=1)
        cb[:, -1] = 1.0
        cum = np.where(blocked[:, None], cb[s], cum)
    u = rng.random(len(s))[:, None]
    return (u >= cum).sum(axis=1)
