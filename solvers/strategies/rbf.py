"""The ``rbf`` strategy: example-based scattered-data interpolation (Pyun et al. 2003).

Source features are PCA-reduced marker deltas ``p = F x`` (F: the leading principal directions
of the training frames, uncentred so the neutral maps to p = 0, scaled to unit RMS). Character
weights are interpolated between the N examples with radial basis functions plus a polynomial
tail (``scipy.interpolate.RBFInterpolator``): ``w(p) = sum_j c_j phi(||p - p_j||) + a + B p``,
exact at the examples when ``smoothing = 0`` (the cardinal-function formulation of Pyun is the
same interpolant). Weights are clipped to the character's bounds; frames far from every example
are flagged (RBF extrapolation is poor).
"""

import numpy as np
from scipy.interpolate import RBFInterpolator

from ..errors import FacecapError
from .base import StrategyResult, as_target
from .linear import align_source, as_source
from .lowrank import fill_gaps, gap_subspace, pca_gappy
from .sources import check_pairs, clamp_to, flat, reorder

KERNELS = ("thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric",
           "inverse_multiquadric", "inverse_quadratic")
_SCALED = {"gaussian", "multiquadric", "inverse_multiquadric", "inverse_quadratic"}


class RBFStrategy:
    """Radial-basis interpolation from PCA-reduced marker deltas to character weights.

    Parameters (keyword-only)
    ----------
    kernel : one of ``KERNELS``, default "thin_plate_spline"
    smoothing : float >= 0, default 0 (interpolate the examples exactly); relative to the features' unit RMS
    degree : polynomial tail degree, default 1 (linear, Pyun's "linear part"); -1 = none
    epsilon : shape parameter for the scaled kernels (default: 1 / median example spacing)
    n_components : int, default 18 (Pyun: 60 -> 18), capped by the training rank
    variance : float in (0, 1], default 0.999: keep at most the components reaching this share
    far : float, default 2.0; a frame farther than ``far`` x the median example spacing from its
        nearest example is reported as extrapolated
    align : as in ``LinearStrategy``
    """

    name = "rbf"
    source_kind = "markers"

    def __init__(self, *, kernel="thin_plate_spline", smoothing=0.0, degree=1, epsilon=None, n_components=18,
                 variance=0.999, far=2.0, align="rigid"):
        if kernel not in KERNELS:
            raise FacecapError(f"rbf: unknown kernel {kernel!r}; available: {', '.join(KERNELS)}")
        if not smoothing >= 0:
            raise FacecapError(f"rbf: `smoothing` must be >= 0; got {smoothing}")
        if degree not in (-1, 0, 1, 2):
            raise FacecapError(f"rbf: `degree` must be -1, 0, 1 or 2; got {degree}")
        if not (0 < variance <= 1) or int(n_components) < 1:
            raise FacecapError("rbf: need n_components >= 1 and 0 < variance <= 1")
        self.kernel, self.smoothing, self.degree, self.epsilon = kernel, float(smoothing), int(degree), epsilon
        self.n_components, self.variance, self.far, self.align = int(n_components), float(variance), float(far), align
        self.target = None
        self.interpolator = None
        self.notes = ()

    def fit(self, character, *, examples, weights, training=None, names=None, neutral=None):
        """Learn the interpolant.

        Parameters
        ----------
        character : Basis or shape names
        examples : ndarray (N, M, 3), marker deltas of the example frames (no gaps), or (N, P)
            feature vectors (flow-PCA coefficients of footage)
        weights : ndarray (N, K), the character weights posed for them
        training : ndarray (F, M, 3), optional; frames whose principal directions define the
            features (default: the examples); gaps allowed (imputed for the PCA, ``pca_gappy``)
        names, neutral : as in ``LinearStrategy.fit``
        """
        self.target = as_target(character)
        ex = as_source(examples, what="examples")
        X, W = check_pairs(ex, weights, self.target)
        self.marker_shape = ex.shape[1:]
        self.names = None if names is None else tuple(names)
        self.fit_neutral = None if neutral is None else np.asarray(neutral, dtype=np.float64)
        T = X
        if training is not None:
            tr = flat(as_source(training, what="training"))
            if tr.shape[1] != X.shape[1]:
                raise FacecapError(f"rbf: `training` frames have {tr.shape[1]} coordinates; examples have {X.shape[1]}")
            T = tr[np.isfinite(tr).any(axis=1)]
            if len(T) == 0:
                raise FacecapError("rbf: no `training` frame has a visible marker")
        # frames with gaps count: the gap-free ones alone may be only the neutral holds
        _, comps, _, _ = pca_gappy(T, center=False, n_components=self.n_components, variance=self.variance)
        notes = []
        N = len(X)
        degree = self.degree
        if degree >= 1 and N < comps.shape[0] + 1:  # the tail needs N >= d + 1: keep it, drop components
            if N >= 3:
                notes.append(f"rbf: {N} example(s) support a linear tail in at most {N - 1} dimensions; "
                             f"using {N - 1} of {comps.shape[0]} components")
                comps = comps[: N - 1]
            else:
                degree = 0 if self.kernel not in ("thin_plate_spline", "cubic") else -1
                notes.append(f"rbf: {N} example(s) are too few for a polynomial tail; using degree {degree}")
        if degree == 2 and N < (comps.shape[0] + 1) * (comps.shape[0] + 2) // 2:
            degree = 1
            notes.append("rbf: too few examples for a quadratic tail; using degree 1")
        self._components = comps
        self._gap_rows = np.concatenate([X, T])
        P = X @ comps.T
        self._scale = float(np.sqrt(np.mean(np.sum(P**2, axis=1)))) or 1.0
        P = P / self._scale
        self._points = P
        dist = np.linalg.norm(P[:, None] - P[None], axis=2)
        np.fill_diagonal(dist, np.inf)
        nearest = dist.min(axis=1) if N > 1 else np.ones(1)
        if np.any(nearest < 1e-9):
            raise FacecapError("rbf: two examples have the same features (duplicate frames?); remove one")
        self._spacing = float(np.median(nearest))
        eps = self.epsilon if self.epsilon is not None else (1.0 / self._spacing if self.kernel in _SCALED else 1.0)
        self.interpolator = RBFInterpolator(P, W, kernel=self.kernel, smoothing=self.smoothing, degree=degree, epsilon=eps)
        self.used_degree = degree
        self.notes = tuple(notes)
        return self

    def features(self, deltas):
        """Reduced, scaled features (F, d) of gap-filled deltas (F, M, 3)."""
        X = flat(deltas)
        X, _ = fill_gaps(X, *gap_subspace(self._gap_rows, X))
        return X @ self._components.T / self._scale

    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """Character weights for marker deltas (F, M, 3); gaps are filled through the principal subspace of
        the gap-free frames (training, examples and the take itself)."""
        if self.interpolator is None:
            raise FacecapError("rbf: call fit() before solve()")
        deltas = reorder(as_source(source), names, self.names)
        if neutral is not None and self.fit_neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, self.names)[0]
            deltas, _ = align_source(deltas, neutral, self.fit_neutral, mode=self.align)
        if deltas.shape[1:] != self.marker_shape:
            raise FacecapError(f"rbf: `source` frames have shape {deltas.shape[1:]}; fitted on {self.marker_shape}")
        X = flat(deltas)
        X, filled = fill_gaps(X, *gap_subspace(self._gap_rows, X))
        solved = np.isfinite(X).all(axis=1)
        P = np.where(solved[:, None], X, 0.0) @ self._components.T / self._scale
        raw = self.interpolator(P)
        weights, clamped = clamp_to(self.target, raw)
        weights[~solved] = np.nan
        nearest = np.min(np.linalg.norm(P[:, None] - self._points[None], axis=2), axis=1) / self._spacing
        nearest[~solved] = np.nan
        far = np.flatnonzero(nearest > self.far)
        warnings = list(self.notes)
        if far.size:
            warnings.append(
                f"rbf: {far.size} frame(s) lie more than {self.far:g}x the example spacing from every example "
                f"(extrapolated; add examples near them), e.g. frame indices {far[:5].tolist()}"
            )
        if clamped.any():
            warnings.append(f"rbf: {int(clamped.sum())} weight value(s) clipped to the shape bounds")
        return StrategyResult(
            weights=weights, shape_names=self.target.names, solved=solved, warnings=tuple(warnings),
            source_weights=P, source_names=tuple(f"pc{i}" for i in range(P.shape[1])), clamped=clamped,
            info={"examples": len(self._points), "components": P.shape[1], "degree": self.used_degree,
                  "extrapolated_frames": int(far.size), "distance": nearest},
        )
