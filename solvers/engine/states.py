"""The active-set vocabulary shared by the engine's kernels: each variable is free or fixed at its
lower bound, its upper bound or the L1 kink 0, read from the proximal point
``v = w - s grad``: ``w = clip(soft(v, s lam), lo, hi)``."""

import numpy as np

#: State codes (int8): free, at the lower bound, at the upper bound, at the L1 kink 0.
FREE, LO, HI, ZERO = 0, 1, 2, 3


def classify(v, step, lo, hi, lam):
    """State of each variable from the proximal point v (see module docstring); ``step`` per frame
    (F,) or per variable (F, K)."""
    state = np.full(v.shape, FREE, dtype=np.int8)
    if not lam.any():  # no L1: the shrunk point is v itself (the same states, fewer passes)
        t = v
        state[v == 0] = ZERO
    else:
        tau = (step if step.ndim == 2 else step[:, None]) * lam
        t = np.sign(v) * np.maximum(np.abs(v) - tau, 0.0)
        state[np.abs(v) <= tau] = ZERO
    state[t >= hi] = HI
    state[t <= lo] = LO
    sign = np.sign(v)
    return state, sign


def start_state(w, lo, hi, lam):
    """(state, sign) of the weights ``w`` (e.g. an earlier solve's), read as an active set."""
    state = np.full(w.shape, FREE, dtype=np.int8)
    state[(w == 0) & (lam > 0) & (lo < 0) & (hi > 0)] = ZERO
    state[w <= lo] = LO
    state[w >= hi] = HI
    return state, np.sign(w)


def fixed_values(state, lo, hi):
    """The value each fixed variable is held at (its bound, or 0 at the kink; 0 for free ones)."""
    return np.where(state == LO, lo, np.where(state == HI, hi, 0.0))
