"""Suggest the stable (head-rigid) markers of a take from the data, and say when there are none.

Pairwise-distance spreads do not separate the head from skin that moves by a millimetre or less
(noise is a third of a millimetre). What does: motion that is *synchronous with the expression*.
Each round stabilises on the current candidates (robust fit), takes the temporal components of the
face's deformation (PCA of the stabilised deltas smoothed over ~0.15 s) and scores every marker by
the energy of its deviation that those components explain, over its *visible* frames, in units of
what noise alone would give (~1 for a rigid marker whatever its gaps; moving skin scores several
times more). Isolated outliers are removed before scoring.

Every marker whose score is within what noise gives (``max_score``) is rigid; the set is all of them
that are visible in nearly every frame, spread so the rigid fit is well conditioned (markers with
gaps are added only where frames would lack well-spread markers). The set is then validated:

* **visibility** - frames with fewer than three chosen markers cannot be stabilised;
* **conditioning** - the head-pose error the marker noise alone causes at the face, predicted from
  the geometry of the markers visible in each frame (``face_error_mm``, in units of the noise);
* **residual** - each chosen marker's distance from the rigid fit, against the noise;
* **agreement** - two interleaved halves of the set, stabilised separately, must give the same head
  motion at the face within what their conditioning predicts.

A set that fails says so (``ok`` False, ``problems``) and names the best candidates instead of
silently choosing a bad set; :meth:`StableSuggestion.report` has the per-marker figures.
"""

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import FacecapError, needs
from ..transforms import fit_rigid_batch
from .stabilise import stabilise_rigid


@dataclass(frozen=True, eq=False)
class StableSuggestion:
    """What :func:`suggest_stable_markers` found.

    names: the suggested stable markers (best first); scores: marker -> score (noise units, ~1 =
    rigid); visibility: marker -> fraction of frames seen; gap: score ratio between the first
    rejected and the last accepted marker; noise_mm: estimated per-coordinate marker noise; ok: the
    set passed validation (``problems`` says why not); candidates: the best markers to name by hand
    when it did not; conditioning: figures of the chosen set (see the module docstring).
    """

    names: tuple
    scores: dict
    gap: float
    noise_mm: float
    clear: bool
    rounds: int
    visibility: dict = field(default_factory=dict)
    ok: bool = True
    problems: tuple = ()
    candidates: tuple = ()
    conditioning: dict = field(default_factory=dict)
    residual_mm: dict = field(default_factory=dict)  # chosen marker -> RMS distance from the rigid fit

    def report(self):
        """JSON-ready: the set, validation, conditioning and per-marker score / visibility / residual."""
        per = {n: {"score": round(s, 3), "visible": round(self.visibility.get(n, float("nan")), 4)}
               for n, s in sorted(self.scores.items(), key=lambda kv: kv[1])}
        for n, r in self.residual_mm.items():
            per[n]["residual_mm"] = round(r, 4)
        return {"markers": list(self.names), "ok": self.ok, "problems": list(self.problems),
                "candidates": list(self.candidates), "gap": round(self.gap, 3), "clear": self.clear,
                "noise_mm": round(self.noise_mm, 4), "conditioning": self.conditioning,
                "scores": {k: round(v, 3) for k, v in self.scores.items()}, "per_marker": per}

    def message(self):
        """One line for notes and operator reports."""
        if self.ok:
            c = self.conditioning
            return (f"stable markers suggested from the take ({len(self.names)}, head-fit error at the face "
                    f"{c.get('face_error_mm', float('nan')):.3f} mm for noise {self.noise_mm:.3f} mm): {list(self.names)}")
        best = ", ".join(f"{n} (score {self.scores[n]:.1f}, {100 * self.visibility[n]:.0f}% visible)"
                         for n in self.candidates)
        return (f"no reliable stable set in this take: {'; '.join(self.problems)}; best candidates: {best}")


def moving_mean(x, half):
    with needs("scipy", "Stable-marker scoring (Suggest Stable Markers, Detect Neutral)"):
        from scipy.ndimage import uniform_filter1d  # scipy: loaded on first use

    v = np.isfinite(x)
    w = 2 * half + 1
    num = uniform_filter1d(np.where(v, x, 0.0), w, axis=0, mode="nearest")
    den = uniform_filter1d(v.astype(np.float64), w, axis=0, mode="nearest")
    return np.where(den > 0.5, num / np.maximum(den, 1e-12), np.nan)


def _stabilise(m, names, iterations=3):
    """Robust rigid stabilisation on ``names`` against the median shape of the whole take.

    ``stabilise_rigid``'s default reference is one frame (its noise would shift the pose whenever a
    marker drops out); here the reference is refined to the median of the stabilised frames, and
    each refit Tukey-weights the markers by their distance from it.

    Returns
    -------
    positions : (F, M, 3) every marker in the reference head frame (NaN where the fit is not determined)
    R, t : (F, 3, 3), (F, 3) raw -> stabilised
    reference : (S, 3) the stable markers' median shape
    flagged : (F,) bool
    """
    idx = m.index(names)
    pts = m.positions[:, idx]
    vis = np.isfinite(pts[:, :, 0])
    first = stabilise_rigid(m, names)
    R, t = first.rotations, first.translations
    for _ in range(iterations):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            aligned = pts @ R.transpose(0, 2, 1) + t[:, None]
            aligned[first.flagged] = np.nan
            reference = np.nanmedian(aligned, axis=0)
            dist = np.linalg.norm(aligned - reference, axis=2)
        scale = 4.685 * 1.4826 * max(float(np.nanmedian(dist)), 1e-12)
        w = np.where(vis & np.isfinite(dist), np.clip(1 - (np.nan_to_num(dist) / scale) ** 2, 0, 1) ** 2, 0.0)
        w = np.where(w.sum(axis=1, keepdims=True) > 0, w, vis.astype(np.float64))  # a frame never loses all
        R, t, ok = fit_rigid_batch(pts, reference, w)
    flagged = ~ok | (vis.sum(axis=1) < 3)
    X = m.positions @ R.transpose(0, 2, 1) + t[:, None]
    X[flagged] = np.nan
    return X, R, t, reference, flagged


def _with_complete_frame(vis, idx, rows=None):
    """``idx`` without the markers missing from the frame (of ``rows``, default all) that shows most
    of them: the stabilisation reference needs one frame showing the whole set."""
    idx = list(idx)
    if not idx:
        return idx
    rows = np.arange(len(vis)) if rows is None else np.flatnonzero(rows)
    if rows.size == 0:
        return idx
    best = rows[int(np.argmax(vis[np.ix_(rows, idx)].sum(axis=1)))]
    return [i for i in idx if vis[best, i]]


def _scores(m, core, half, components):
    """(M,) rigidity scores, the noise sigma (m) and the stabilised positions with outliers removed.
    A marker with no sample at all (or none left after the outliers) scores NaN -> infinite, quietly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: "Mean of empty slice"
        return _scores_of(m, core, half, components)


def _scores_of(m, core, half, components):
    F = m.n_frames
    w = 2 * half + 1
    core = [m.names[i] for i in _with_complete_frame(m.visible, m.index(core))]
    X = _stabilise(m, core)[0]
    D = X - np.nanmedian(X, axis=0)
    S = moving_mean(D, half)
    hf = D - S
    fast = 1.4826 * np.nanmedian(np.abs(hf).reshape(F, -1, 1).reshape(F, hf.shape[1], 3), axis=(0, 2))
    fast = fast * np.sqrt(w / (w - 1))  # (M,) each marker's frame-to-frame scatter
    sigma = np.nanmedian(fast[m.index(core)])  # noise: the (rigid) core's scatter
    sigma = max(float(sigma) if np.isfinite(sigma) else 0.0, 1e-6)  # 1 micron: noise-free takes
    with np.errstate(invalid="ignore"):
        outlier = np.linalg.norm(hf, axis=2) > 6.0 * sigma  # isolated spikes would pass for motion
    D[outlier] = np.nan
    S = moving_mean(D, half)
    vis = np.isfinite(D[:, :, 0])
    Sz = np.nan_to_num(S - np.nanmean(S, axis=0)).reshape(F, -1)
    U = np.linalg.svd(Sz, full_matrices=False)[0][:, :components]  # (F, k) temporal components
    k = U.shape[1]
    Dz = np.where(vis[..., None], D - np.nanmean(D, axis=0), 0.0)
    # Least-squares projection over each marker's visible frames (zeros at gaps would lower the score).
    G = np.einsum("fm,fk,fl->mkl", vis.astype(np.float64), U, U) + 1e-9 * np.eye(k)
    b = np.einsum("fk,fmd->mkd", U, Dz)
    energy = np.einsum("mkd,mkd->m", b, np.linalg.solve(G, b))
    # Motion faster than the window (a jittering or sliding marker) shows as scatter above the noise.
    return np.maximum(energy / (3 * k * sigma**2), np.nan_to_num((fast / sigma) ** 2, nan=np.inf)), sigma, X


def _spread(P):
    """(M, M) 5-95 % range over frames of every pairwise distance of ``P`` (F, M, 3), gaps ignored
    (inf where a pair is never seen together), and the (M, M) fraction of frames each pair is seen."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        d = np.linalg.norm(P[:, :, None] - P[:, None], axis=3)  # (F, M, M)
    n = np.isfinite(d).sum(axis=0)
    d = np.sort(d, axis=0)  # gaps (NaN) sort last: percentiles of the n seen values
    lo = np.take_along_axis(d, (0.05 * np.maximum(n - 1, 0)).astype(int)[None], axis=0)[0]
    hi = np.take_along_axis(d, (0.95 * np.maximum(n - 1, 0)).astype(int)[None], axis=0)[0]
    return np.where(n > 0, hi - lo, np.inf), n / len(P)


def _rigid_clique(m, half, min_common=0.3):
    """Marker indices that keep their mutual distances (smoothed over the window) within what noise
    allows: a greedy largest clique of the "rigid with" graph, the seed of the scoring rounds. Distances
    ignore head motion, so this needs no stable set; a coherent moving group (both brows) forms a
    smaller clique than the head."""
    step = max(1, half // 2)  # smoothed: a few samples per window do
    P = moving_mean(m.positions, half)[::step]
    raw = m.positions
    second = raw[2:] - 2 * raw[1:-1] + raw[:-2]  # head motion is smooth: this is noise (x sqrt 6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scatter = 1.4826 * np.nanmedian(np.abs(second), axis=(0, 2)) / np.sqrt(6.0)  # (M,)
    scatter = np.sort(scatter[np.isfinite(scatter)])
    if scatter.size < 3:
        return []
    # The noise: the third quietest marker (skin can jitter, the head cannot); >= 1 micron.
    sigma = max(float(scatter[2]), 1e-6)
    noise = 3.3 * sigma * np.sqrt(2.0)  # 5-95 % range of a distance's noise
    spread_raw, common = _spread(raw[::step])
    A = (spread_raw < 2.0 * noise) & (_spread(P)[0] < 2.0 * noise / np.sqrt(2 * half + 1)) & (common >= min_common)
    np.fill_diagonal(A, False)
    degree = A.sum(axis=1)
    if degree.max() < 2:
        return []
    clique = [int(np.argmax(degree))]
    cand = A[clique[0]].copy()
    while cand.any():
        inside = np.where(cand, A[:, cand].sum(axis=1), -1)  # most links within the candidates first
        u = int(np.argmax(inside))
        clique.append(u)
        cand &= A[u]
    return clique


def _inertia(x):
    """Inertia tensor (3, 3) of points ``x`` (N, 3) about their centroid."""
    c = x - x.mean(axis=0)
    return np.eye(3) * np.sum(c * c) - c.T @ c


def _face_error(shape, vis, face, sigma):
    """(F,) RMS head-fit error (m) at the ``face`` points caused by noise ``sigma`` on the visible
    stable points of ``shape`` (S, 3); inf where fewer than 3 are visible or they are collinear."""
    out = np.full(vis.shape[0], np.inf)
    patterns, inverse = np.unique(vis, axis=0, return_inverse=True)
    for p, row in enumerate(patterns):
        if row.sum() < 3:
            continue
        x = shape[row]
        J = _inertia(x)
        if np.linalg.eigvalsh(J)[0] <= 1e-12 * np.trace(J):
            continue
        Ji = np.linalg.inv(J)
        r = face - x.mean(axis=0)
        rot = np.sum(r * r, axis=1) * np.trace(Ji) - np.einsum("ni,ij,nj->n", r, Ji, r)
        out[inverse.ravel() == p] = sigma * np.sqrt(3.0 / row.sum() + rot.mean())
    return out


def _choose(names, rigid, vis, shape, face, sigma, min_visible, max_markers):
    """The stable set from the rigid markers: well visible ones, spread; gappy ones only where needed."""
    frac = vis.mean(axis=0)
    good = [i for i in rigid if frac[i] >= min_visible]
    rest = sorted((i for i in rigid if frac[i] < min_visible), key=lambda i: -frac[i])
    chosen = list(good)
    if len(chosen) > max_markers:  # farthest-point sampling keeps the spread of a large set
        keep = [chosen[int(np.argmax(np.linalg.norm(shape[chosen] - shape[chosen].mean(axis=0), axis=1)))]]
        while len(keep) < max_markers:
            d = np.min(np.linalg.norm(shape[chosen][:, None] - shape[keep][None], axis=2), axis=1)
            keep.append(chosen[int(np.argmax(d))])
        chosen = keep
    target = np.median(_face_error(shape[chosen], vis[:, chosen], face, sigma)) if len(chosen) >= 3 else np.inf
    for i in rest:  # add gappy rigid markers while they fix frames or conditioning
        err = _face_error(shape[chosen], vis[:, chosen], face, sigma) if len(chosen) >= 3 else np.full(len(vis), np.inf)
        if np.isfinite(err).all() and np.max(err) <= 2.0 * target and len(chosen) >= 4:
            break
        chosen.append(i)
    return chosen


def _agreement(m, names, face_idx, face_err):
    """RMS disagreement (m) at the face between the head motions of two interleaved halves of
    ``names`` (ordered by position), and what their conditioning predicts; (nan, nan) if too few."""
    if len(names) < 6:
        return np.nan, np.nan
    halves = names[0::2], names[1::2]
    moved = [_stabilise(m, half)[0][:, face_idx] for half in halves]
    diff = moved[0] - moved[1]
    diff -= np.nanmedian(diff, axis=0)  # the two references differ by a constant offset per marker
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rms = float(np.sqrt(np.nanmedian(np.nanmean(np.sum(diff**2, axis=2), axis=1))))
    return rms, float(np.hypot(*face_err))


def suggest_stable_markers(markers, *, window=0.15, components=8, min_markers=3, max_score=3.0, min_visible=0.9,
                           max_markers=24, max_rounds=6, candidates=None, reference_frames=None, min_gap=2.0):
    """Suggest the markers that move only with the head, validated (see the module docstring).

    Parameters
    ----------
    markers : MarkerSet (3D)
    window : float
        Smoothing window (seconds) for the temporal components of the deformation.
    components : int
        Temporal components of the face motion each marker's deviation is projected on.
    min_markers : int
        Smallest stable set (a rigid fit needs 3; 4 or more let the robust fit reject a mover).
    max_score : float
        Highest score (noise units) of a rigid marker; noise alone gives ~1 (chi-square with
        3 x ``components`` degrees of freedom: 99.9 % of rigid markers score below ~2.2).
    min_visible : float
        Fraction of frames a marker must be seen in to be preferred.
    max_markers : int
        Largest set (more add little; the most spread are kept).
    candidates : sequence of str, optional
        Markers allowed in the set (default: all).
    reference_frames : (first, last), optional
        The stabilisation's reference range: one of its frames must show the whole set.
    min_gap : float
        Score ratio across the split for ``clear`` (kept for reports).

    Returns
    -------
    StableSuggestion
    """
    if markers.dim != 3:
        raise FacecapError(f"suggest stable markers: needs 3D markers; got {markers.dim}D")
    pool = tuple(markers.names if candidates is None else candidates)
    markers.index(pool, what="candidate marker")
    if len(pool) < min_markers:
        raise FacecapError(f"suggest stable markers: need at least {min_markers} candidates; got {len(pool)}")
    m = markers.to_units("m")
    F = m.n_frames
    if F < 10:
        raise FacecapError(f"suggest stable markers: needs a take of at least 10 frames; got {F}")
    half = max(1, int(round(window * m.fps / 2)))
    pool_idx = np.array(m.index(pool))
    vis_all = m.visible
    frac = vis_all.mean(axis=0)
    seed = [pool[i] for i in _rigid_clique(m.subset(pool), half)] if len(pool) <= 400 else []
    seen = [pool[i] for i in range(len(pool)) if frac[pool_idx[i]] >= 0.5]
    core = tuple(seed) if len(seed) >= min_markers else tuple(seen) if len(seen) >= min_markers else pool
    rounds, scores, sigma, X = 0, None, np.nan, None
    for rounds in range(1, max_rounds + 1):
        scores, sigma, X = _scores(m, core, half, components)
        order = pool_idx[np.argsort(scores[pool_idx])]
        rigid = [i for i in order if scores[i] <= max_score]
        if len(rigid) < min_markers:
            rigid = list(order[:max(min_markers, 4)])
        new = tuple(m.names[i] for i in rigid)
        if set(new) == set(core):
            break
        core = new
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        shape = np.nanmedian(X, axis=0)  # the stabilised (reference-frame) face
    face = shape[np.isfinite(shape[:, 0])]
    rigid_ok = [i for i in rigid if np.isfinite(shape[i, 0])]
    chosen = _choose(m.names, rigid_ok, vis_all, shape, face, sigma, min_visible, max_markers)
    rows = None if reference_frames is None else m.frame_range_mask(*reference_frames)
    chosen = _with_complete_frame(vis_all, _with_complete_frame(vis_all, chosen, rows))
    chosen = sorted(chosen, key=lambda i: scores[i])
    names = tuple(m.names[i] for i in chosen)
    pool_sorted = np.sort(scores[pool_idx])
    n_in = sum(1 for i in pool_idx if scores[i] <= max_score)
    gap = float(pool_sorted[n_in] / max(pool_sorted[n_in - 1], 1e-12)) if 0 < n_in < len(pool_sorted) else 1.0
    problems, conditioning, residual = _validate(m, names, chosen, vis_all, shape, face, sigma, scores, max_score,
                                                 min_markers)
    ranked = sorted(pool_idx, key=lambda i: (scores[i] > max_score, -min(frac[i], min_visible), scores[i]))
    return StableSuggestion(
        names=names, scores={n: float(scores[m.names.index(n)]) for n in pool}, gap=gap, noise_mm=sigma * 1e3,
        clear=gap >= min_gap, rounds=rounds, visibility={n: float(frac[m.names.index(n)]) for n in pool},
        ok=not problems, problems=tuple(problems), candidates=tuple(m.names[i] for i in ranked[:8]),
        conditioning=conditioning, residual_mm=residual,
    )


def _validate(m, names, chosen, vis_all, shape, face, sigma, scores, max_score, min_markers):
    """(problems, conditioning figures, per-marker residual in mm) of the chosen set."""
    problems = []
    if len(chosen) < min_markers:
        return [f"only {len(chosen)} marker(s) move with the head alone (need {min_markers})"], {}, {}
    vis = vis_all[:, chosen]
    err = _face_error(shape[chosen], vis, face, sigma)
    short = int((vis.sum(axis=1) < 3).sum())
    J = _inertia(shape[chosen])
    ev = np.linalg.eigvalsh(J)
    finite = err[np.isfinite(err)]
    noise = np.sqrt(3.0) * sigma  # RMS noise of one marker
    conditioning = {
        "markers": len(chosen), "frames_below_3": short,
        "frames_below_4": int((vis.sum(axis=1) < 4).sum()),
        "spread_mm": round(float(np.sqrt(np.trace(J) / 2 / len(chosen))) * 1e3, 3),
        "isotropy": round(float(np.sqrt(max(ev[0], 0.0) / ev[-1])), 4),
        "face_error_mm": round(float(np.median(finite)) * 1e3, 4) if finite.size else None,
        "face_error_worst_mm": round(float(np.max(finite)) * 1e3, 4) if finite.size else None,
        "face_error_ratio": round(float(np.median(finite) / noise), 4) if finite.size else None,
    }
    if short > 0.005 * len(err):
        problems.append(f"{short} frame(s) show fewer than 3 of the chosen markers")
    if not finite.size or np.median(finite) > 3.0 * noise:
        problems.append("the chosen markers are too few or too close together for a usable head fit "
                        f"(head-fit error at the face {conditioning['face_error_ratio']} x the marker noise)")
    elif np.median(finite) > 0.75 * noise:
        conditioning["warning"] = (f"weakly conditioned: the head fit alone adds {conditioning['face_error_ratio']} x "
                                   "the marker noise at the face (the refit on all markers reduces it)")
    X, _, _, reference, _ = _stabilise(m, names)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        d = np.linalg.norm(X[:, chosen] - reference[None], axis=2)
        per = np.sqrt(np.nanmedian(d**2, axis=0))  # median: outliers and gaps aside
    residual = {n: float(v) * 1e3 for n, v in zip(names, per)}
    conditioning["residual_ratio"] = round(float(np.nanmedian(per) / noise), 4)
    if np.nanmedian(per) > 1.5 * noise:
        problems.append(f"the chosen markers do not fit a rigid head within the noise (median residual "
                        f"{np.nanmedian(per) * 1e3:.2f} mm for noise {noise * 1e3:.2f} mm)")
    face_idx = np.flatnonzero(np.isfinite(shape[:, 0]))
    pts = shape[chosen] - shape[chosen].mean(axis=0)
    order = list(np.argsort(pts @ np.linalg.svd(pts, full_matrices=False)[2][0]))  # along the set's long axis
    halves = [names[i] for i in order]
    errs = [np.median(_face_error(shape[[chosen[i] for i in order][k::2]], vis[:, order[k::2]], face, sigma))
            for k in (0, 1)]
    rms, expected = _agreement(m, halves, face_idx, errs)
    if np.isfinite(rms):
        conditioning["halves_disagree_mm"] = round(rms * 1e3, 4)
        conditioning["halves_expected_mm"] = round(expected * 1e3, 4)
        if rms > 3.0 * expected + 0.2 * noise:
            problems.append(f"two halves of the set disagree on the head motion by {rms * 1e3:.2f} mm at the face "
                            f"(noise predicts {expected * 1e3:.2f} mm)")
    return problems, conditioning, residual
