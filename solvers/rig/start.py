"""Where a rig's Gauss-Newton solve starts: every frame solved alone, linearly, along each control's own curve.

The pipeline's linear solve sees one column per control: its effect at the end of its range that
moves the points most. A control whose effect is far from proportional to it (a smoothstep or pow
driver, an in-between that comes and goes half way, a joystick whose other side moves other shapes)
is then described badly, the linear solve makes up for it with other controls, and the Gauss-Newton
steps start in the wrong valley. Here such a control has a column per quarter of each side of its
range (the increment of its effect over that quarter, used between 0 and 1), as four shape keys
would be, and starts at the quarters it used; controls close to proportional keep their column.
"""

import numpy as np

from ..engine import solve_bounded

#: Quarters of each side; a control is described by them when its effect at one of them differs
#: from the proportional one by more than ``CURVED`` of its effect at the end.
QUARTERS, CURVED = 4, 0.1


def curved_start(model, deltas, *, regularisation, lower, upper, locks=None):
    """Offsets (F, C) to start ``model`` (a normalised ``RigModel``) from on ``deltas`` (F, M, D), or
    None when every control is close to proportional (the linear solve's start is as good).
    ``lower``, ``upper`` (C,) the bounds; ``locks`` (C,) or (F, C) held values (NaN: free)."""
    F, M, D = deltas.shape
    C = model.n_controls
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    secant, ends = model.secant(), model.secant_ends()
    columns, owner, lo, hi = [], [], [], []  # owner: (control, step of offset per unit weight)
    for i in range(C):
        sides = [(t, np.arange(1, QUARTERS + 1) / QUARTERS * t) for t in (upper[i], lower[i]) if t != 0]
        curved = False
        for end, knots in sides:
            effect = model.along(i, knots)
            straight = knots[:, None, None] / end * effect[-1]
            curved |= np.abs(effect - straight).max() > CURVED * max(np.abs(effect[-1]).max(), 1e-300)
        if not curved:
            columns.append(secant[i])
            owner.append((i, 1.0))
            lo.append(lower[i])
            hi.append(upper[i])
            continue
        for end, knots in sides:
            effect = model.along(i, np.r_[0.0, knots])
            for k in range(QUARTERS):
                columns.append(effect[k + 1] - effect[k])
                owner.append((i, end / QUARTERS))
                lo.append(0.0)
                hi.append(1.0)
    if len(columns) == C:
        return None
    owner = np.array(owner)
    which, step = owner[:, 0].astype(int), owner[:, 1]
    A = np.array(columns).reshape(len(columns), M * D).T
    held = None
    if locks is not None:  # a held control holds its one column, or its quarters at 0
        lk = np.broadcast_to(np.asarray(locks, dtype=np.float64), (F, C) if np.ndim(locks) == 2 else (C,))
        held = np.where(np.isnan(lk[..., which]), np.nan, np.where(step == 1.0, lk[..., which], 0.0))
    res = solve_bounded(A, deltas.reshape(F, M * D), dims=D, lower=np.array(lo), upper=np.array(hi),
                        regularisation=regularisation, relative=True, locks=held)
    w = np.nan_to_num(np.asarray(res.weights, dtype=np.float64))
    up = np.zeros((F, C))
    down = np.zeros((F, C))
    for j, (i, s) in enumerate(zip(which, step)):
        (up if s > 0 else down)[:, i] += w[:, j] * s
    start = np.where(np.abs(up) >= np.abs(down), up, down)  # a control is on one side of rest
    if locks is not None:
        start = np.where(np.isnan(lk), start, lk)
    return np.clip(start, lower, upper)
