"""The ``geometric`` strategy: stabilised actor marker deltas against the character's shape keys.

The actor's deltas are carried into character space by the similarity that maps the actor's
neutral markers onto the character's bound points, then solved against the shape-key deltas at
those points with bounded, regularised least squares (gaps masked out, bridged samples trusted
less).
"""

from dataclasses import dataclass

from ..engine import DEFAULT_SMOOTHING, solve_bounded


@dataclass(frozen=True)
class GeometricOptions:
    """Priors of the geometric solve, all relative to the mean squared norm of a basis column
    (unit free: the same values work for millimetre and metre rigs).

    regularisation : ridge weight on every shape (keeps weights of shapes the markers barely see small)
    sparsity : L1 weight (most shapes are off most of the time; pulls noise-level activations to 0)
    symmetry : coupling of each ``<name>Left`` / ``<name>Right`` pair (off by default: it lets a
        side whose markers are missing follow the other side, but biases asymmetric expressions)
    smoothing : (first, second) temporal difference weights; (0, 0) solves frames independently.
        The default keeps a 3-frame lip closure at 60 fps and halves frame-to-frame jitter.
    """

    regularisation: float = 1e-3
    sparsity: float = 1e-3
    symmetry: float = 0.0
    smoothing: tuple = DEFAULT_SMOOTHING


def symmetric_pairs(shape_names):
    """Index pairs (left, right) of shapes named ``<base>Left`` / ``<base>Right`` (ARKit style)."""
    index = {n: i for i, n in enumerate(shape_names)}
    pairs = []
    for name, i in index.items():
        if name.endswith("Left") and name[:-4] + "Right" in index:
            pairs.append((i, index[name[:-4] + "Right"]))
    return pairs


def solve_geometric(basis, deltas, *, options=GeometricOptions(), confidence=None, lower=None, upper=None,
                    locks=None, regions=None, start=None, max_iter=None, exact=True):
    """Solve weights for character-space marker deltas.

    Parameters
    ----------
    basis : Basis with M markers, D dims
    deltas : ndarray, shape (F, M, D), NaN for gaps, already in the basis' space and units
    options : GeometricOptions
    confidence : ndarray (F, M), optional
        Trust per marker sample (0 = ignore).
    lower, upper : ndarray (K,), optional
        Weight bounds (default: the basis' slider range).
    locks : ndarray (K,) or (F, K), optional
        Values held fixed, NaN = free.
    regions : list of (shape indices, coordinate indices), optional
        See :func:`solvers.engine.solve_bounded`.
    start : ndarray (F, K), optional
        Weights of an earlier solve of similar deltas: the solve starts from them (faster, same result).
    max_iter, exact : see :func:`solvers.engine.solve_bounded` (``exact=False`` with a small
        ``max_iter``: a quick per-frame prediction instead of the optimum)

    Returns
    -------
    SolveResult; its residuals have shape (F, M * D)
    """
    F, M, D = deltas.shape
    pairs = symmetric_pairs(basis.shape_names) if options.symmetry > 0 else ()
    return solve_bounded(
        basis.matrix(),
        deltas.reshape(F, M * D),
        mask=confidence,
        dims=D,
        lower=basis.lower if lower is None else lower,
        upper=basis.upper if upper is None else upper,
        locks=locks,
        regions=regions,
        regularisation=options.regularisation,
        sparsity=options.sparsity,
        symmetry=pairs,
        symmetry_weight=options.symmetry,
        smoothing=tuple(options.smoothing),
        relative=True,
        start=start,
        max_iter=max_iter,
        exact=exact,
    )
