"""Exact solve of one frame's box/L1 QP: the per-frame kernel's fallback for the few frames whose
active set does not settle (plain numpy: per-frame solves need no scipy, which Blender does not ship)."""

import numpy as np


def exact_frame(H, g, lo, hi, lam, sign0=None):
    """Exact solve of one frame's box/L1 QP.

    Fixed variables (lo == hi) are eliminated; shapes whose range excludes 0 carry their L1 term as
    a linear term; shapes whose range straddles 0 (with lam > 0) are solved orthant by orthant with
    ``box_qp``, flipping the sign of any variable stuck at 0 whose subgradient condition fails. Each flip
    strictly lowers the objective, so the search ends.
    """
    K = g.size
    w = np.where(lo == hi, lo, 0.0).astype(float)
    fr = np.flatnonzero(lo < hi)
    if fr.size == 0:
        return w
    fx = np.flatnonzero(lo == hi)
    Hr = H[np.ix_(fr, fr)]
    gr = g[fr] - H[np.ix_(fr, fx)] @ w[fx]
    l, h, lm = lo[fr], hi[fr], lam[fr]
    straddle = (l < 0) & (h > 0) & (lm > 0)
    s = np.where(l >= 0, 1.0, np.where(h <= 0, -1.0, 0.0))
    if sign0 is not None:
        s0 = np.sign(sign0[fr])
        s[straddle] = np.where(s0[straddle] < 0, -1.0, 1.0)
    else:
        s[straddle] = 1.0
    x = None
    for _ in range(4 * K + 8):
        lb = np.where(straddle & (s > 0), 0.0, l)
        ub = np.where(straddle & (s < 0), 0.0, h)
        x = box_qp(Hr, gr - lm * s, lb, ub, x)
        grad = Hr @ x - gr
        at0 = straddle & (np.abs(x) <= 1e-14)
        flip = at0 & (((s > 0) & (grad > lm)) | ((s < 0) & (grad < -lm)))
        if not flip.any():
            break
        s[flip] = -s[flip]
    w[fr] = x
    return w


def box_qp(H, q, lb, ub, x0=None):
    """Exact minimiser of ``1/2 x'Hx - q'x`` on ``lb <= x <= ub`` (H SPD; bounds may be infinite).

    Primal active set in the manner of Lawson-Hanson / BVLS: keep a feasible point and a set of
    variables held at a bound; solve for the others; if that point leaves the box, step to the
    first bound hit and hold that variable too; otherwise release the held variable whose
    multiplier has the wrong sign (the worst one), or stop when none has. Each release strictly
    lowers the objective and each step holds one more variable, so it ends; a generous iteration
    cap guards against rounding-induced cycling.
    """
    n = q.size
    x = np.clip(np.zeros(n) if x0 is None else x0, lb, ub)
    held = (x <= lb) | (x >= ub)
    movable = lb < ub
    scale = max(float(np.abs(np.diag(H)).max(initial=0.0)), 1e-300)
    tol = 1e-13 * scale * max(1.0, float(np.abs(x).max(initial=0.0)))
    for _ in range(20 * n + 40):
        fr = ~held
        z = x.copy()
        if fr.any():
            z[fr] = np.linalg.solve(H[np.ix_(fr, fr)], q[fr] - H[np.ix_(fr, held)] @ x[held])
        out = fr & ((z < lb) | (z > ub))
        if not out.any():
            x = z
            grad = H @ x - q
            wrong = np.where(held & movable & (x <= lb), -grad, 0.0)  # wants to rise off lb
            wrong = np.maximum(wrong, np.where(held & movable & (x >= ub), grad, 0.0))
            k = int(np.argmax(wrong))
            if wrong[k] <= tol:
                return x
            held[k] = False
            continue
        d = z - x
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(out & (z < lb), (lb - x) / d, np.where(out & (z > ub), (ub - x) / d, np.inf))
        k = int(np.argmin(t))
        x = x + np.clip(t[k], 0.0, 1.0) * d
        x[k] = lb[k] if z[k] < lb[k] else ub[k]
        x = np.clip(x, lb, ub)
        held[k] = True
    return x
