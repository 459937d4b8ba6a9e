"""The contract every cross-mapping strategy keeps: what it is given (``Target``, ``PreparedTake``),
what it must provide (``Strategy``) and what it returns (``StrategyResult``).

See the package docstring (``solvers/strategies/__init__.py``) for the interface in words; the
maths the strategies share lives in ``sources`` (marker deltas) and ``lowrank`` (PCA, gap filling).
"""

from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np

from ..character.basis import Basis
from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class StrategyResult:
    """Character weights from one strategy solve.

    weights : (F, K) weights for the character's shapes (``shape_names``), NaN where unsolved
    shape_names : tuple of K character shape names
    solved : (F,) bool
    warnings : tuple of str (legal but doubtful input or output; never raised)
    source_weights : (F, S) or None, the intermediate activations (actor poses for calibrated/refine,
        basis-frame or component coefficients for pca, mapped source channels for parallel)
    source_names : tuple of S names for ``source_weights``
    residual_rms : (F,) or None, RMS fit residual of the markers in source space (metres),
        for strategies that fit markers
    clamped : (F,) int, character weights moved onto their bounds by the final clamp
    info : dict of strategy-specific diagnostics (JSON-ready scalars and short lists)
    solve : the engine's SolveResult where a weight solve ran, else None
    marker_names : markers of the fit, in the order of ``solve.residuals``' columns (empty: the
        strategy's ``actor_basis`` markers, else the take's)
    alignment : the transform that carried the take's neutral onto what the strategy was fitted on
        (``geometric``: actor -> character similarity), else None
    alignment_residual : (U,) each of ``marker_names``' distance from its target after ``alignment``
    """

    weights: np.ndarray
    shape_names: tuple
    solved: np.ndarray
    warnings: tuple = ()
    source_weights: np.ndarray = None
    source_names: tuple = ()
    residual_rms: np.ndarray = None
    clamped: np.ndarray = None
    info: dict = field(default_factory=dict)
    solve: object = None
    marker_names: tuple = ()
    alignment: object = None
    alignment_residual: np.ndarray = None


@runtime_checkable
class Strategy(Protocol):
    """What the pipeline calls on every strategy (``geometric`` included).

    ``name`` is the ``[solve] strategy`` value; ``source_kind`` is ``"markers"`` (stabilised,
    neutral-normalised actor deltas (F, M, D)) or ``"weights"`` (solved channels (F, S)).
    ``fit`` learns from the character and the strategy's inputs and returns the strategy;
    ``solve`` maps a take to character weights.
    """

    name: str
    source_kind: str

    def fit(self, character, **inputs): ...

    def solve(self, source, *, names=None, neutral=None, confidence=None) -> "StrategyResult": ...


@runtime_checkable
class PredictsMarkers(Protocol):
    """A strategy whose solve predicts the markers themselves: the pipeline refits the head on every
    marker against that prediction (hierarchical stabilisation) before the final solve.

    ``solve`` also takes ``start`` (weights of an earlier solve, (F, K)), ``quick`` (a cheap
    per-frame prediction instead of the optimum) and ``overwrite`` (the caller gives ``source`` up:
    the solve may work in its memory); ``predict(result)`` returns the actor-space marker deltas
    (F, U, D) of ``result.marker_names`` that ``result`` explains.
    """

    def solve(self, source, *, names=None, neutral=None, confidence=None, start=None, quick=False,
              overwrite=False): ...

    def predict(self, result): ...


@dataclass(frozen=True, eq=False)
class PreparedTake:
    """A take as every marker strategy receives it.

    deltas : (F, M, D) stabilised marker positions minus the neutral (metres, or pixels for 2D
        tracks), NaN for gaps; master T-pose offsets already added
    neutral : (M, D) the neutral in the same (stabilised head) frame
    names : M marker names
    frames : (F,) frame numbers
    stabilise : StabiliseResult
    offsets : (F, M, D) master T-pose offsets added to the positions, or None
    observed : (F, M) bool, where each marker was measured, kept when ``deltas`` were handed to a
        solve (``handed_over``; then ``deltas`` is None)
    fps : the take's frame rate (None where unknown)
    """

    deltas: np.ndarray
    neutral: np.ndarray
    names: tuple
    frames: np.ndarray
    stabilise: object
    offsets: np.ndarray = None
    observed: np.ndarray = None
    fps: float = None

    @property
    def dim(self):
        return self.neutral.shape[1]

    def seen(self):
        """(F, M) bool: where each marker was measured."""
        return self.observed if self.deltas is None else np.isfinite(self.deltas[:, :, 0])

    def handed_over(self):
        """This take without its deltas, for a solve that may overwrite them; where each marker was
        measured is kept."""
        return replace(self, deltas=None, observed=self.seen())


@dataclass(frozen=True)
class Target:
    """The character side of every strategy: shape names and slider bounds."""

    names: tuple
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n_shapes(self):
        return len(self.names)


def as_target(character):
    """A ``Target`` from a Basis, a Target or a sequence of shape names (bounds [0, 1])."""
    if isinstance(character, Target):
        return character
    if isinstance(character, Basis):
        return Target(character.shape_names, character.lower.copy(), character.upper.copy())
    if isinstance(character, str) or not hasattr(character, "__iter__"):
        raise FacecapError(f"`character` must be a Basis or a sequence of shape names; got {type(character).__name__}")
    names = tuple(str(n) for n in character)
    if not names or len(set(names)) != len(names):
        raise FacecapError("`character` shape names must be non-empty and unique")
    return Target(names, np.zeros(len(names)), np.ones(len(names)))
