"""The weight solve shared by every strategy: bounded, regularised, sparse, smooth least squares.

For frames f = 0..F-1 with observed coordinates d_f (P,), basis A (P, K) and weights w_f (K,)::

    minimise  sum_f  sum_p c_fp (A w_f - d_f)_p^2            data, c = confidence (0 = gap)
                   + w_f' R w_f                               R = regularisation + symmetry
                   + sum_k l1_k |w_fk|                        sparsity
                   + mu1 ||w_f - w_(f-1)||^2                  smoothing (first difference)
                   + mu2 ||w_(f+1) - 2 w_f + w_(f-1)||^2      smoothing (second difference)
    subject to  lo_fk <= w_fk <= hi_fk,  w_fk = lock_fk where a shape is locked.

In the notation of issue 3, ``c = W_f^2`` (a confidence multiplies the *squared* residual) and
``R = lambda2 G'G`` (``regularisation`` is that matrix, or its diagonal, or a scalar times I).

With ``smoothing == (0, 0)`` frames are independent and solved together by the batched
active-set kernel of ``engine.frames``; otherwise the whole take is one problem, solved by
``engine.temporal`` (active set over the take, banded Cholesky of the block-pentadiagonal system).
"""

import numpy as np

from ..errors import FacecapError
from ..options import default
from . import setup
from .frames import exact_frame, solve_frames  # noqa: F401  (re-exported for tests)
from .result import SolveResult  # noqa: F401  (the facade's result type)

#: Default smoothing (mu1, mu2) for ``relative=True``, in units of the basis scale (see ``basis_scale``).
#: Chosen by ``tests/core/test_engine_temporal.py``: a 3-frame lip closure at 60 fps keeps >= 90 % of
#: its peak while the second-difference jitter of a noisy take drops by >= 50 %.
DEFAULT_SMOOTHING = default("solve.smoothing")

#: Ridge floor, relative to the basis scale, added to every solve so unobservable shapes stay at
#: their smallest-norm value instead of making the system singular.
RIDGE_FLOOR = 1e-12


def basis_scale(A):
    """Mean squared column norm of ``A``: the unit of every penalty when ``relative=True``."""
    A = np.asarray(A, dtype=np.float64)
    return float(np.mean(np.einsum("pk,pk->k", A, A))) or 1.0


def solve_bounded(
    A,
    D,
    *,
    mask=None,
    lower=0.0,
    upper=1.0,
    regularisation=0.0,
    sparsity=0.0,
    locks=None,
    regions=None,
    symmetry=(),
    symmetry_weight=0.0,
    smoothing=(0.0, 0.0),
    relative=False,
    dims=None,
    max_iter=None,
    chunk=4096,
    start=None,
    exact=True,
):
    """Solve the bounded, regularised least-squares problem of the module docstring.

    Parameters
    ----------
    A : ndarray, shape (P, K)
        Basis matrix: column k is shape k's effect on the P observed coordinates.
    D : ndarray, shape (F, P)
        Observed coordinates (deltas from neutral); NaN entries are missing (confidence 0).
    mask : ndarray, optional
        Confidence c >= 0 per coordinate, multiplying the squared residual; 0 drops it.
        Shape (F, P) or (P,); with ``dims`` also (F, M) or (M,) per marker (P = M * dims).
        Default: 1 where D is finite.
    lower, upper : float, ndarray (K,) or (F, K)
        Bounds on the weights (default [0, 1], the shape-key slider range).
    regularisation : float, ndarray (K,) or (K, K)
        Ridge ``R``: a scalar (R = r I), per-shape weights (R = diag(r), i.e. lambda2 * g_k^2
        for a diagonal G), or a symmetric positive semi-definite matrix (lambda2 G'G). With
        ``regions``, cross terms between shapes of different regions are ignored.
    sparsity : float or ndarray (K,)
        L1 weight ``l1_k`` (>= 0). On shapes with lower >= 0 it is a linear term (pulls weights to
        their lower bound); on shapes whose range contains 0 it is the true |w| (an extra
        "kink" state at 0 in the active set).
    locks : mapping {k: value}, ndarray (K,) or (F, K), optional
        Shapes held at the given values (NaN = free). (F, K) holds per-frame values, e.g. an
        animator's keys. Locked values are held exactly, even outside [lower, upper].
    regions : sequence of (shapes, coords), optional
        Each region solves its shapes (indices into K) from its coordinates only (indices into
        P, or a boolean (P,) mask). Regions must not share shapes. Shapes in no region never
        move: they are held at their lock value or, if unlocked, at clip(0, lower, upper). The
        known contribution of held/locked shapes is subtracted from every region's data; the
        shapes of other regions are not seen by a region.
    symmetry : sequence of (a, b) shape index pairs
        Left/right pairs coupled by ``symmetry_weight * (w_a - w_b)^2`` (same region required).
    symmetry_weight : float
    smoothing : (mu1, mu2)
        Temporal weights of the first and second difference. (0, 0) = independent frames.
        Anything else solves the whole take as one problem (frames without data are bridged).
        ``DEFAULT_SMOOTHING`` holds a tested default for ``relative=True``.
    relative : bool
        If True, ``regularisation``, ``sparsity``, ``symmetry_weight`` and ``smoothing`` are in
        units of ``basis_scale(A)`` (mean squared column norm), hence unit-free: the same values
        work for millimetre and metre rigs. If False (default, backward compatible) they are
        absolute, in the units of A'A.
    dims : int, optional
        Coordinates per marker (2 or 3), needed only for per-marker ``mask`` shapes.
    max_iter : int, optional
        Active-set iterations before the exact fallback (per-frame; default 40) or before giving
        up (temporal: ``converged=False`` and a warning; default 200: its late iterations only
        re-solve windows around the changes, and a degenerate problem, such as L1 at 0 on shapes
        the markers barely see, can need 100-200 of them).
    chunk : int
        Frames per batch in per-frame mode (memory ~ chunk * K * K floats).
    start : ndarray (F, K), optional
        Weights of an earlier solve of similar data (e.g. the same take before a head refit; NaN =
        none): the active-set iterations start from them. Only the work changes, not the result
        (the optimum is unique up to the tolerances above); should the whole-take iteration not
        settle from it, it starts again from its own per-frame guess.
    exact : bool
        Per-frame mode: False keeps, for frames whose active set has not settled within
        ``max_iter``, the last iterate clipped to the bounds instead of handing them to the exact
        fallback. With a small ``max_iter`` this is a quick near-optimal prediction (the pipeline's
        head refits use it); temporal solves are always exact.

    Returns
    -------
    SolveResult

    Notes
    -----
    A ridge floor of ``RIDGE_FLOOR * basis_scale(A)`` is always added to R so that shapes the
    markers cannot see get a unique (smallest-norm) value.
    """
    prob = setup.build_problem(
        A, D, mask=mask, lower=lower, upper=upper, regularisation=regularisation, sparsity=sparsity,
        locks=locks, regions=regions, symmetry=symmetry, symmetry_weight=symmetry_weight,
        smoothing=smoothing, relative=relative, dims=dims, max_iter=max_iter, chunk=chunk,
    )
    if start is not None:
        start = np.asarray(start, dtype=np.float64)
        if start.shape != (prob.D.shape[0], prob.A.shape[1]):
            raise FacecapError(f"`start` must have shape (F, K) = {(prob.D.shape[0], prob.A.shape[1])}; got {start.shape}")
    return setup.run(prob, max_iter=max_iter, chunk=chunk, start=start, exact=exact)
