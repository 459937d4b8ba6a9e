"""Flow-PCA features of footage as the source of the example strategies (``linear``, ``rbf``, ``pca``).

Dense flow over the face region relative to the neutral reference (``dense_flow``), optionally
with the head's per-frame similarity removed (fitted to the flow at stable points, the thesis'
SUGGESTION), is reduced by PCA to a few coefficients per frame (``flow_pca``; centred on the
neutral so coefficients 0 = neutral). Those coefficient vectors are the features an example
strategy maps to character weights, learned from frames an animator posed - no markers at all.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..strategies import make_strategy
from ..strategies.base import as_target
from ..transforms import fit_similarity_2d
from .pca import flow_pca

EXAMPLE_STRATEGIES = ("linear", "rbf", "pca")


@dataclass(frozen=True, eq=False)
class FlowFeatures:
    """Per-frame flow-PCA coefficients ``(F, P)`` and the PCA (``FlowPCA``) they come from."""

    frames: np.ndarray
    coefficients: np.ndarray
    pca: object
    stabilised: bool

    def rows(self, frames):
        """Indices of frame numbers ``frames``; raises naming the frames the footage lacks."""
        frames = np.asarray(frames, dtype=np.float64)
        idx = np.searchsorted(self.frames, frames).clip(0, len(self.frames) - 1)
        missing = frames[np.abs(self.frames[idx] - frames) > 1e-6]
        if missing.size:
            raise FacecapError(f"flow features: frame(s) {missing[:8].tolist()} are not in the footage "
                               f"({self.frames[0]:g}-{self.frames[-1]:g})")
        return idx


def remove_similarity(flows, points, stable):
    """Flow fields with each frame's head similarity taken out.

    ``flows`` (F, h, w, 2) on reference points ``points`` (h, w, 2); ``stable`` (h, w) bool marks
    samples that move with the head only. Per frame a similarity S maps ``p`` to ``p + F(p)`` on
    them; the returned field is ``S^-1(p + F(p)) - p`` (the face's own motion, in the reference frame).
    """

    flows = np.asarray(flows, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    mask = np.asarray(stable, dtype=bool).reshape(-1)
    if mask.shape[0] != p.shape[0]:
        raise FacecapError(f"`stable` must have the flow grid's shape {np.shape(points)[:2]}; got {np.shape(stable)}")
    if mask.sum() < 3:
        raise FacecapError(f"`stable` marks {int(mask.sum())} flow samples; need at least 3")
    out = np.empty_like(flows)
    for f, field in enumerate(flows):
        q = p + field.reshape(-1, 2)
        S = fit_similarity_2d(p[mask], q[mask])
        back = (q - S.translation) @ S.rotation / S.scale  # S^-1(q)
        out[f] = (back - p).reshape(field.shape)
    return out


def flow_features(dense, *, n_components=12, variance=None, stable=None):
    """Flow-PCA features of a ``DenseFlowResult``.

    Parameters
    ----------
    dense : DenseFlowResult (``dense_flow``), cropped to the face region
    n_components, variance : as in ``flow_pca`` (PCA centred on the neutral reference)
    stable : (h, w) bool, optional
        Flow samples on stable areas (forehead, temples, a head-cam rig): the per-frame head
        similarity fitted there is removed before the PCA, so head motion does not enter the features.
    """
    flows = dense.flows
    if stable is not None:
        flows = remove_similarity(flows, dense.points, stable)
    result = flow_pca(flows, n_components=n_components, variance=variance, center="reference", frames=dense.frames)
    return FlowFeatures(np.asarray(dense.frames, dtype=np.float64), result.coefficients, result, stable is not None)


def solve_from_flow(features, character, *, strategy="linear", example_frames, example_weights, **options):
    """Character weights for every frame from flow features and posed example frames.

    Parameters
    ----------
    features : FlowFeatures
    character : Basis, Target or shape names (the output shapes and their bounds)
    strategy : "linear", "rbf" or "pca" (``pca``: ``mode="related"`` regression on the features)
    example_frames : (N,) frame numbers the animator posed
    example_weights : (N, K) the character weights posed there
    options : keyword options of the strategy class (e.g. ``ridge`` for linear, ``kernel`` for rbf)

    Returns
    -------
    StrategyResult (one row per footage frame)
    """
    return fit_from_flow(features, character, strategy=strategy, example_frames=example_frames,
                         example_weights=example_weights, **options).solve(features.coefficients)


def fit_from_flow(features, character, *, strategy="linear", example_frames, example_weights, **options):
    """The strategy of :func:`solve_from_flow`, fitted (its ``solve(features.coefficients)`` gives the weights)."""

    if strategy not in EXAMPLE_STRATEGIES:
        raise FacecapError(f"flow features drive {', '.join(EXAMPLE_STRATEGIES)}; got strategy {strategy!r}")
    target = as_target(character)
    idx = features.rows(example_frames)
    W = np.asarray(example_weights, dtype=np.float64)
    if W.shape != (len(idx), target.n_shapes):
        raise FacecapError(f"`example_weights` must have shape ({len(idx)}, {target.n_shapes}); got {W.shape}")
    X = features.coefficients
    s = make_strategy(strategy, **options)
    if strategy == "pca":
        s.fit(target, training=X, example_frames=idx, example_weights=W)
    else:
        s.fit(target, examples=X[idx], weights=W, training=X)
    return s
