"""Suggest the stable (head-rigid) markers of a take from the data, with a score per marker.

Pairwise-distance spreads do not separate the head from skin that moves by a millimetre or less
(noise is a third of a millimetre). What does: motion that is *synchronous with the expression*.
Each round stabilises on the current candidates (robust fit), takes the temporal components of
the face's deformation (PCA of the stabilised deltas smoothed over ~0.15 s), and scores every
marker by the energy of its deviation that those components explain, in units of what noise alone
would give (score ~1 or less: rigid; moving skin scores several times more). The stable set is the
low cluster below the largest gap of the sorted log-scores; a round repeats on it until it is fixed.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from .stabilise import stabilise_rigid


@dataclass(frozen=True, eq=False)
class StableSuggestion:
    """names: the suggested stable markers; scores: marker -> score (noise units, low = rigid);
    gap: ratio between the first rejected and the last accepted score (>= 2: a clear split);
    noise_mm: estimated per-coordinate marker noise."""

    names: tuple
    scores: dict
    gap: float
    noise_mm: float
    clear: bool
    rounds: int

    def report(self):
        return {"markers": list(self.names), "scores": {k: round(v, 3) for k, v in self.scores.items()},
                "gap": round(self.gap, 3), "clear": self.clear, "noise_mm": round(self.noise_mm, 4)}


def _moving_mean(x, half):
    from scipy.ndimage import uniform_filter1d  # scipy: loaded on first use

    v = np.isfinite(x)
    w = 2 * half + 1
    num = uniform_filter1d(np.where(v, x, 0.0), w, axis=0, mode="nearest")
    den = uniform_filter1d(v.astype(np.float64), w, axis=0, mode="nearest")
    return np.where(den > 0.5, num / np.maximum(den, 1e-12), np.nan)


def suggest_stable_markers(markers, *, window=0.15, components=8, min_markers=3, min_gap=2.0, max_rounds=6,
                           candidates=None):
    """Suggest the markers that move only with the head.

    Parameters
    ----------
    markers : MarkerSet (3D)
    window : float
        Smoothing window (seconds) for the temporal components of the deformation.
    components : int
        Temporal components of the face motion each marker's deviation is projected on.
    min_markers : int
        Smallest stable set returned.
    min_gap : float
        Score ratio across the split for it to count as clear (otherwise ``clear`` is False).
    candidates : sequence of str, optional
        Markers allowed in the set (default: all).

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
    F, M = m.n_frames, m.n_markers
    if F < 10:
        raise FacecapError(f"suggest stable markers: needs a take of at least 10 frames; got {F}")
    half = max(1, int(round(window * m.fps / 2)))
    w = 2 * half + 1
    pool_idx = np.array(m.index(pool))
    core = pool
    rounds, scores, gap, sigma = 0, None, 1.0, np.nan
    for rounds in range(1, max_rounds + 1):
        stab = stabilise_rigid(m, core)
        X = stab.markers.positions
        D = X - np.nanmedian(X, axis=0)
        S = _moving_mean(D, half)
        hf = (D - S)[np.isfinite(D - S)]
        sigma = 1.4826 * np.median(np.abs(hf)) * np.sqrt(w / (w - 1)) if hf.size else np.nan
        sigma = max(float(sigma), 1e-9)
        Sz = np.nan_to_num(S).reshape(F, -1)
        U = np.linalg.svd(Sz - Sz.mean(axis=0), full_matrices=False)[0][:, :components]
        Dz = np.nan_to_num(D)
        Dz = Dz - Dz.mean(axis=0)
        energy = (np.einsum("fk,fmd->kmd", U, Dz) ** 2).sum(axis=(0, 2))
        scores = energy / (3 * U.shape[1] * sigma**2)
        pool_scores = scores[pool_idx]
        order = np.argsort(pool_scores)
        logs = np.log(np.maximum(pool_scores[order], 1e-12))
        steps = np.diff(logs)[min_markers - 1: max(min_markers, len(pool) // 2)]
        k = min_markers + int(np.argmax(steps)) if steps.size else len(pool)
        gap = float(np.exp(steps.max())) if steps.size else 1.0
        new = tuple(pool[i] for i in order[:k])
        if set(new) == set(core):
            break
        core = new
    ordered = sorted(core, key=lambda n: scores[m.names.index(n)])
    return StableSuggestion(
        names=tuple(ordered),
        scores={n: float(scores[m.names.index(n)]) for n in pool},
        gap=gap, noise_mm=sigma * 1e3, clear=gap >= min_gap, rounds=rounds,
    )
