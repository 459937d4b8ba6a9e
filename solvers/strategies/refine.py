"""The ``refine`` strategy (Choe & Ko 2001): an actor basis refined from a training take.

Starting from an actor basis A0 (calibration poses, or a stored library), alternate

1. weights: solve every training frame against the current basis (``solve_bounded``);
2. basis: per marker, least squares over the training frames with a pull towards A0::

       A'_m = argmin sum_f ||d_fm - A_m w_f||^2 + mu ||A_m - A0_m||^2
            = (D_m^T W + mu A0_m)(W^T W + mu I)^-1       (frames where marker m is seen)

until the RMS fit error stops falling by ``tol`` (relative). An iteration that does not lower
the error is discarded, so the recorded history never rises. The original basis is never
modified: ``fit`` stores a new ``Basis`` (``refined_basis``, ``version`` = accepted iterations)
beside the original and then solves like ``calibrated`` with it.
"""

import numpy as np

from ..character.basis import Basis
from ..engine import solve_bounded
from ..errors import FacecapError
from ..options import default
from .calibrated import CalibratedStrategy
from .geometric import symmetric_pairs
from .sources import align_to, as_deltas, flat, reorder


class RefineStrategy(CalibratedStrategy):
    """``calibrated`` with an actor basis refined on a training take.

    Parameters (keyword-only)
    ----------
    max_iterations : int, default 10
    tol : float, default 1e-3: stop when the fit error falls by less than this fraction
    stiffness : float, default 1e-2: pull towards the original basis, relative to the mean
        squared activation of a pose over the training take (larger = smaller corrections)
    fit_smoothing : (mu1, mu2) of the weight solves inside the iteration, default (0, 0)
        (per-frame; the final ``solve`` uses ``smoothing``)
    **calibrated options : mapping, keyed_by, aliases, regularisation, sparsity, symmetry,
        smoothing, align, pose_bounds (see ``CalibratedStrategy``)
    """

    name = "refine"

    def __init__(self, *, max_iterations=default("refine.max_iterations"), tol=default("refine.tol"),
                 stiffness=default("refine.stiffness"), fit_smoothing=(0.0, 0.0), **options):
        super().__init__(**options)
        if int(max_iterations) < 0 or not tol >= 0 or not stiffness >= 0:
            raise FacecapError("refine: need max_iterations >= 0, tol >= 0 and stiffness >= 0")
        self.max_iterations, self.tol, self.stiffness = int(max_iterations), float(tol), float(stiffness)
        self.fit_smoothing = tuple(fit_smoothing)
        self.original_basis = None
        self.refined_basis = None
        self.history = ()
        self.version = 0

    def fit(self, character, *, training, names=None, neutral=None, confidence=None, **calibration):
        """Fit the starting basis (``CalibratedStrategy.fit`` arguments: ``actor_basis=`` or
        ``calibration=, poses=, neutral_frames -> neutral=``) and refine it on ``training``.

        Parameters
        ----------
        training : ndarray (F, M, 3), stabilised, neutral-normalised actor deltas (NaN gaps)
        names : marker names of ``training``
        neutral : ndarray (M, 3), the training take's neutral (aligned onto the basis' neutral)
        confidence : ndarray (F, M), optional
        calibration : keyword arguments for ``CalibratedStrategy.fit``; the calibration take's
            neutral frame range is ``calibration_neutral=`` here
        """
        if "calibration_neutral" in calibration:
            calibration["neutral"] = calibration.pop("calibration_neutral")
        super().fit(character, **calibration)
        original = self.actor_basis
        deltas = reorder(as_deltas(training, what="training"), names, original.marker_names)
        if neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, original.marker_names)[0]
        deltas, _ = align_to(deltas, neutral, original.neutral, mode=self.align)
        if confidence is not None:
            confidence = reorder(np.asarray(confidence, dtype=np.float64)[:, :, None], names, original.marker_names)[:, :, 0]
        seen = ~np.isnan(deltas[:, :, 0])
        if confidence is not None:
            seen &= np.nan_to_num(confidence) > 0
        D = np.where(seen[:, :, None], deltas, 0.0)

        def weights_and_error(basis):
            res = solve_bounded(
                basis.matrix(), flat(deltas), mask=confidence, dims=deltas.shape[2], lower=basis.lower,
                upper=basis.upper, regularisation=self.regularisation, sparsity=self.sparsity,
                symmetry=symmetric_pairs(basis.shape_names) if self.symmetry > 0 else (),
                symmetry_weight=self.symmetry, smoothing=self.fit_smoothing, relative=True,
            )
            W = np.nan_to_num(res.weights)
            pred = np.einsum("fk,kmd->fmd", W, basis.deltas)
            err = float(np.sqrt(np.sum(np.where(seen[:, :, None], pred - D, 0.0) ** 2) / max(seen.sum(), 1)))
            return W, err

        W, err = weights_and_error(original)
        history = [err]
        current = original
        A0 = original.deltas.transpose(1, 2, 0)  # (M, D, K)
        for _ in range(self.max_iterations):
            mu = max(self.stiffness * float(np.mean(np.sum(W**2, axis=0))), 1e-12)
            G = np.einsum("fm,fk,fl->mkl", seen.astype(float), W, W) + mu * np.eye(W.shape[1])
            R = np.einsum("fmd,fk->mdk", D, W) + mu * A0
            A = np.linalg.solve(G, R.transpose(0, 2, 1)).transpose(0, 2, 1)  # R_m G_m^-1, G symmetric
            candidate = Basis(current.shape_names, current.marker_names, current.neutral, A.transpose(2, 0, 1),
                              current.lower, current.upper)
            W_new, err_new = weights_and_error(candidate)
            if err_new >= err:
                break
            improved = err - err_new
            current, W, err = candidate, W_new, err_new
            history.append(err)
            if improved < self.tol * history[-2]:
                break
        self.original_basis = original
        self.refined_basis = current
        self.actor_basis = current
        self.history = tuple(history)
        self.version = len(history) - 1
        return self
