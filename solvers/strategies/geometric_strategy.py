"""``geometric`` behind the common strategy interface (the solve itself is ``geometric.solve_geometric``).

Actor-space deltas are carried into character space by the similarity that maps the take's
neutral onto the character's bound points, then solved against the character's own shape keys.
The pipeline calls ``solve_geometric`` directly inside its hierarchical stabilisation loop; this
class is for strategy switching and comparisons.
"""

import numpy as np

from ..character.basis import Basis
from ..engine import DEFAULT_SMOOTHING
from ..errors import FacecapError
from .base import StrategyResult, as_deltas, reorder
from .geometric import GeometricOptions, solve_geometric
from ..transforms import fit_similarity


class GeometricStrategy:
    """Parameters (keyword-only): regularisation=1e-3, sparsity=1e-3, symmetry=0.0,
    smoothing=DEFAULT_SMOOTHING (see ``GeometricOptions``)."""

    name = "geometric"
    source_kind = "markers"

    def __init__(self, *, regularisation=1e-3, sparsity=1e-3, symmetry=0.0, smoothing=DEFAULT_SMOOTHING):
        self.options = GeometricOptions(regularisation=regularisation, sparsity=sparsity, symmetry=symmetry,
                                        smoothing=tuple(smoothing))
        self.basis = None

    def fit(self, character):
        """``character`` : Basis (the character's shapes at the bound points). Nothing is learned."""
        if not isinstance(character, Basis):
            raise FacecapError(f"geometric: `character` must be a Basis; got {type(character).__name__}")
        self.basis = character
        return self

    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """``source`` (F, M, 3) actor-space deltas; with ``neutral`` (M, 3) they are aligned onto the
        character by a similarity, without it they must already be in character space."""
        if self.basis is None:
            raise FacecapError("geometric: call fit() before solve()")
        basis = self.basis
        deltas = reorder(as_deltas(source), names, basis.marker_names)
        info = {}
        if neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, basis.marker_names)[0]
            sim = fit_similarity(neutral, basis.neutral)
            deltas = sim.apply_vectors(deltas)
            info["alignment_scale"] = sim.scale
        if confidence is not None:
            confidence = np.nan_to_num(reorder(np.asarray(confidence, float)[:, :, None], names, basis.marker_names)[:, :, 0])
        res = solve_geometric(basis, deltas, options=self.options, confidence=confidence)
        seen = ~np.isnan(deltas[:, :, 0])
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt((res.residuals**2).sum(axis=1) / seen.sum(axis=1))
        return StrategyResult(
            weights=res.weights, shape_names=basis.shape_names, solved=res.solved, warnings=tuple(res.warnings),
            residual_rms=rms, clamped=np.zeros(len(deltas), dtype=int), info={**info, "mode": res.mode}, solve=res,
        )
