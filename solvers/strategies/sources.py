"""The source side every marker strategy shares: validating marker deltas, matching them to the
markers a strategy was fitted on, aligning them into its head frame, and checking example pairs."""

import numpy as np

from ..errors import FacecapError
from ..transforms import fit_similarity


def clamp_to(target, weights):
    """Clip (F, K) weights to the target's bounds; returns (clipped, count per frame)."""
    clipped = np.clip(weights, target.lower, target.upper)
    changed = np.isfinite(weights) & (np.abs(clipped - weights) > 1e-12)
    return clipped, changed.sum(axis=1)


def as_deltas(source, *, what="source", overwrite=False):
    """Validate marker deltas: (F, M, D) float array (D = 2 or 3), NaN for gaps (a sample with one
    NaN coordinate is a gap in all of them). The array is copied only when such a sample must be
    made whole, and not even then with ``overwrite`` (the caller gives the array up)."""
    deltas = np.asarray(source, dtype=np.float64)
    if deltas.ndim == 2 and deltas.shape[0] > 0:
        raise FacecapError(f"`{what}` must have shape (F, M, 3) marker deltas; got {deltas.shape} (weights go to `parallel`)")
    if deltas.ndim != 3 or deltas.shape[2] not in (2, 3) or deltas.shape[0] == 0:
        raise FacecapError(f"`{what}` must have shape (F, M, 3); got {deltas.shape}")
    if np.isinf(deltas).any():
        raise FacecapError(f"`{what}` contains infinite values")
    nan = np.isnan(deltas)
    partial = nan.any(axis=2) & ~nan.all(axis=2)
    if partial.any():
        deltas = deltas if overwrite else deltas.copy()
        deltas[partial] = np.nan
    return deltas


def reorder(deltas, names, fitted_names, *, what="source"):
    """Columns of ``deltas`` (F, M, D) in ``fitted_names`` order; markers the source lacks are gaps."""
    if names is None or fitted_names is None:
        if fitted_names is not None and deltas.shape[1] != len(fitted_names):
            raise FacecapError(
                f"`{what}` has {deltas.shape[1]} markers; the strategy was fitted on {len(fitted_names)} "
                "(pass `names` to match them by name)"
            )
        return deltas
    names = tuple(names)
    if len(names) != deltas.shape[1]:
        raise FacecapError(f"`names` has {len(names)} entries for {deltas.shape[1]} markers in `{what}`")
    lookup = {n: i for i, n in enumerate(names)}
    common = [n for n in fitted_names if n in lookup]
    if len(common) < 3:
        raise FacecapError(
            f"`{what}` shares only {len(common)} marker(s) with the fitted ones; "
            f"fitted: {list(fitted_names)[:8]}..., source: {list(names)[:8]}..."
        )
    out = np.full((deltas.shape[0], len(fitted_names), deltas.shape[2]), np.nan)
    for j, n in enumerate(fitted_names):
        if n in lookup:
            out[:, j] = deltas[:, lookup[n]]
    return out


def align_to(deltas, neutral, fitted_neutral, *, mode="rigid"):
    """Rotate (and, for ``mode="similarity"``, scale) deltas from the source's neutral frame into
    the frame the strategy was fitted in (Sony's master T-pose alignment).

    ``neutral`` (M, D) is in the source's order after ``reorder``; rows with NaN are ignored.
    Returns (deltas, Similarity or None).
    """
    if mode == "none" or neutral is None or fitted_neutral is None:
        return deltas, None
    if mode not in ("rigid", "similarity"):
        raise FacecapError(f"`align` must be 'none', 'rigid' or 'similarity'; got {mode!r}")
    neutral = np.asarray(neutral, dtype=np.float64)
    if neutral.shape != fitted_neutral.shape:
        raise FacecapError(f"`neutral` must have shape {fitted_neutral.shape}; got {neutral.shape}")
    sim = fit_similarity(neutral, fitted_neutral, allow_scale=(mode == "similarity"))
    return sim.apply_vectors(deltas), sim


def flat(deltas):
    """(F, M, D) -> (F, M * D)."""
    return deltas.reshape(deltas.shape[0], -1)


def check_pairs(features, weights, target, *, what="examples"):
    """Validate example pairs: features (N, M, D) or (N, P) without gaps, weights (N, K) finite."""
    X = np.asarray(features, dtype=np.float64)
    if X.ndim == 3:
        X = X.reshape(X.shape[0], -1)
    if X.ndim != 2 or X.shape[0] == 0:
        raise FacecapError(f"`{what}` must have shape (N, M, 3) or (N, P); got {np.shape(features)}")
    if not np.isfinite(X).all():
        raise FacecapError(f"`{what}` must have no gaps (NaN); fill or drop those frames first")
    W = np.asarray(weights, dtype=np.float64)
    if W.shape != (X.shape[0], target.n_shapes):
        raise FacecapError(f"`weights` must have shape ({X.shape[0]}, {target.n_shapes}); got {W.shape}")
    if not np.isfinite(W).all():
        raise FacecapError("`weights` must be finite")
    return X, W
