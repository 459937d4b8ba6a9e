"""The ``geometric`` strategy: stabilised actor marker deltas against the character's shape keys.

The actor's deltas are carried into character space by the similarity that maps the actor's
neutral markers onto the character's bound points, then solved against the shape-key deltas at
those points with bounded, regularised least squares (gaps masked out).
"""

from dataclasses import dataclass

import numpy as np

from ..engine import solve_bounded


@dataclass(frozen=True)
class GeometricOptions:
    """Options of the geometric solve.

    regularisation : ridge weight relative to the mean squared norm of a basis column
        (scale free: the same value works for millimetre and metre rigs).
    """

    regularisation: float = 1e-3


def solve_geometric(basis, deltas, *, options=GeometricOptions()):
    """Solve weights for character-space marker deltas.

    Parameters
    ----------
    basis : Basis with M markers, D dims
    deltas : ndarray, shape (F, M, D), NaN for gaps, already in the basis' space and units
    options : GeometricOptions

    Returns
    -------
    SolveResult (residuals reshaped by the caller)
    """
    A = basis.matrix()
    scale = float(np.mean(np.einsum("pk,pk->k", A, A))) or 1.0
    D = deltas.reshape(deltas.shape[0], -1)
    return solve_bounded(
        A, D, lower=basis.lower, upper=basis.upper, regularisation=options.regularisation * scale
    )
