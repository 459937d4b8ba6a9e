"""The actor's shapes from a range-of-motion session's poses, estimated together with a prior for every shape
(after Li, Weise & Pauly, "Example-Based Facial Rigging", SIGGRAPH 2010: a generic model and a few of the person's
expressions give the person's own blendshapes; here at the markers, where the expressions are measured).

A natural expression moves several shapes at once, and a shape may be asked in several poses (the jaw opens in
"jaw open", in "oo" and in "closed lips, jaw open"), so a pose is not one shape: with the measured poses ``E``
(J, M, 3), what the sheet asked ``a`` (J, K) and a prior for every shape ``P`` (K, M, 3: the human template
fitted to the actor, or the character's shapes carried to the actor), minimise over the shapes ``B`` (K, M, 3)
and per-shape gains ``g`` (K,)

    sum_j |a_j B - E_j|^2 / s_E^2                   the poses as measured (markers seen in each)
  + sum_k |B_k - g_k P_k|^2 / (ETA rms(P_k))^2       each shape near its prior's direction, at its own size
  + sum_k (g_k - 1)^2 / GAIN_SD^2                    the prior's sizes, loosely

alternating the shapes (a K x K system per pattern of seen markers) and the gains (closed form) until they
settle. Where the poses measure a shape, the data decide it (the prior is weak: ETA); where a combined expression
measures only a sum, the prior splits it, each part at the size the data give its direction; a shape no pose
asks stays the prior's. The weights the performer really gave are not estimated: at the markers they are not
identifiable from the poses (a pose per shape fits any mix exactly), and on the realism benchmark neither
re-estimating them nor the true ones did better than the weights asked (docs/accuracy.md).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError

#: How far (relative to its RMS size at the markers) a shape may be from its prior's direction (weak: the prior
#: splits what the poses measure together, it does not pull what they measure apart), and how far the prior's
#: size may be off.
ETA, GAIN_SD = 2.0, 0.5
#: Alternations at most, and the gains' change below which they have settled.
ITERATIONS, SETTLED = 50, 1e-6
#: The smallest error of a measured pose's coordinate (metres: a held pose is never exactly held); the spread
#: (metres) of a shape the prior does not move: no pull at all.
MIN_ERROR, FREE = 1e-4, 1e-2
#: A shape counts as measured when the poses ask this much of it in all (their weights summed).
MEASURED = 0.5


@dataclass(frozen=True, eq=False)
class JointFit:
    """``shapes`` (K, M, 3) the actor's; ``gains`` (K,) of the prior; ``support`` (K,) the poses' weights
    summed per shape; ``measured`` (K,) bool (``support >= MEASURED``); ``residual`` (J,) each pose's RMS misfit
    (metres)."""

    shapes: np.ndarray
    gains: np.ndarray
    support: np.ndarray
    measured: np.ndarray
    residual: np.ndarray


def fit_examples(measured, asked, prior, *, error=MIN_ERROR):
    """Estimate the actor's shapes from measured poses (see the module docstring).

    Parameters
    ----------
    measured : (J, M, 3) the poses' deltas from the neutral (NaN where a marker was not seen)
    asked : (J, K) the weights the sheet asked of each pose
    prior : (K, M, 3) every shape as the prior knows it (zeros for a shape it lacks)
    error : the measured poses' error per coordinate (metres; at least ``MIN_ERROR``)

    Returns
    -------
    JointFit
    """
    E = np.asarray(measured, dtype=np.float64)
    a = np.asarray(asked, dtype=np.float64)
    P = np.asarray(prior, dtype=np.float64)
    J, M, _ = E.shape
    K = P.shape[0]
    if a.shape != (J, K) or P.shape != (K, M, 3):
        raise FacecapError(f"ROM fit: asked weights {a.shape} and prior {P.shape} do not fit {J} poses of {M} "
                           f"markers and {K} shapes")
    seen = np.isfinite(E).all(axis=2)  # (J, M)
    Ef = np.nan_to_num(E).reshape(J, -1)
    mask = np.repeat(seen, 3, axis=1).astype(np.float64)  # (J, X)
    Pf = P.reshape(K, -1)
    size = np.sqrt(np.mean(Pf**2, axis=1))
    # (K,) how far a shape may stray from its prior's direction; a shape the prior does not move is free
    spread = np.where(size > MIN_ERROR, ETA * size, FREE)
    s_e = max(float(error), MIN_ERROR)
    g = np.ones(K)
    for _ in range(ITERATIONS):
        B = _shapes(Ef, mask, a, Pf * g[:, None], s_e, spread)
        g, before = _gains(B, Pf, spread), g
        if np.abs(g - before).max() < SETTLED:
            break
    B = _shapes(Ef, mask, a, Pf * g[:, None], s_e, spread)
    misfit = (a @ B - Ef) * mask
    residual = np.sqrt((misfit**2).sum(axis=1) / np.maximum(mask.sum(axis=1), 1))
    support = a.sum(axis=0)
    return JointFit(B.reshape(K, M, 3), g, support, support >= MEASURED, residual)


def _shapes(Ef, mask, w, target, s_e, spread):
    """The shapes (K, X) for fixed weights: per coordinate x, (sum_j m_jx w_j w_j^T / s_e^2 + D) B_x =
    sum_j m_jx w_j E_jx / s_e^2 + D target_x, with D = diag(1 / spread^2). Coordinates seen in the same poses
    share their matrix (most markers are seen in every pose): one factorisation per pattern of gaps."""
    D = 1.0 / spread**2
    rhs = (mask * Ef).T @ w / s_e**2 + (D[:, None] * target).T  # (X, K)
    patterns, which = np.unique(mask.T > 0, axis=0, return_inverse=True)
    out = np.empty_like(target)
    for i, seen in enumerate(patterns):
        cols = np.flatnonzero(np.ravel(which) == i)
        A = w[seen].T @ w[seen] / s_e**2 + np.diag(D)
        out[:, cols] = np.linalg.solve(A, rhs[cols].T)
    return out


def _gains(B, Pf, spread):
    """Each shape's gain on its prior: the least-squares size of B_k along P_k, pulled towards 1."""
    prior = 1.0 / GAIN_SD**2
    num = np.sum(B * Pf, axis=1) / spread**2 + prior
    den = np.sum(Pf * Pf, axis=1) / spread**2 + prior
    return num / den
