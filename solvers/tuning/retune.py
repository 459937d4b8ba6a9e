"""The animator feedback loop: re-tune the actor calibration library from a few corrected frames.

Sony's "multidimensional tuning" (``shared/research/retargeting-course-2006.md`` section 3): after
a solve, an animator corrects the pose weights on a handful of frames; the library is re-optimised so
that a re-solve hits those frames *and* improves the others.

Why not the plain closed form
-----------------------------
``A' = argmin sum_t ||d_t - A' w*_t||^2 + mu ||A' - A||^2 = (D W*^T + mu A)(W* W*^T + mu I)^-1``
(``closed_form_update``) moves every column of the library in every direction the 8-odd corrected
frames leave undetermined: it fits the corrected frames but puts the misfit into poses the animator
never touched. Measured (``tests/core/test_tuning.py``, 4 of 52 poses calibrated at 40%, 8
corrected frames, after re-solving the take): mu = 0.1 -> corrected RMSE 0.128 -> 0.066, held-out
0.070 -> 0.085 (worse); mu = 1 -> 0.080 / 0.076; mu = 10 -> 0.107 / 0.065. ``retune``: corrected
0.026, held-out 0.026 (-63%), recovered gains 2.43-2.67 (truth 2.5).

The method (``retune``)
-----------------------
1. **What the corrections reveal.** Per pose k, the change c_tk = w*_tk - w_tk (corrected minus
   solved) over the corrected frames where the animator set that pose. Its *size* (RMS) and its
   *consistency* (|sum c| / sum |c|, 1 = always the same direction) say whether the animator
   deliberately moved the pose. Poses with size >= ``min_change`` and consistency >=
   ``min_consistency`` are *implicated*; only their columns of the library may change.
2. **Per-pose gain.** A pose calibrated at 40% strength is explained by one number: its marker
   pattern scaled by a gain g_k. Model d_t = sum_k g_k w*_tk a_k (g = 1 off the implicated set),
   linear in g: a tiny least-squares problem over all observed coordinates of the corrected frames,
   with a weak ridge pulling g to 1. g is clipped to [``gain_bounds``]. A wider candidate set adds
   every pose the animator set to >= ``active_weight`` on a corrected frame: a pose calibrated too
   weak can sit at its upper bound in the solve, so its *weight* barely changes; only the markers
   show it.
3. **Small per-marker correction with a strong prior.** On the implicated columns only,
   A'_I = g A_I + E, minimising sum_t ||d_t - A' w*_t||^2 + mu ||E||^2 (per coordinate, missing
   markers skipped). mu is in "frames at full weight" (a pose seen at weight 1 on mu frames weighs
   as much as the prior).
4. **Model choice by leave-one-frame-out.** Candidates, from simplest: no change; gains of the
   implicated poses; gains of all exercised poses; gains + E for each mu of ``mu_grid`` (largest
   first). For each candidate and each corrected frame t: fit on the other corrected frames,
   re-solve frame t (per-frame) with the candidate library, compare with the animator's weights.
   A more complex candidate is chosen only if it lowers the LOO error by
   ``min_improvement`` (relative) over the best simpler one. A fixed ``mu`` skips the search over mu
   (gains are still fitted; ``mu=inf`` = gains only) but is still compared with "no change"
   unless ``force=True``.
5. **Verify.** The whole take is re-solved with the new library; if the error on the corrected
   frames is not lower than before, the original library is kept (reported in ``notes``).

No harm: when the corrections agree with the library (the current solve, or the truth on a right
library) the leave-one-out keeps the library (other frames move 0%); a forced refit
(``force=True``) moved them 0.6% (held-out RMSE 0.0207 -> 0.0208).

The input library is never modified; the result carries a new ``Basis`` and a content-hashed version
name so both can be stored side by side. Weights and corrections are in the actor-pose space of the
library (for a one-to-one mapping, the character's shapes); mapping character corrections back
through a many-to-many table is the caller's job.

``fit_gain_offset`` is the one-click alternative: least squares per shape of corrected = gain *
solved + offset.
"""

import hashlib
from dataclasses import dataclass, field

import numpy as np

from ..character.basis import Basis
from ..engine import DEFAULT_SMOOTHING, solve_bounded
from ..errors import FacecapError
from ..options import default

#: mu candidates (frames at full weight) for the leave-one-frame-out search, simplest (largest) first
MU_GRID = (30.0, 10.0, 3.0, 1.0, 0.3)


@dataclass(frozen=True, eq=False)
class TuneResult:
    """Outcome of ``retune``.

    library : Basis, the new library (the input one if nothing changed)
    weights : (F, K) re-solved weights of the whole take with ``library``
    version : str, name of the new library version (content-hashed; equal to ``parent`` if unchanged)
    frames : (T,) corrected frame indices
    corrected_rmse_before, corrected_rmse_after : RMS of (solved - corrected) over the corrected entries
    moved_rms : RMS change of the weights on the other (not corrected) frames
    moved_relative : ``moved_rms`` / RMS of the previous weights on those frames
    implicated : tuple of pose names whose columns the chosen model was allowed to change (the
        evidence set when the library stays unchanged)
    evidence : {pose: (size, consistency)} for every pose the animator changed at all
    gains : (K,) per-pose gain applied (1 off the implicated set)
    pose_changes : {pose: {"gain", "delta_rms" (library units), "relative"}} for the changed poses
    changed : tuple of pose names whose library column changed
    model : "unchanged", "gain" or "gain+markers"
    candidate : label of the chosen candidate (a key of ``cv`` when the leave-one-out ran)
    mu : float, the prior of the per-marker correction (inf for gains only / unchanged)
    cv : {candidate label: leave-one-frame-out RMS error}
    notes : tuple of str
    """

    library: Basis
    weights: np.ndarray
    version: str
    frames: np.ndarray
    corrected_rmse_before: float
    corrected_rmse_after: float
    moved_rms: float
    moved_relative: float
    implicated: tuple
    evidence: dict
    gains: np.ndarray
    pose_changes: dict
    changed: tuple
    model: str
    candidate: str
    mu: float
    cv: dict = field(default_factory=dict)
    notes: tuple = ()


def default_solver(library, deltas, *, regularisation=default("solve.regularisation"),
                   sparsity=default("solve.sparsity"), smoothing=DEFAULT_SMOOTHING):
    """The ``calibrated`` strategy's actor solve: (F, M, D) deltas -> (F, K) weights (NaN unsolved)."""
    F, M, D = deltas.shape
    res = solve_bounded(library.matrix(), deltas.reshape(F, M * D), lower=library.lower, upper=library.upper,
                        regularisation=regularisation, sparsity=sparsity, smoothing=smoothing, relative=True)
    w = np.array(res.weights, dtype=np.float64)
    w[~res.solved] = np.nan
    return w


def _frame_solver(library, deltas):
    return default_solver(library, deltas, smoothing=(0.0, 0.0))


def _corrections(corrections, F, K):
    if not corrections:
        raise FacecapError("tuning: no corrected frames")
    frames = np.array(sorted(int(t) for t in corrections), dtype=np.int64)
    if frames.min() < 0 or frames.max() >= F:
        raise FacecapError(f"tuning: corrected frame indices must be in [0, {F}); got {frames.min()}..{frames.max()}")
    Wc = np.empty((len(frames), K))
    for i, t in enumerate(frames):
        row = np.asarray(corrections[t] if t in corrections else corrections[int(t)], dtype=np.float64)
        if row.shape != (K,):
            raise FacecapError(f"tuning: correction of frame {t} must have {K} weights; got shape {row.shape}")
        Wc[i] = row
    return frames, Wc


def _rms(x):
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else 0.0


def _fit(A, D, Wt, implicated, mu, *, gain_ridge=1e-3, gain_bounds=(0.2, 5.0)):
    """Library (K, P) from corrected frames. A (K, P), D (T, P) with NaN, Wt (T, K) full weights.

    Returns (new A (K, P), gains (K,)). ``implicated`` is an index array; mu=inf = gains only.
    """
    K, P = A.shape
    gains = np.ones(K)
    if len(implicated) == 0:
        return A.copy(), gains
    obs = np.isfinite(D)
    Dz = np.where(obs, D, 0.0)
    I = np.asarray(implicated)
    # gains: residual r_t = d_t - A' w_t ~ sum_{k in I} h_k w_tk a_k with g = 1 + h
    R = np.where(obs, Dz - Wt @ A, 0.0)  # (T, P)
    X = Wt[:, I][:, :, None] * A[I][None] * obs[:, None, :]  # (T, |I|, P)
    G = np.einsum("tip,tjp->ij", X, X)
    b = np.einsum("tip,tp->i", X, R)
    # prior: as if ``gain_ridge`` frames at full weight kept each gain at 1
    norms = np.sum(A[I] ** 2, axis=1)
    h = np.linalg.solve(G + gain_ridge * np.diag(np.maximum(norms, 1e-12 * max(norms.max(), 1e-300))), b)
    gains[I] = np.clip(1.0 + h, *gain_bounds)
    A1 = A * gains[:, None]
    if not np.isfinite(mu):
        return A1, gains
    # per-marker correction E on the implicated columns, per coordinate p
    R1 = np.where(obs, Dz - Wt @ A1, 0.0)
    WI = Wt[:, I]  # (T, |I|)
    H = np.einsum("ti,tj,tp->pij", WI, WI, obs.astype(float)) + mu * np.eye(len(I))[None]
    g = np.einsum("ti,tp->pi", WI, R1)
    E = np.linalg.solve(H, g[:, :, None])[:, :, 0]  # (P, |I|)
    A1[I] += E.T
    return A1, gains


def closed_form_update(library, deltas, solved, corrections, *, mu=1.0):
    """The plain closed form A' = (D W*^T + mu A)(W* W*^T + mu I)^-1 over all poses (the baseline).

    Same inputs as ``retune`` (``solved`` fills the poses a correction leaves NaN); missing markers
    are skipped per coordinate. ``mu`` in frames at full weight. Returns a new Basis.
    """
    deltas = np.asarray(deltas, dtype=np.float64)
    F = deltas.shape[0]
    K = library.n_shapes
    frames, Wc = _corrections(corrections, F, K)
    Wt = np.where(np.isfinite(Wc), Wc, np.asarray(solved, dtype=np.float64)[frames])
    A = library.matrix().T  # (K, P)
    D = deltas[frames].reshape(len(frames), -1)
    obs = np.isfinite(D)
    Dz = np.where(obs, D, 0.0)
    H = np.einsum("ti,tj,tp->pij", Wt, Wt, obs.astype(float)) + mu * np.eye(K)[None]
    g = np.einsum("ti,tp->pi", Wt, Dz) + mu * A.T
    new = np.linalg.solve(H, g[:, :, None])[:, :, 0].T
    return Basis(library.shape_names, library.marker_names, library.neutral, new.reshape(library.deltas.shape),
                 library.lower, library.upper)


def corrected_rmse(weights, frames, Wc):
    """RMS of weights - corrections over the entries the animator set (finite in ``Wc``)."""
    return _rms(np.where(np.isfinite(Wc), np.asarray(weights)[frames] - Wc, np.nan))


def retune(library, deltas, solved, corrections, *, mu=None, mu_grid=MU_GRID, min_change=0.05,
           min_consistency=0.6, active_weight=0.05, min_improvement=0.05, gain_ridge=1e-3,
           gain_bounds=(0.2, 5.0), solver=None,
           frame_solver=None, force=False, parent="v0", version=None):
    """Re-tune the actor calibration library from an animator's corrected frames.

    Parameters
    ----------
    library : Basis, K poses x M markers x D (deltas from neutral), never modified
    deltas : (F, M, D) the take's actor-space marker deltas, NaN gaps
    solved : (F, K) the current weights of the take (from ``library``)
    corrections : {frame index: (K,) corrected weights}, NaN = pose not corrected on that frame
    mu : None (choose by leave-one-frame-out), a float (prior of the per-marker correction, frames at
        full weight) or inf (gains only)
    mu_grid : mu candidates for the search
    min_change, min_consistency : evidence a pose needs to be implicated (see the module docstring)
    active_weight : a pose whose corrected weight reaches this on some corrected frame joins the
        wider gain candidate set
    min_improvement : relative LOO improvement a more complex model needs over a simpler one
    gain_ridge, gain_bounds : prior of the gain fit (as if ``gain_ridge`` frames at full weight
        held each gain at 1) and the gain range
    solver : callable (Basis, deltas) -> (F, K), the re-solve of the whole take (default: the
        ``calibrated`` strategy's solve, ``default_solver``)
    frame_solver : the same for single frames in the leave-one-out (default: per-frame solve)
    force : bool, drop "no change" from the candidates (the implicated poses are re-fitted even if
        the leave-one-out does not favour it; the final re-solve check still applies)
    parent, version : name of the input library; name of the new one (default: content-hashed)

    Returns
    -------
    TuneResult
    """
    if not isinstance(library, Basis):
        raise FacecapError(f"tuning: `library` must be a Basis; got {type(library).__name__}")
    deltas = np.asarray(deltas, dtype=np.float64)
    solved = np.asarray(solved, dtype=np.float64)
    K, M, Dm = library.deltas.shape
    if deltas.ndim != 3 or deltas.shape[1:] != (M, Dm):
        raise FacecapError(f"tuning: deltas must have shape (F, {M}, {Dm}); got {deltas.shape}")
    F = deltas.shape[0]
    if solved.shape != (F, K):
        raise FacecapError(f"tuning: solved weights must have shape ({F}, {K}); got {solved.shape}")
    if mu is not None and not mu > 0:
        raise FacecapError(f"tuning: mu must be > 0 (or None to choose it); got {mu}")
    solver = default_solver if solver is None else solver
    frame_solver = _frame_solver if frame_solver is None else frame_solver
    frames, Wc = _corrections(corrections, F, K)
    set_ = np.isfinite(Wc)
    Ws = solved[frames]
    Wt = np.where(set_, Wc, Ws)
    if not np.isfinite(Wt).all():
        raise FacecapError("tuning: a corrected frame has unsolved (NaN) weights the correction does not fill")
    notes = []

    # 1. evidence
    change = np.where(set_, Wc - Ws, 0.0)
    n_set = set_.sum(axis=0)
    size = np.sqrt((change**2).sum(axis=0) / np.maximum(n_set, 1))
    absum = np.abs(change).sum(axis=0)
    consistency = np.divide(np.abs(change.sum(axis=0)), absum, out=np.zeros(K), where=absum > 0)
    strong = np.flatnonzero((size >= min_change) & (consistency >= min_consistency))
    # poses the corrected frames exercise (a pose saturated at a bound changes little in weight
    # although its calibration is off: only the markers can tell); tried as a wider gain set
    exercised = np.abs(np.where(set_, Wc, 0.0)).max(axis=0) >= active_weight  # set by the animator only
    active = np.flatnonzero(exercised | np.isin(np.arange(K), strong))
    evidence = {library.shape_names[k]: (float(size[k]), float(consistency[k])) for k in np.flatnonzero(absum > 0)}

    A = library.matrix().T  # (K, P)
    D = deltas[frames].reshape(len(frames), -1)
    fit = dict(gain_ridge=gain_ridge, gain_bounds=gain_bounds)

    # 4. candidates (label, poses, mu), simplest first, chosen by leave-one-frame-out
    candidates = [] if (force and len(strong)) else [("unchanged", None, None)]
    if len(strong):
        if mu is None:
            candidates.append(("gain", strong, np.inf))
            if len(active) > len(strong):
                candidates.append(("gain (all active poses)", active, np.inf))
            candidates += [(f"gain+markers mu={m:g}", strong, float(m)) for m in sorted(mu_grid, reverse=True)]
        else:
            candidates.append(("gain" if not np.isfinite(mu) else f"gain+markers mu={mu:g}", strong, float(mu)))
    cv = {}
    T = len(frames)
    if not len(strong):
        chosen = candidates[0]
        notes.append("tuning: no pose changed consistently enough to implicate it; library unchanged")
    elif len(candidates) == 1:
        chosen = candidates[0]
    elif T < 3:
        notes.append(f"tuning: {T} corrected frame(s) are too few for leave-one-out; fitting gains only")
        chosen = candidates[1] if mu is None else candidates[-1]
    else:
        for label, poses, m in candidates:
            errs = []
            for i in range(T):
                if poses is None:
                    Ai = A
                else:
                    keep = np.arange(T) != i
                    Ai, _ = _fit(A, D[keep], Wt[keep], poses, m, **fit)
                lib_i = Basis(library.shape_names, library.marker_names, library.neutral,
                              Ai.reshape(K, M, Dm), library.lower, library.upper)
                w = frame_solver(lib_i, deltas[frames[i]][None])[0]
                errs.append(np.where(set_[i], w - Wc[i], np.nan))
            cv[label] = _rms(np.array(errs))
        chosen, best_err = candidates[0], cv[candidates[0][0]]
        for cand in candidates[1:]:
            if cv[cand[0]] < best_err * (1.0 - min_improvement):
                chosen, best_err = cand, cv[cand[0]]
        if chosen[1] is None:
            notes.append("tuning: leave-one-frame-out does not favour changing the library; library unchanged")

    candidate, implicated, chosen_mu = chosen
    if implicated is None:
        implicated, newA, gains = np.zeros(0, dtype=np.int64), A.copy(), np.ones(K)
    else:
        newA, gains = _fit(A, D, Wt, implicated, chosen_mu, **fit)
    chosen = None if chosen[1] is None else chosen_mu
    new = Basis(library.shape_names, library.marker_names, library.neutral.copy(), newA.reshape(K, M, Dm),
                library.lower.copy(), library.upper.copy())

    # 5. verify by re-solving the take
    before = corrected_rmse(solved, frames, Wc)
    weights = solver(new, deltas) if chosen is not None else solved.copy()
    after = corrected_rmse(weights, frames, Wc)
    if chosen is not None and not after < before:
        notes.append(f"tuning: the re-solve did not improve the corrected frames ({before:.4f} -> {after:.4f}); "
                     "library unchanged")
        new = Basis(library.shape_names, library.marker_names, library.neutral.copy(), library.deltas.copy(),
                    library.lower.copy(), library.upper.copy())
        weights, after, chosen, gains, candidate = solved.copy(), before, None, np.ones(K), "unchanged"

    other = np.ones(F, dtype=bool)
    other[frames] = False
    moved = _rms(weights[other] - solved[other])
    base = _rms(solved[other])
    delta_cols = new.deltas - library.deltas
    norms = np.linalg.norm(library.deltas.reshape(K, -1), axis=1)
    rel = np.linalg.norm(delta_cols.reshape(K, -1), axis=1) / np.where(norms > 0, norms, 1.0)
    changed = np.flatnonzero(rel > 1e-9)
    pose_changes = {library.shape_names[k]: {"gain": float(gains[k]), "delta_rms": _rms(delta_cols[k]),
                                             "relative": float(rel[k])} for k in changed}
    if version is None:
        if len(changed):
            digest = hashlib.sha1(np.ascontiguousarray(new.deltas).tobytes()).hexdigest()[:8]
            version = f"{parent}+tune{T}f-{digest}"
        else:
            version = parent
    model = "unchanged" if chosen is None else ("gain" if not np.isfinite(chosen) else "gain+markers")
    return TuneResult(
        library=new, weights=weights, version=version, frames=frames, corrected_rmse_before=before,
        corrected_rmse_after=after, moved_rms=moved, moved_relative=moved / base if base > 0 else 0.0,
        implicated=tuple(library.shape_names[k] for k in (implicated if len(implicated) else strong)),
        evidence=evidence, gains=gains, pose_changes=pose_changes,
        changed=tuple(library.shape_names[k] for k in changed), model=model, candidate=candidate,
        mu=float("inf") if chosen is None else float(chosen), cv=cv, notes=tuple(notes),
    )


def spread_frames(scores, n=8, *, min_gap=20):
    """Indices of the ``n`` highest-scoring frames at least ``min_gap`` frames apart, sorted.

    The frames worth correcting first (score = per-frame residual, or error against a reference);
    spreading them out makes the corrections tell more about the library than a run of neighbours.
    NaN scores are never picked.
    """
    scores = np.asarray(scores, dtype=np.float64)
    out = []
    for t in np.argsort(-np.where(np.isfinite(scores), scores, -np.inf), kind="stable"):
        if not np.isfinite(scores[t]):
            break
        if all(abs(int(t) - s) >= min_gap for s in out):
            out.append(int(t))
        if len(out) == n:
            break
    return sorted(out)


def fit_gain_offset(solved, corrections, *, min_frames=2):
    """Per-shape least squares corrected = gain * solved + offset over the corrected frames.

    Parameters
    ----------
    solved : (F, K) current weights
    corrections : {frame index: (K,) corrected weights}, NaN = not corrected
    min_frames : shapes corrected on fewer frames keep (1, 0); with too little spread in the solved
        values (a single distinct value) only the offset is fitted

    Returns
    -------
    gain, offset : (K,) arrays (identity (1, 0) where nothing was corrected)
    """
    solved = np.asarray(solved, dtype=np.float64)
    F, K = solved.shape
    frames, Wc = _corrections(corrections, F, K)
    Ws = solved[frames]
    gain, offset = np.ones(K), np.zeros(K)
    for k in range(K):
        ok = np.isfinite(Wc[:, k]) & np.isfinite(Ws[:, k])
        if ok.sum() < min_frames:
            if ok.sum() >= 1:
                offset[k] = float(np.mean(Wc[ok, k] - Ws[ok, k]))
            continue
        x, y = Ws[ok, k], Wc[ok, k]
        if np.ptp(x) < 1e-9:
            offset[k] = float(np.mean(y - x))
            continue
        X = np.column_stack([x, np.ones_like(x)])
        (g, o), *_ = np.linalg.lstsq(X, y, rcond=None)
        gain[k], offset[k] = float(g), float(o)
    return gain, offset


def apply_gain_offset(weights, gain, offset, *, lower=None, upper=None):
    """weights * gain + offset, clipped to [lower, upper] where given."""
    out = np.asarray(weights, dtype=np.float64) * gain + offset
    if lower is not None or upper is not None:
        out = np.clip(out, lower, upper)
    return out
