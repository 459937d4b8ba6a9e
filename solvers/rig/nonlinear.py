"""The bounded nonlinear solve of a rig's controls over a whole take: Gauss-Newton on a ``RigModel``.

Over the control offsets u (F, C) of a take::

    minimise  1/2 sum_f sum_p c_fp (x_p(u_f) + e_fp - d_fp)^2       data (x: the model; e: a defect)
              + 1/2 r ||u||^2 + sum l1_k z_fk                         ridge; L1 on one-sided controls
              + 1/2 u' (mu1 D1'D1 + mu2 D2'D2) u                      the engine's temporal term
    subject to lower <= u <= upper, locked offsets held

where z = g(u) is each control's *response* (``RigModel.response``: how much of its full effect it
gives, in the units of its offset; z = u for a control moving the points linearly). The sparsity
acts on what a control does, as it acts on a shape-key weight: on u itself its constant pull would
pin at rest a slider that drives its shape through smoothstep or pow, whose flat start the markers
cannot answer (the ridge's pull vanishes at rest, so it stays on u, where the step is well posed).

with the priors in units of the mean squared column of the model's secant basis, like the linear
engine's ``relative=True``, so the same ``[solve]`` values mean the same thing. A ``RigTarget`` solves
the normalised model (``RigModel.normalised``: each control in units of its span), so that unit is
the mean squared effect of a control moved through its range and the priors weigh every control by
its range, whatever its own units. Started from the
linear solve, each iteration linearises every frame (``RigModel.jacobian``), fixes the controls
held at a bound by their gradient, and solves the damped normal equations of the whole take at
once: frame-major they are a band of width 2C (the temporal term couples frame f with f +- 2), a
banded Cholesky (``scipy.linalg.solveh_banded``). A backtracking step keeps every iterate inside
the bounds and the objective falling. ``e`` carries what the model misses of the real rig, so a
refinement through the rig (``solvers.rig.retarget``) solves the model with the rig's defect at the
current solution (defect correction).
"""

from dataclasses import dataclass

import numpy as np
from numpy.linalg import LinAlgError

from ..engine import basis_scale
from ..engine.threads import single_blas_thread
from ..errors import FacecapError

#: Frames per block when the Jacobian's normal matrices are formed: (block, P, C) temporaries.
BLOCK = 512


@dataclass(frozen=True, eq=False)
class NonlinearResult:
    """offsets (F, C); residual_rms (F,) in the units of the deltas; iterations; converged; the
    objective at the start and the end; how much (share of the objective) the last step lowered it."""

    offsets: np.ndarray
    residual_rms: np.ndarray
    iterations: int
    converged: bool
    cost_start: float
    cost_end: float
    last_drop: float = 0.0


class _Problem:
    def __init__(self, model, deltas, confidence, defect, ridge, l1, temporal, lower, upper, *, hessian=np.float64,
                 reuse=0.0):
        self.model, self.ridge, self.l1, self.temporal = model, ridge, l1, temporal
        self.hessian, self.reuse = hessian, reuse * model.span
        self.H = self.u_at_H = None
        F, M, D = deltas.shape
        seen = np.isfinite(deltas).all(axis=2)
        c = seen.astype(np.float64) if confidence is None else np.where(seen, np.nan_to_num(confidence), 0.0)
        self.c = np.repeat(c, D, axis=1)  # (F, P)
        target = np.nan_to_num(deltas).reshape(F, M * D)
        self.target = target if defect is None else target - np.nan_to_num(defect).reshape(F, M * D)
        self.lower, self.upper = lower, upper

    def residual(self, u):
        with single_blas_thread():
            return self.model.deltas(u).reshape(u.shape[0], -1) - self.target

    def cost(self, u, r=None):
        r = self.residual(u) if r is None else r
        z = self.model.response(u)[0] if self.l1.any() else u
        diag, off1, off2 = self.temporal
        smooth = (diag[:, None] * u * u).sum() + 2 * (off1[:, None] * u[1:] * u[:-1]).sum() \
            + 2 * (off2[:, None] * u[2:] * u[:-2]).sum()
        return 0.5 * float((self.c * r * r).sum() + self.ridge * (u * u).sum() + smooth) + float((self.l1 * z).sum())

    def temporal_mul(self, u):
        diag, off1, off2 = self.temporal
        out = diag[:, None] * u
        out[1:] += off1[:, None] * u[:-1]
        out[:-1] += off1[:, None] * u[1:]
        out[2:] += off2[:, None] * u[:-2]
        out[:-2] += off2[:, None] * u[2:]
        return out

    def normal(self, u, r):
        """Per-frame Gauss-Newton blocks H (F, C, C) and the full gradient (F, C).

        The gradient is exact (float64, without forming the Jacobian). H only steers the step (the
        line search checks the true objective), so it may be formed in float32 and kept for frames
        whose controls moved less than ``reuse`` (of each control's span) since it was formed."""
        F, C = u.shape
        g = self.model.jacobian_t_dot(u, self.c * r) + self.ridge * u + self.temporal_mul(u)
        if self.l1.any():
            g += self.l1 * self.model.response(u)[1]
        if self.H is None:
            self.H, self.u_at_H = np.empty((F, C, C), dtype=self.hessian), u.copy()
            stale = np.arange(F)
        else:
            stale = np.flatnonzero((np.abs(u - self.u_at_H) > self.reuse).any(axis=1))
        for a in range(0, stale.size, BLOCK):
            rows = stale[a:a + BLOCK]
            J = self.model.jacobian_t(u[rows], self.hessian).transpose(1, 0, 2)  # (n, C, P)
            cJ = J * self.c[rows, None, :].astype(self.hessian)
            self.H[rows] = np.matmul(cJ, J.transpose(0, 2, 1))  # batched BLAS, one (C, P) x (P, C) per frame
            self.u_at_H[rows] = u[rows]
        return self.H, g


def _band(H, temporal, free, ridge):
    """The frame-major band (upper form, width 2C) of blockdiag(H) + ridge + T, with the rows and
    columns of held variables replaced by the identity; and the damping's diagonal (F * C,), 0 on
    held variables (``ab[-1] += damping * that`` damps the step)."""
    F, C, _ = H.shape
    diag, off1, off2 = temporal
    width = 2 * C if F > 2 else C
    ab = np.zeros((width + 1, F * C), dtype=H.dtype)
    for k in range(C):  # within a frame: column j couples with row j - k (the k-th diagonal of each block)
        ab[width - k].reshape(F, C)[:, k:] = np.diagonal(H, offset=k, axis1=1, axis2=2)
    main = ab[width].reshape(F, C)
    main += diag[:, None] + ridge
    damp = np.maximum(np.einsum("fii->fi", H), 1e-12 * (np.einsum("fii->", H) / max(F * C, 1)) + 1e-300).reshape(-1)
    if F > 1 and C <= width:
        ab[width - C].reshape(F, C)[1:] += off1[:, None]
    if F > 2:
        ab[width - 2 * C].reshape(F, C)[2:] += off2[:, None]
    keep = free.reshape(-1).astype(ab.dtype)  # a held variable's row and column cleared, 1 on its diagonal
    for k in range(1, width + 1):
        ab[width - k, k:] *= keep[k:] * keep[:-k]  # entry (j - k, j)
    ab[width] = np.where(keep > 0, ab[width], 1.0)
    damp *= keep
    return ab, damp


def _step(solveh_banded, ab, rhs):
    """The Gauss-Newton step: the band's Cholesky solve in the band's precision (float32 halves the
    time of the largest part of an iteration; the line search checks the exact objective), again in
    float64 should float32 find it not positive definite."""
    with single_blas_thread():  # a threaded banded Cholesky is 100x slower on a busy machine
        try:
            return solveh_banded(ab, rhs.astype(ab.dtype), check_finite=False).astype(np.float64)
        except LinAlgError:
            if ab.dtype == np.float64:
                raise
            return solveh_banded(ab.astype(np.float64), rhs, check_finite=False)


def solve_nonlinear(model, deltas, **options):
    """Solve a take's control offsets through the rig model ``model`` (``RigModel``); the options
    are those of ``iterate_nonlinear``. Returns a NonlinearResult."""
    steps = iterate_nonlinear(model, deltas, **options)
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def iterate_nonlinear(model, deltas, *, start, confidence=None, defect=None, locks=None, regularisation=1e-3,
                      sparsity=0.0, smoothing=(0.0, 0.3), max_iter=20, tol=1e-5, hessian=np.float64, reuse=0.0,
                      bounds=None):
    """``solve_nonlinear`` as a generator that yields the iteration number after each Gauss-Newton
    step (so a job can report progress and stop between steps) and returns the NonlinearResult.

    Parameters
    ----------
    deltas : ndarray (F, M, D), the take in the model's space and units (NaN: gaps)
    start : ndarray (F, C), control offsets to start from (the linear solve); NaN rows start at rest
    confidence : ndarray (F, M), optional, trust per marker sample
    defect : ndarray (F, M, D), optional, what the real rig adds to the model at ``start``
    locks : ndarray (C,) or (F, C), optional, offsets held fixed (NaN: free)
    regularisation, sparsity, smoothing : the ``[solve]`` priors, relative to the basis scale
    max_iter, tol : Gauss-Newton iterations at most; stop when the objective falls by less than
        ``tol`` of itself
    bounds : (lower, upper) (C,) raw control values instead of the model's limits
    hessian, reuse : the dtype the Gauss-Newton blocks are formed in, and how far (share of each
        control's span) a frame's controls may move before its block is formed again (0: every
        iteration). The gradient and the objective stay exact float64 either way.

    Returns (from the generator)
    -------
    NonlinearResult
    """
    from scipy.linalg import solveh_banded  # scipy: loaded with the first rig solve, not with the package

    from ..engine.temporal import temporal_operator  # loads scipy (the banded kernels): not with the package

    deltas = np.asarray(deltas, dtype=np.float64)
    F, M, D = deltas.shape
    C = model.n_controls
    if model.neutral.shape != (M, D):
        raise FacecapError(f"rig solve: the take has {M} markers in {D}D but the model {model.neutral.shape}")
    start = np.asarray(start, dtype=np.float64)
    if start.shape != (F, C):
        raise FacecapError(f"rig solve: start must have shape ({F}, {C}); got {start.shape}")
    unit = basis_scale(model.basis().matrix())
    lower, upper = (model.lower, model.upper) if bounds is None else (np.asarray(b, dtype=np.float64) for b in bounds)
    lower, upper = lower - model.rest, upper - model.rest
    l1 = np.where(lower >= 0, float(sparsity) * unit, 0.0)
    mu1, mu2 = (float(v) * unit for v in smoothing)
    temporal = temporal_operator(F, mu1, mu2)
    prob = _Problem(model, deltas, confidence, defect, float(regularisation) * unit + 1e-12 * unit, l1, temporal,
                    lower, upper, hessian=hessian, reuse=reuse)
    held = np.zeros((F, C), dtype=bool)
    lock_values = np.zeros((F, C))
    if locks is not None:
        lk = np.broadcast_to(np.asarray(locks, dtype=np.float64), (F, C))
        held, lock_values = ~np.isnan(lk), np.nan_to_num(lk)
    u = np.clip(np.nan_to_num(start), lower, upper)
    u[held] = lock_values[held]
    r = prob.residual(u)
    cost = cost0 = prob.cost(u, r)
    damping, converged, it, last = 1e-6, False, 0, 0.0
    for it in range(1, max_iter + 1):
        with single_blas_thread():  # small batched products: threads only contend on a busy machine
            H, g = prob.normal(u, r)
        at_lo = (u <= lower + 1e-12) & (g > 0)
        at_hi = (u >= upper - 1e-12) & (g < 0)
        free = ~(held | at_lo | at_hi)
        if not free.any():
            converged = True
            break
        improved = False
        ab, damp = _band(H, temporal, free, prob.ridge)  # built once: a retry only damps its diagonal more
        added = 0.0
        for _ in range(14):  # damping up to 1e5 x its floor: in the end a scaled gradient step
            ab[-1] += (damping - added) * damp
            added = damping
            step = _step(solveh_banded, ab, np.where(free, -g, 0.0).reshape(-1)).reshape(F, C)
            for alpha in (1.0, 0.5, 0.25):
                trial = np.clip(u + alpha * step, lower, upper)
                trial[held] = lock_values[held]
                r_trial = prob.residual(trial)
                c_trial = prob.cost(trial, r_trial)
                if c_trial < cost:
                    improved = True
                    break
            if improved:
                damping = max(damping / 4, 1e-9)
                break
            damping *= 10
        if not improved:
            converged = True
            break
        drop = cost - c_trial
        u, r, cost = trial, r_trial, c_trial
        last = drop / max(cost, 1e-300)
        yield it
        if drop <= tol * max(cost, 1e-300):
            converged = True
            break
    seen = (prob.c > 0).reshape(F, M, D)[:, :, 0]
    sq = ((r.reshape(F, M, D) ** 2).sum(axis=2) * seen).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq / seen.sum(axis=1))
    return NonlinearResult(u, rms, it, converged, cost0, cost, last)
