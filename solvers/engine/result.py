"""The result of ``engine.solve_bounded``."""

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Weights and diagnostics of a solve.

    weights : (F, K), NaN for frames with no data (per-frame mode; locked/held shapes keep their value)
    residuals : (F, P), ``A w - d`` where the coordinate was observed (confidence > 0), 0 elsewhere
        (computed on first access)
    at_bound : (F,) number of solved (not locked/held) weights at a bound
    solved : (F,) bool, False where a frame had no data (temporal mode solves every frame
        as long as the take has data: gaps are bridged by the smoothing)
    iterations : int, active-set iterations used
    fallback_frames : int, frames handed to the exact per-frame fallback
    warnings : tuple of str
    converged : bool, False if the temporal active set did not settle within ``max_iter``
        (the weights are then the last iterate: feasible, but not optimal)
    mode : "per-frame" or "temporal"
    """

    weights: np.ndarray
    _residuals: object  # the (F, P) array, or a function computing it on first use
    at_bound: np.ndarray
    solved: np.ndarray
    iterations: int = 0
    fallback_frames: int = 0
    warnings: tuple = field(default_factory=tuple)
    converged: bool = True
    mode: str = "per-frame"

    @property
    def residuals(self):
        r = self._residuals
        if callable(r):
            r = r()
            object.__setattr__(self, "_residuals", r)
        return r
