"""The result of ``engine.solve_bounded``."""

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Weights and diagnostics of a solve.

    weights : (F, K), NaN for frames with no data (per-frame mode; locked/held shapes keep their value)
    residuals : (F, P), ``A w - d`` where the coordinate was observed (confidence > 0), 0 elsewhere
        (computed on first access; ``residual_norms`` sums them per marker without it)
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
    _residual_rows: object = None  # function (a, b) -> the residuals of frames [a, b), or None

    @property
    def residuals(self):
        r = self._residuals
        if callable(r):
            r = r()
            object.__setattr__(self, "_residuals", r)
        return r

    def residual_norms(self, dims, block=8192):
        """(F, P // dims): the squared length of each marker's residual (``dims`` coordinates a
        marker), 0 where unobserved. In blocks of frames: no (F, P) residual array (587 MB on 100
        minutes at 60 fps of 68 markers) unless ``residuals`` was already read."""
        rows = self._residual_rows
        if rows is None or not callable(self._residuals):
            r = self.residuals
            return (r.reshape(r.shape[0], -1, dims) ** 2).sum(axis=2)
        F = self.weights.shape[0]
        out = None
        for a in range(0, F, block):
            r = rows(a, min(F, a + block))
            r2 = (r.reshape(r.shape[0], -1, dims) ** 2).sum(axis=2)
            if out is None:
                out = np.empty((F, r2.shape[1]))
            out[a : a + block] = r2
        return np.zeros((0, 0)) if out is None else out
