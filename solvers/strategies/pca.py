"""The ``pca`` strategy: a basis learned from the performance itself.

1. PCA of the training frames' marker deltas, frames with gaps included (``pca_gappy``),
   optionally rotated to independent components by FastICA (deflation, G = log cosh, as in
   Kalberer's speech thesis); the components are "pseudo-muscle" directions and reconstruct the
   training frames exactly at full rank. FastICA sees only the leading components above the noise
   level (Gavish & Donoho's threshold, ``signal_rank``); the weaker ones, mostly marker noise at the
   default ``variance``, stay principal components after them (same span). Rotating whitened noise
   components made the leading "independent" directions noise and, in the under-determined related
   regression, weighed noise like signal (weights RMSE 0.093 against 0.038 without ICA on a
   600-frame take with 30 examples; 0.034 now).
2. Chuang & Bregler basis frames: for each leading component, the frames with the smallest and
   the largest projection. They are offered to the animator as the frames to pose
   (``basis_frames``).
3. Two ways to reach the character:
   - ``mode="posed"``: each frame is a non-negative combination of the posed basis frames'
     marker deltas (``solve_bounded``); the same coefficients blend the character weights the
     animator posed for them;
   - ``mode="related"`` (the optic-flow thesis' related basis): principal-component regression
     from the frame's component coefficients to character weights, learned on example frames
     with known weights (``W = Phi'^T B Lambda^-1`` when every training frame is an example).
"""

import numpy as np

from ..engine import DEFAULT_SMOOTHING, solve_bounded
from ..errors import FacecapError
from .base import StrategyResult, as_target
from .linear import align_source, as_source
from .lowrank import fill_gaps, noise_threshold, pca, pca_gappy
from .sources import as_deltas, clamp_to, flat, reorder

MODES = ("related", "posed")

# Frames missing more than this share of their coordinates are not offered as frames to pose:
# their fill (and so their projection) rests on too little of the face.
MAX_PICK_GAP_SHARE = 0.25


def _filled_training(X, *, n_components=None, variance=None, center=True):
    """Learn a subspace of X (F, P) with gaps from every frame with a visible coordinate
    (``pca_gappy``) and fill the gaps through it.

    Returns (mean, components, singular values, energy, filled X (F, P; frames with nothing
    visible stay NaN), seen (F,) bool: frames with a visible coordinate, pickable (F,) bool: seen
    frames missing at most ``MAX_PICK_GAP_SHARE`` of their coordinates, or every seen frame if
    none is). Without gaps this is ``pca(X)`` and X itself.
    """
    gaps = np.isnan(X)
    seen = ~gaps.all(axis=1)
    mean, comps, s, energy = pca_gappy(X[seen], center=center, n_components=n_components, variance=variance)
    filled = fill_gaps(X, mean, comps)[0] if gaps.any() else X
    pickable = seen & (gaps.mean(axis=1) <= MAX_PICK_GAP_SHARE)
    if not pickable.any():
        pickable = seen
    return mean, comps, s, energy, filled, seen, pickable


def signal_rank(Xc, *, max_rows=2000):
    """Number of singular values of the centred rows Xc (N, P) above Gavish & Donoho's optimal hard
    threshold for unknown noise (``omega(beta) * median singular value``): the components that
    carry signal rather than marker noise. At most ``max_rows`` evenly spaced rows are used."""
    Xc = np.asarray(Xc, dtype=np.float64)
    if len(Xc) > max_rows:
        Xc = Xc[np.linspace(0, len(Xc) - 1, max_rows).round().astype(np.int64)]
    s = np.linalg.svd(Xc, compute_uv=False)
    if s.size == 0 or s[0] <= 0:
        return 0
    return int(np.sum(s > noise_threshold(s, Xc.shape)))


def fast_ica(Z, *, max_iter=400, tol=1e-8, step=1.0, seed=0):
    """FastICA by deflation with G(y) = log cosh(y) on whitened data.

    Parameters
    ----------
    Z : ndarray (N, C), zero mean, identity covariance
    step : Newton step size in (0, 1] (a damped step helps where the plain one oscillates)

    Returns
    -------
    unmixing : ndarray (C, C), orthonormal rows; sources = Z @ unmixing.T
    converged : bool
    """
    N, C = Z.shape
    rng = np.random.default_rng(seed)
    U = np.zeros((C, C))
    converged = True
    for p in range(C):
        w = rng.normal(size=C)
        w -= U[:p].T @ (U[:p] @ w)
        w /= np.linalg.norm(w)
        for _ in range(max_iter):
            y = Z @ w
            g = np.tanh(y)
            newton = (Z * g[:, None]).mean(axis=0) - (1.0 - g**2).mean() * w
            w_new = (1.0 - step) * w + step * newton if step < 1.0 else newton
            w_new -= U[:p].T @ (U[:p] @ w_new)
            w_new /= np.linalg.norm(w_new)
            done = abs(abs(w_new @ w) - 1.0) < tol
            w = w_new
            if done:
                break
        else:
            converged = False
        U[p] = w
    return U, converged


class PCAStrategy:
    """Performance-derived basis (PCA, optional FastICA) mapped to character weights.

    Parameters (keyword-only)
    ----------
    mode : "related" (default) or "posed"
    n_components : int or None; default None = as many as ``variance`` needs
    variance : float in (0, 1], default 0.99
    ica : bool, default False: rotate the components above the noise level to independent ones
        (FastICA); ``n_independent`` is their number (0 without ICA), the components after them
        stay principal components
    n_basis : int, default 8: leading components whose min/max frames are the basis frames
    regularisation, sparsity, smoothing : priors of the non-negative solve (``posed`` mode),
        relative to the basis scale; default 1e-4, 0, ``DEFAULT_SMOOTHING``
    coefficient_bound : float, default 1.5: upper bound on a basis frame's coefficient (posed)
    align : as in ``LinearStrategy``
    """

    name = "pca"
    source_kind = "markers"

    def __init__(self, *, mode="related", n_components=None, variance=0.99, ica=False, n_basis=8,
                 regularisation=1e-4, sparsity=0.0, smoothing=DEFAULT_SMOOTHING, coefficient_bound=1.5,
                 align="rigid", seed=0):
        if mode not in MODES:
            raise FacecapError(f"pca: `mode` must be one of {MODES}; got {mode!r}")
        if not 0 < variance <= 1:
            raise FacecapError(f"pca: `variance` must be in (0, 1]; got {variance}")
        self.mode, self.n_components, self.variance, self.ica = mode, n_components, float(variance), bool(ica)
        self.n_basis, self.regularisation, self.sparsity = int(n_basis), float(regularisation), float(sparsity)
        self.smoothing, self.coefficient_bound, self.align, self.seed = tuple(smoothing), float(coefficient_bound), align, seed
        self.target = None
        self.notes = ()

    # -- the learned basis ------------------------------------------------------------------
    def learn_basis(self, training, *, names=None, neutral=None):
        """PCA (+ ICA) of the training frames (F, M, 3); frames with gaps count.

        With markers occluded independently most frames of a take have some gap and the gap-free
        ones may be little more than the neutral holds, so the PCA is learnt from every frame with
        a visible marker (``pca_gappy``); the ICA and the basis-frame picks then see the frames
        with their gaps filled through that subspace (``fill_gaps``). Without gaps this is the
        plain PCA of the frames.

        Basis frames may have gaps: the animator poses the character at the actor's expression,
        which the reference footage shows whatever markers were occluded, and the fit fills the
        frame's gaps through the subspace. Frames missing more than ``MAX_PICK_GAP_SHARE`` of their
        coordinates are not picked (unless every frame is), as their projection rests on too
        little of the face.

        With ``ica`` the first ``n_independent`` components are the independent ones (FastICA of
        the components above the noise level, largest first), the rest principal components.

        Sets ``mean`` (P,), ``components`` (C, P) unit rows, ``basis_frames`` and returns self.
        """
        tr = as_source(training, what="training")
        self.marker_shape = tr.shape[1:]
        self.names = None if names is None else tuple(names)
        self.fit_neutral = None if neutral is None else np.asarray(neutral, dtype=np.float64)
        X = flat(tr)
        if np.isfinite(X).any(axis=1).sum() < 2:
            raise FacecapError("pca: fewer than 2 training frames with a visible marker")
        mean, comps, s, energy, filled, seen, pickable = _filled_training(
            X, n_components=self.n_components, variance=self.variance)
        notes = []
        self.n_independent = 0
        self._pca_components = comps
        if self.ica and len(comps) > 1:
            coef = (filled[seen] - mean) @ comps.T
            k = min(len(comps), signal_rank(filled[seen] - mean))
            if k >= 2:
                sigma = coef[:, :k].std(axis=0)
                U, ok = fast_ica(coef[:, :k] / sigma, seed=self.seed)
                if not ok:
                    notes.append("pca: FastICA did not converge for every component (kept the last iterate)")
                mixing = (U * sigma[None, :]) @ comps[:k]  # (k, P): signal part of X - mean ~ sources @ mixing
                norms = np.linalg.norm(mixing, axis=1)
                order = np.argsort(-norms)
                mixing = mixing[order] / norms[order, None]
                signs = np.sign(mixing[np.arange(len(mixing)), np.argmax(np.abs(mixing), axis=1)])
                comps = np.vstack([mixing * signs[:, None], comps[k:]])
                self.n_independent = k
            else:
                notes.append(f"pca: {k} component(s) above the noise level: FastICA skipped (plain PCA)")
        self.mean, self.components = mean, comps
        self.explained_variance = energy
        self._ortho = pca(comps, center=False)[1]  # orthonormal span, for gap filling
        frames = np.flatnonzero(pickable)
        coef = self.coefficients(filled[frames])
        picks = []
        for c in range(min(self.n_basis, comps.shape[0])):
            for which, i in (("min", int(np.argmin(coef[:, c]))), ("max", int(np.argmax(coef[:, c])))):
                picks.append((int(frames[i]), c, which))
        seen, unique = set(), []
        for f, c, which in picks:
            if f not in seen:
                seen.add(f)
                unique.append((f, c, which))
        self.basis_frames = tuple(unique)
        self._training = X
        self.notes = tuple(notes)
        return self

    def coefficients(self, X):
        """Component coefficients (F, C) of gap-free (or gap-filled) rows X (F, P), by least squares
        (an ICA basis is not orthogonal)."""
        return np.linalg.lstsq(self.components.T, (X - self.mean).T, rcond=None)[0].T

    def reconstruct(self, deltas):
        """Project deltas (F, M, 3) on the learned basis and rebuild them (gaps filled)."""
        X, _ = fill_gaps(flat(as_source(deltas)), self.mean, self._ortho)
        return (self.mean + self.coefficients(X) @ self.components).reshape(np.shape(deltas))

    def frames_to_pose(self):
        """Frame indices (into the training take) the animator should pose, Chuang & Bregler order."""
        return [f for f, _, _ in self.basis_frames]

    # -- mapping to the character -------------------------------------------------------------
    def fit(self, character, *, training, example_frames=None, example_weights=None, names=None, neutral=None):
        """Learn the basis from ``training`` and the map to the character from posed examples.

        Parameters
        ----------
        character : Basis or shape names
        training : ndarray (F, M, 3), the performance (stabilised, neutral-normalised deltas), or
            (F, P) feature vectors (flow-PCA coefficients of footage)
        example_frames : indices into ``training`` whose character weights are known; default:
            ``frames_to_pose()`` in posed mode, every frame in related mode
        example_weights : ndarray (N, K), the character weights of those frames (required)
        """
        self.target = as_target(character)
        self.learn_basis(training, names=names, neutral=neutral)
        if example_weights is None:
            raise FacecapError(
                f"pca: `example_weights` are required; pose the character at training frames {self.frames_to_pose()}"
            )
        Wx = np.asarray(example_weights, dtype=np.float64)
        if example_frames is None:
            example_frames = self.frames_to_pose() if self.mode == "posed" else list(range(len(self._training)))
        idx = np.asarray(example_frames, dtype=np.intp)
        if Wx.shape != (len(idx), self.target.n_shapes):
            raise FacecapError(f"pca: `example_weights` must have shape ({len(idx)}, {self.target.n_shapes}); got {Wx.shape}")
        X = self._training[idx]
        if not np.isfinite(X).all():
            X, _ = fill_gaps(X, self.mean, self._ortho)
        self.example_frames = idx
        if self.mode == "posed":
            self._posed = X  # (N, P) marker deltas of the posed basis frames
            self._posed_weights = Wx
        else:
            C = self.coefficients(X)
            design = np.hstack([C, np.ones((len(C), 1))])
            sol = np.linalg.lstsq(design, Wx, rcond=None)[0]
            self.related = sol[:-1].T  # (K, C)
            self.related_offset = sol[-1]
            if len(idx) < C.shape[1] + 1:
                self.notes += (f"pca: {len(idx)} example(s) for {C.shape[1]} components: the related basis is under-determined",)
        return self

    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """Character weights for marker deltas (F, M, 3)."""
        if self.target is None:
            raise FacecapError("pca: call fit() before solve()")
        deltas = reorder(as_source(source), names, self.names)
        if neutral is not None and self.fit_neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, self.names)[0]
            deltas, _ = align_source(deltas, neutral, self.fit_neutral, mode=self.align)
        if deltas.shape[1:] != self.marker_shape:
            raise FacecapError(f"pca: `source` frames have shape {deltas.shape[1:]}; fitted on {self.marker_shape}")
        if self.mode == "posed":
            return self._solve_posed(deltas, confidence)
        X, filled = fill_gaps(flat(deltas), self.mean, self._ortho)
        solved = np.isfinite(X).all(axis=1)
        C = self.coefficients(np.where(solved[:, None], X, 0.0))
        weights, clamped = clamp_to(self.target, C @ self.related.T + self.related_offset)
        weights[~solved] = np.nan
        return StrategyResult(
            weights=weights, shape_names=self.target.names, solved=solved, warnings=self.notes,
            source_weights=C, source_names=tuple(f"{'ic' if self.ica else 'pc'}{i}" for i in range(C.shape[1])),
            clamped=clamped, info={"components": C.shape[1], "gap_frames": int(filled.size)},
        )

    def _solve_posed(self, deltas, confidence):
        A = self._posed.T  # (P, N): column j = basis frame j's marker deltas
        N = A.shape[1]
        res = solve_bounded(
            A, flat(deltas), mask=confidence, dims=deltas.shape[2], lower=0.0, upper=self.coefficient_bound,
            regularisation=self.regularisation, sparsity=self.sparsity, smoothing=self.smoothing, relative=True,
        )
        weights, clamped = clamp_to(self.target, np.nan_to_num(res.weights) @ self._posed_weights)
        weights[~res.solved] = np.nan
        seen = ~np.isnan(deltas[:, :, 0])
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt((res.residuals**2).sum(axis=1) / seen.sum(axis=1))
        return StrategyResult(
            weights=weights, shape_names=self.target.names, solved=res.solved,
            warnings=self.notes + tuple(res.warnings), source_weights=res.weights,
            source_names=tuple(f"frame{f}" for f in self.example_frames), residual_rms=rms, clamped=clamped,
            info={"basis_frames": N, "mode": res.mode}, solve=res,
        )


def farthest_frames(training, n, *, n_components=18, include_neutral=True):
    """``n`` frames of ``training`` (F, M, 3) that cover its expressions: farthest-point sampling
    in the leading principal components. A complement to the Chuang & Bregler frames when an
    animator poses examples for ``linear`` / ``rbf`` / ``pca``.

    Frames with gaps count: the components are learnt from every frame with a visible marker
    (``pca_gappy``, uncentred) and a frame's point is its projection with the gaps filled through
    them. Picked frames may have gaps (the animator poses the actor's expression, known from the
    footage; the strategies fill the frame's gaps), but not more than ``MAX_PICK_GAP_SHARE`` of
    their coordinates (unless every frame has that many). Without gaps this is the farthest-point
    sampling of the plain PCA.

    Returns sorted frame indices (at most ``n``).
    """
    X = flat(as_deltas(training, what="training"))
    if not np.isfinite(X).any():
        raise FacecapError("farthest_frames: no training frame has a visible marker")
    _, comps, _, _, filled, _, pickable = _filled_training(X, n_components=n_components, center=False)
    cand = np.flatnonzero(pickable)
    P = filled[cand] @ comps.T
    dist = np.linalg.norm(P, axis=1)  # distance to the neutral (p = 0)
    picks = [int(np.argmin(dist))] if include_neutral else [int(np.argmax(dist))]
    dist = np.linalg.norm(P - P[picks[0]], axis=1)
    while len(picks) < min(n, len(cand)):
        i = int(np.argmax(dist))
        if dist[i] <= 0:
            break
        picks.append(i)
        dist = np.minimum(dist, np.linalg.norm(P - P[i], axis=1))
    return np.sort(cand[picks])
