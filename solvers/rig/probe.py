"""Probing a rig: which control poses to evaluate, and the ``RigModel`` fitted from what the rig gave.

Blender evaluates (``facecap_addon.rig.rig_eval``); this module only plans and fits. ``probe_rig`` takes
``evaluate(offsets (N, C)) -> deltas (N, M, D)`` and

1. moves each control alone to 1/4, 1/2, 3/4 and all of its span on each side it has (its linear
   and own-curvature terms; the *checked step*: the cubic through rest and the 1/4, 1/2 and full
   probes must predict the 3/4 probe within ``step_tol``, else the control is reported as uneven,
   its response is not a cubic there, e.g. an in-between or a clamp, and the refinement through
   the rig matters),
   A control with two sides whose probes no single cubic through rest explains within
   ``step_tol`` (a joystick moving one shape up and another down) is *split*: a cubic per side,
2. tests every candidate pair (the rig's product drivers, plus, with ``find_pairs``, every two
   controls that move a common bound point) at the corner of their spans (each side of a split
   control: a quadrant each): the pair gets a term when the mixed difference
   x(a, b) - x(a, 0) - x(0, b) is above ``pair_tol`` of the larger one alone,
3. adds random poses with a few controls on at once, fits the model on everything and reports its
   error on a held-out fifth of them.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from .fit import fit_model

STEPS = (0.25, 0.5, 0.75, 1.0)
#: A control's support: the points it moves by at least this share of its own largest reach.
SUPPORT = 0.05
#: The width (share of its span) over which a split control's two halves blend about rest.
KINK = 0.02


@dataclass(frozen=True)
class ProbeReport:
    """What probing found: probes evaluated, pairs with a term (a split control's name ends in + or
    - for the half the term reads), the fit's RMS at the probes and on held-out random poses (units
    of the bound points), controls whose checked step failed, controls that move no bound point,
    and controls modelled per side."""

    probes: int
    pairs: tuple
    fit_rms: float
    holdout_rms: float
    uneven: tuple
    unseen: tuple
    split: tuple = ()

    def as_dict(self):
        return {"probes": self.probes, "pairs": [list(p) for p in self.pairs], "fit_rms": self.fit_rms,
                "holdout_rms": self.holdout_rms, "uneven_controls": list(self.uneven), "unseen_controls": list(self.unseen),
                "split_controls": list(self.split)}


def _axis_offsets(lower, upper):
    """(rows, control index, signed fraction) of the single-control probes."""
    rows, which = [], []
    for i, (lo, hi) in enumerate(zip(lower, upper)):
        for side in (hi, lo):
            if side == 0:
                continue
            for t in STEPS:
                u = np.zeros(len(lower))
                u[i] = t * side
                rows.append(u)
                which.append((i, t * side))
    return np.array(rows).reshape(-1, len(lower)), which


def probe_rig(evaluate, control_names, marker_names, neutral, *, progress=None, **options):
    """Probe a rig through ``evaluate`` and fit its ``RigModel``.

    Parameters
    ----------
    evaluate : callable, offsets (N, C) from rest -> deltas (N, M, D) of the bound points from ``neutral``
    rest, lower, upper : (C,) control rest values and limits (raw values)
    pairs : control index pairs known to interact (e.g. read from the rig's driver expressions)
    find_pairs : also test every two controls that move a common bound point
    n_random, active : random poses and how many controls each moves at once
    progress : callable(done, total) -> bool, False cancels (FacecapError "cancelled")
    the other options: those of ``probe_rig_steps``

    Returns
    -------
    (RigModel, ProbeReport)
    """
    steps = probe_rig_steps(evaluate, control_names, marker_names, neutral, **options)
    return run_steps(steps, progress, lambda done, planned: FacecapError("rig probing cancelled"))


def run_steps(steps, progress, cancelled):
    """What the generator ``steps`` (yielding (done, planned), returning its result) returns, with
    ``progress(done, planned) -> bool`` told after each step: False closes it and raises
    ``cancelled(done, planned)``."""
    while True:
        try:
            done, planned = next(steps)
        except StopIteration as stop:
            return stop.value
        if progress is not None and progress(done, planned) is False:
            steps.close()
            raise cancelled(done, planned)


def probe_rig_steps(evaluate, control_names, marker_names, neutral, *, rest, lower, upper, pairs=(),
                    find_pairs=True, n_random=1000, active=4, seed=0, pair_tol=0.02, step_tol=0.02, chunk=None):
    """``probe_rig`` as a generator: yields (probes done, probes planned) after every ``chunk``
    poses evaluated (default: each batch at once), so a caller can show progress and stop between
    two chunks (``close()``); returns (RigModel, ProbeReport)."""
    rest, lower, upper = (np.asarray(a, dtype=np.float64) for a in (rest, lower, upper))
    C = len(control_names)
    lo, hi = lower - rest, upper - rest
    if np.any(hi - lo <= 0):
        bad = [n for n, a, b in zip(control_names, lo, hi) if b - a <= 0]
        raise FacecapError(f"rig controls {bad[:5]} have an empty range (lower >= upper); check their limits")
    rng = np.random.default_rng(seed)
    total = [0]

    def run(offsets):
        size = chunk or max(len(offsets), 1)
        parts = []
        for a in range(0, len(offsets), size):
            parts.append(evaluate(offsets[a:a + size]))
            total[0] += len(parts[-1])
            yield total[0], planned
        return np.concatenate(parts) if parts else evaluate(offsets)

    axis, which = _axis_offsets(lo, hi)
    planned = len(axis) + n_random + C * 4
    axis_d = yield from run(axis)
    size = np.linalg.norm(axis_d, axis=2)  # (N, M)
    reach = np.zeros((C, len(marker_names)))
    for row, (i, _) in enumerate(which):
        reach[i] = np.maximum(reach[i], size[row])
    seen = reach > 1e-3 * max(reach.max(), 1e-300)
    unseen = tuple(control_names[i] for i in range(C) if not seen[i].any())
    # where a control acts: the points it moves by 5 % of its own largest reach (its fringe of
    # skinning weights would make nearly every two face controls a candidate pair)
    moved = seen & (reach >= SUPPORT * reach.max(axis=1, keepdims=True))
    uneven = _uneven(axis_d, which, C, step_tol, control_names)

    span = np.maximum(hi, -lo)
    kinked = _kinked(axis_d, which, C, step_tol)
    kink = np.where(kinked, KINK * span, 0.0)

    candidates = {(min(a, b), max(a, b)) for a, b in pairs if a != b}
    if find_pairs:
        overlap = moved.astype(np.float64) @ moved.T.astype(np.float64)
        candidates |= {(a, b) for a in range(C) for b in range(a + 1, C) if overlap[a, b] > 0}
    far = np.where(hi >= -lo, hi, lo)
    end = {1: hi, -1: lo, 0: far}
    quadrants = [(a, b, sa, sb) for a, b in sorted(candidates)
                 for sa in ((1, -1) if kinked[a] else (0,)) for sb in ((1, -1) if kinked[b] else (0,))]
    planned += len(quadrants)
    kept = []
    if quadrants:
        singles = {(i, t): axis_d[row] for row, (i, t) in enumerate(which)}
        corner = np.zeros((len(quadrants), C))
        for q, (a, b, sa, sb) in enumerate(quadrants):
            corner[q, a], corner[q, b] = end[sa][a], end[sb][b]
        corner_d = yield from run(corner)
        for q, (a, b, sa, sb) in enumerate(quadrants):
            one, two = singles[(a, end[sa][a])], singles[(b, end[sb][b])]
            mixed = np.abs(corner_d[q] - one - two).max()
            alone = max(np.abs(one).max(), np.abs(two).max(), 1e-300)
            if mixed > pair_tol * alone:
                kept.append((a, b, sa, sb))
    else:
        corner, corner_d = np.zeros((0, C)), np.zeros((0,) + axis_d.shape[1:])

    rand = np.zeros((n_random, C))
    for row in rand:
        on = rng.choice(C, size=min(active, C), replace=False)
        row[on] = rng.uniform(lo[on], hi[on])
    rand_d = (yield from run(rand)) if n_random else np.zeros((0,) + axis_d.shape[1:])
    held = np.zeros(n_random, dtype=bool)
    held[: n_random // 5] = True
    fit_u = np.vstack([axis, corner, rand[~held]])
    fit_d = np.concatenate([axis_d, corner_d, rand_d[~held]])
    model, rms = fit_model(control_names, marker_names, neutral, fit_u, fit_d, pairs=[q[:2] for q in kept],
                           pair_sides=[q[2:] for q in kept], kink=kink, rest=rest, lower=lower, upper=upper)
    holdout = float(np.sqrt(np.mean((model.deltas(rand[held]) - rand_d[held]) ** 2))) if held.any() else float("nan")
    sign = {0: "", 1: "+", -1: "-"}
    report = ProbeReport(total[0], tuple((control_names[a] + sign[sa], control_names[b] + sign[sb])
                                         for a, b, sa, sb in kept), rms, holdout, uneven, unseen,
                         tuple(n for n, k in zip(control_names, kinked) if k))
    return model, report


def _uneven(axis_d, which, C, tol, names):
    """Controls whose response is not a cubic (the checked step): on each side, the cubic through
    rest and the 1/4, 1/2 and full-span probes must predict the 3/4 probe within ``tol`` of its size."""
    at = {(i, t): axis_d[row] for row, (i, t) in enumerate(which)}
    out = []
    for i in range(C):
        for sign in (1.0, -1.0):
            side = sorted((t for (j, t) in at if j == i and t * sign > 0), key=abs)
            if len(side) < 4:
                continue
            ts = np.array([side[0], side[1], side[3]])
            V = np.stack([ts, ts ** 2, ts ** 3], axis=1)  # x(t) = a t + b t^2 + c t^3
            coef = np.linalg.solve(V, np.stack([at[(i, t)].ravel() for t in ts]))
            t = side[2]
            predicted = (coef.T @ np.array([t, t * t, t ** 3])).reshape(at[(i, t)].shape)
            ref = np.abs(at[(i, side[3])]).max()
            if ref > 0 and np.abs(predicted - at[(i, t)]).max() > tol * ref:
                out.append(names[i])
                break
    return tuple(out)


def _kinked(axis_d, which, C, tol):
    """(C,) bool: the controls with two sides whose probes no single cubic through rest explains
    within ``tol`` of their largest displacement (their sides act differently: a cubic each)."""
    rows = {}
    for row, (i, t) in enumerate(which):
        rows.setdefault(i, []).append((t, row))
    out = np.zeros(C, dtype=bool)
    for i, items in rows.items():
        ts = np.array([t for t, _ in items])
        if not (ts > 0).any() or not (ts < 0).any():
            continue
        Y = np.stack([axis_d[r].ravel() for _, r in items])
        V = np.stack([ts, ts ** 2, ts ** 3], axis=1)
        coef, *_ = np.linalg.lstsq(V, Y, rcond=None)
        ref = np.abs(Y).max()
        out[i] = ref > 0 and np.abs(V @ coef - Y).max() > tol * ref
    return out
