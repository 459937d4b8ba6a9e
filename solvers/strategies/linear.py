"""The ``linear`` strategy: posed correspondence, the "cloning matrix" (Lewis & Pighin).

From N example pairs — source features x_i (the take's marker deltas at a frame) and the
character weights w_i an animator posed for that frame — learn E (K, P) with::

    E = argmin  sum_i ||E x_i - w_i||^2 + lambda ||E||_F^2      = W^T X (X^T X + lambda I)^-1

(computed in the dual, ``W^T (X X^T + lambda I)^-1 X``, when N < P), with ``lambda`` relative to
the mean squared norm of the examples. A frame is solved as ``clip(E x, bounds)``; gaps are
filled from the visible markers through the examples' principal subspace first.
With noiseless examples and ``ridge=0`` the map reproduces every example exactly.
"""

import numpy as np

from ..errors import FacecapError
from ..transforms import Similarity, fit_similarity_2d
from .base import StrategyResult, as_target
from .lowrank import fill_gaps, gap_subspace
from .sources import align_to, as_deltas, check_pairs, clamp_to, flat, reorder


def as_source(source, *, what="source"):
    """Marker deltas (F, M, D) as they are, or feature vectors (F, P) - e.g. flow-PCA coefficients
    of footage (``solvers.video.features``) - as (F, P, 1) so the example strategies treat both alike."""
    X = np.asarray(source, dtype=np.float64)
    if X.ndim == 2 and X.shape[0] > 0 and X.shape[1] > 0:
        if np.isinf(X).any():
            raise FacecapError(f"`{what}` contains infinite values")
        return X[:, :, None]
    return as_deltas(X, what=what)


def align_source(deltas, neutral, fitted_neutral, *, mode="rigid"):
    """``align_to`` for 3D markers and for 2D image tracks (a 2D rotation, + scale for "similarity");
    feature vectors (D = 1) are not aligned. Returns (deltas, Similarity or None)."""
    if deltas.shape[2] == 3:
        return align_to(deltas, neutral, fitted_neutral, mode=mode)
    if deltas.shape[2] == 1 or mode == "none" or neutral is None or fitted_neutral is None:
        return deltas, None
    if mode not in ("rigid", "similarity"):
        raise FacecapError(f"`align` must be 'none', 'rigid' or 'similarity'; got {mode!r}")
    sim = fit_similarity_2d(neutral, fitted_neutral)
    if mode == "rigid":
        sim = Similarity(1.0, sim.rotation, sim.translation)
    return sim.apply_vectors(deltas), sim


class LinearStrategy:
    """Ridge-regularised linear map from marker deltas to character weights.

    Parameters (keyword-only)
    ----------
    ridge : float, default 1e-6, relative to the mean squared norm of an example's features
    intercept : bool, default False (neutral features -> zero weights, as a delta map should)
    align : "rigid", "similarity" or "none", used when both ``fit(neutral=)`` and ``solve(neutral=)``
        are given
    """

    name = "linear"
    source_kind = "markers"

    def __init__(self, *, ridge=1e-6, intercept=False, align="rigid"):
        if not ridge >= 0:
            raise FacecapError(f"linear: `ridge` must be >= 0; got {ridge}")
        self.ridge = float(ridge)
        self.intercept = bool(intercept)
        self.align = align
        self.target = None
        self.matrix = None  # (K, P)
        self.bias = None  # (K,)
        self.notes = ()

    def fit(self, character, *, examples, weights, training=None, names=None, neutral=None):
        """Learn the map from N example pairs.

        Parameters
        ----------
        character : Basis or shape names
        examples : ndarray (N, M, 3), marker deltas at the example frames (no gaps), or (N, P)
            feature vectors (flow-PCA coefficients of footage)
        weights : ndarray (N, K), the character weights posed for them
        names : marker names of ``examples`` (kept for ``solve(names=)``)
        neutral : ndarray (M, 3), optional, rest positions of the examples' space
        training : ndarray (F, M, 3), optional; more frames of the actor (gaps allowed) whose
            gap-free frames help fill gaps at solve time
        """
        self.target = as_target(character)
        ex = as_source(examples, what="examples")
        X, W = check_pairs(ex, weights, self.target)
        self.marker_shape = ex.shape[1:]
        self.names = None if names is None else tuple(names)
        self.fit_neutral = None if neutral is None else np.asarray(neutral, dtype=np.float64)
        N, P = X.shape
        notes = []
        if N < P:
            notes.append(
                f"linear: {N} example(s) for {P} source dimensions: the map is under-determined "
                "(the smallest-norm map is used); frames unlike the examples are mapped poorly"
            )
        xm = X.mean(axis=0) if self.intercept else np.zeros(P)
        wm = W.mean(axis=0) if self.intercept else np.zeros(W.shape[1])
        Xc, Wc = X - xm, W - wm
        lam = self.ridge * float(np.mean(np.sum(Xc**2, axis=1)))
        if N < P:  # dual form: E = Wc^T (Xc Xc^T + lam I)^-1 Xc
            G = Xc @ Xc.T + lam * np.eye(N)
            coef = np.linalg.lstsq(G, Wc, rcond=None)[0] if lam == 0 else np.linalg.solve(G, Wc)
            E = coef.T @ Xc
        else:
            G = Xc.T @ Xc + lam * np.eye(P)
            E = (np.linalg.lstsq(G, Xc.T @ Wc, rcond=None)[0] if lam == 0 else np.linalg.solve(G, Xc.T @ Wc)).T
        self.matrix = E
        self.bias = wm - E @ xm
        self._gap_rows = X
        if training is not None:
            tr = flat(as_source(training, what="training"))
            if tr.shape[1] != P:
                raise FacecapError(f"linear: `training` frames have {tr.shape[1]} coordinates; examples have {P}")
            self._gap_rows = np.concatenate([X, tr])
        self.notes = tuple(notes)
        self.n_examples = N
        return self

    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """Character weights for marker deltas (F, M, 3); ``confidence`` is ignored (gaps are filled)."""
        if self.matrix is None:
            raise FacecapError("linear: call fit() before solve()")
        deltas = reorder(as_source(source), names, self.names)
        if neutral is not None and self.fit_neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, self.names)[0]
            deltas, _ = align_source(deltas, neutral, self.fit_neutral, mode=self.align)
        if deltas.shape[1:] != self.marker_shape:
            raise FacecapError(f"linear: `source` frames have shape {deltas.shape[1:]}; fitted on {self.marker_shape}")
        X = flat(deltas)
        X, filled = fill_gaps(X, *gap_subspace(self._gap_rows, X))
        raw = X @ self.matrix.T + self.bias
        weights, clamped = clamp_to(self.target, raw)
        solved = np.isfinite(X).all(axis=1)
        weights[~solved] = np.nan
        warnings = list(self.notes)
        if filled.size:
            warnings.append(f"linear: {filled.size} frame(s) had gaps, filled from the visible markers through the principal subspace of the gap-free frames")
        return StrategyResult(
            weights=weights, shape_names=self.target.names, solved=solved, warnings=tuple(warnings),
            clamped=clamped, info={"examples": self.n_examples, "gap_frames": int(filled.size)},
        )
