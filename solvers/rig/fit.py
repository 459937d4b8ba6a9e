"""A ``RigModel`` fitted to probes of a rig: least squares on the model's regressors."""

import numpy as np

from ..errors import FacecapError
from .model import RigModel, factors, halves


def features(u, pairs, kink=None, pair_sides=None):
    """The model's regressors for offsets ``u`` (N, C): [p, p^2, p^3, n, n^2, n^3 (split controls
    only), f_a f_b] -> (N, 3C + 3 S + Q); without splits and sides, [u, u^2, u^3, u_a u_b]."""
    u = np.atleast_2d(np.asarray(u, dtype=np.float64))
    C = u.shape[1]
    kink = np.zeros(C) if kink is None else np.asarray(kink, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    sides = np.zeros(pairs.shape, dtype=np.intp) if pair_sides is None else np.asarray(pair_sides).reshape(-1, 2)
    p, n, _, _ = halves(u, kink)
    split = kink > 0
    fa, _ = factors(u[:, pairs[:, 0]], kink[pairs[:, 0]], sides[:, 0])
    fb, _ = factors(u[:, pairs[:, 1]], kink[pairs[:, 1]], sides[:, 1])
    return np.hstack([p, p * p, p * p * p, n[:, split], (n * n)[:, split], (n * n * n)[:, split], fa * fb])


def fit_model(control_names, marker_names, neutral, offsets, deltas, *, pairs=(), rest, lower, upper, ridge=1e-9,
              kink=None, pair_sides=None):
    """Fit a ``RigModel`` to probes of a rig.

    Parameters
    ----------
    offsets : ndarray (N, C), the control offsets from rest of each probe
    deltas : ndarray (N, M, D), the bound points' displacement from ``neutral`` the rig gave
    pairs : (Q, 2) control index pairs with a pairwise term (from the rig's drivers, or found by probing)
    ridge : relative ridge on the regressors (keeps controls no probe moved at 0)
    kink : (C,) optional, the blend width of each split control's halves (0: one cubic)
    pair_sides : (Q, 2) optional, the factor of each pair term per control (0, 1 or -1: ``RigModel``);
        with sides, ``pairs`` are kept as given (a pair may come twice, with other sides)

    Returns
    -------
    (RigModel, rms) with ``rms`` the fit's RMS error at the probes (the units of ``deltas``).
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    deltas = np.asarray(deltas, dtype=np.float64)
    N, C = offsets.shape
    if deltas.shape[0] != N:
        raise FacecapError(f"rig probes: {N} control rows but {deltas.shape[0]} evaluated poses")
    if not np.isfinite(deltas).all():
        raise FacecapError("rig probes: the rig gave non-finite bound points")
    if pair_sides is None:
        pairs = np.array(sorted({(min(a, b), max(a, b)) for a, b in pairs if a != b}), dtype=np.intp).reshape(-1, 2)
        pair_sides = np.zeros(pairs.shape, dtype=np.intp)
    else:
        pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
        pair_sides = np.asarray(pair_sides, dtype=np.intp).reshape(-1, 2)
    kink = np.zeros(C) if kink is None else np.asarray(kink, dtype=np.float64)
    X = features(offsets, pairs, kink, pair_sides)
    Y = deltas.reshape(N, -1)
    scale = np.sqrt(np.mean(X * X, axis=0)) + 1e-300
    Xs = X / scale
    G = Xs.T @ Xs
    G[np.diag_indices_from(G)] += ridge * max(np.trace(G) / len(G), 1e-300)
    coef = np.linalg.solve(G, Xs.T @ Y) / scale[:, None]
    rms = float(np.sqrt(np.mean((X @ coef - Y) ** 2)))
    _, M, D = deltas.shape
    split = np.flatnonzero(kink > 0)
    S, Q = len(split), len(pairs)
    part = [coef[k * C:(k + 1) * C].reshape(C, M, D) for k in range(3)]
    negative = np.zeros((3, C, M, D))
    for k in range(3):
        negative[k, split] = coef[3 * C + k * S:3 * C + (k + 1) * S].reshape(S, M, D)
    model = RigModel(control_names, marker_names, neutral, *part, pairs, coef[3 * C + 3 * S:].reshape(Q, M, D), rest,
                     lower, upper, negative, kink, pair_sides)
    return model, rms
