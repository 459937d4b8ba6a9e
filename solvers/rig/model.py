"""How the solver sees a rig: the bound points as a quadratic function of the rig's controls.

For control offsets u = c - rest (C,) the bound points move by::

    x(u) = sum_i (u_i L_i + u_i^2 S_i + u_i^3 T_i) + sum_q u_a(q) u_b(q) P_q          (M, D) each

``L`` is the first-order effect of each control, ``S`` and ``T`` its own curvature (a driver's
``s * s`` or smoothstep, a bone's rotation, an in-between shape) and ``P`` the pairwise terms (a corrective or combination
shape firing on ``w_a * w_b``, a product driver, a bone's rotation acting on another's offset).
The model is fitted from probes of the real rig (``fit_model``) or written down directly from
shape keys and their corrective drivers. ``solvers.rig.nonlinear`` solves it; its secant ``basis``
(each control's effect at full range, divided by that range) is what a linear solve sees.
"""

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..character.basis import Basis
from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class RigModel:
    """The bound points of a rig as a quadratic function of its controls.

    Attributes
    ----------
    control_names : tuple of str, length C
    marker_names : tuple of str, length M
    neutral : ndarray (M, D), the bound points with every control at rest
    linear, square, cube : ndarray (C, M, D)
    pairs : ndarray (Q, 2) of control indices (a < b)
    pair_deltas : ndarray (Q, M, D)
    rest, lower, upper : ndarray (C,), the controls' rest values and limits (raw control values)
    """

    control_names: tuple
    marker_names: tuple
    neutral: np.ndarray
    linear: np.ndarray
    square: np.ndarray
    cube: np.ndarray
    pairs: np.ndarray
    pair_deltas: np.ndarray
    rest: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        C, M = len(self.control_names), len(self.marker_names)
        neutral = np.asarray(self.neutral, dtype=np.float64)
        if neutral.ndim != 2 or neutral.shape[0] != M:
            raise FacecapError(f"rig model: neutral must have shape ({M}, D); got {neutral.shape}")
        D = neutral.shape[1]
        pairs = np.asarray(self.pairs, dtype=np.intp).reshape(-1, 2)
        fields = {"neutral": neutral, "pairs": pairs}
        for name, shape in (("linear", (C, M, D)), ("square", (C, M, D)), ("cube", (C, M, D)), ("pair_deltas", (len(pairs), M, D))):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != shape:
                raise FacecapError(f"rig model: {name} must have shape {shape}; got {arr.shape}")
            fields[name] = arr
        for name in ("rest", "lower", "upper"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (C,):
                raise FacecapError(f"rig model: {name} must have shape ({C},); got {arr.shape}")
            fields[name] = arr
        if np.any(fields["lower"] > fields["rest"]) or np.any(fields["rest"] > fields["upper"]):
            bad = [n for n, lo, r, hi in zip(self.control_names, fields["lower"], fields["rest"], fields["upper"])
                   if not lo <= r <= hi]
            raise FacecapError(f"rig model: the rest value of control(s) {bad[:5]} is outside their limits")
        if pairs.size and (pairs.min() < 0 or pairs.max() >= C or np.any(pairs[:, 0] >= pairs[:, 1])):
            raise FacecapError("rig model: pairs must be control index pairs (a, b) with a < b")
        for name, value in fields.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "control_names", tuple(self.control_names))
        object.__setattr__(self, "marker_names", tuple(self.marker_names))

    @property
    def n_controls(self):
        return len(self.control_names)

    @property
    def span(self):
        """(C,) the larger distance from rest to a limit: the probing and secant range of each control."""
        return np.maximum(np.maximum(self.upper - self.rest, self.rest - self.lower), 1e-12)

    def offsets(self, controls):
        """Control values (F, C) -> offsets from rest u (F, C)."""
        return np.asarray(controls, dtype=np.float64) - self.rest

    def controls(self, offsets):
        """Offsets from rest (F, C) -> control values (F, C)."""
        return np.asarray(offsets, dtype=np.float64) + self.rest

    def deltas(self, u):
        """The bound points' displacement (F, M, D) for control offsets ``u`` (F, C)."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C, M, D = self.linear.shape
        flat = u @ self.linear.reshape(C, -1) + (u * u) @ self.square.reshape(C, -1) \
            + (u * u * u) @ self.cube.reshape(C, -1)
        if len(self.pairs):
            prod = u[:, self.pairs[:, 0]] * u[:, self.pairs[:, 1]]
            flat += prod @ self.pair_deltas.reshape(len(self.pairs), -1)
        return flat.reshape(-1, M, D)

    def jacobian(self, u):
        """d deltas / d u at ``u`` (F, C): shape (F, M * D, C)."""
        return self.jacobian_t(u).transpose(1, 2, 0)

    @cached_property
    def _terms(self):
        """(3C + Q, M * D): every fixed vector a column of the Jacobian is a combination of."""
        C = self.n_controls
        return np.vstack([self.linear.reshape(C, -1), self.square.reshape(C, -1), self.cube.reshape(C, -1),
                          self.pair_deltas.reshape(len(self.pairs), self.linear[0].size)])

    def jacobian_t(self, u, dtype=np.float64):
        """The Jacobian control-major, (C, F, M * D) in ``dtype``: column c of frame f is
        L_c + 2 u_c S_c + 3 u_c^2 T_c + sum over c's pairs of the other offset times P_q."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C, M, D = self.linear.shape
        F = u.shape[0]
        coef = np.stack([np.ones_like(u), 2.0 * u, 3.0 * u * u], axis=2).transpose(1, 0, 2).astype(dtype)  # (C, F, 3)
        terms = self._terms.astype(dtype, copy=False)
        own = terms[: 3 * C].reshape(3, C, -1).transpose(1, 0, 2)  # (C, 3, P)
        Jt = np.matmul(coef, own)  # (C, F, P): one small product per control, contiguous per control
        if len(self.pairs):
            P = terms[3 * C:]
            ut = u.astype(dtype, copy=False)
            for c in np.unique(self.pairs):  # d(u_a u_b)/du_c = the other one: a (F, k) @ (k, P) product per control
                rows_a = np.flatnonzero(self.pairs[:, 0] == c)
                rows_b = np.flatnonzero(self.pairs[:, 1] == c)
                other = np.concatenate([self.pairs[rows_a, 1], self.pairs[rows_b, 0]])
                Jt[c] += ut[:, other] @ P[np.concatenate([rows_a, rows_b])]
        return Jt

    def jacobian_t_dot(self, u, v):
        """J(u_f)' v_f for every frame: (F, C), exact in float64 without forming the Jacobian."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C = self.n_controls
        y = np.asarray(v, dtype=np.float64) @ self._terms.T  # (F, 3C + Q)
        out = y[:, :C] + 2.0 * u * y[:, C:2 * C] + 3.0 * u * u * y[:, 2 * C:3 * C]
        if len(self.pairs):
            a, b = self.pairs[:, 0], self.pairs[:, 1]
            yp = y[:, 3 * C:]
            np.add.at(out.T, a, (u[:, b] * yp).T)
            np.add.at(out.T, b, (u[:, a] * yp).T)
        return out

    def secant(self):
        """(C, M, D): each control's displacement at full span (towards its farther limit) / span."""
        t = (self.span * np.where(self.upper - self.rest >= self.rest - self.lower, 1.0, -1.0))[:, None, None]
        return self.linear + self.square * t + self.cube * t * t

    def basis(self):
        """The rig as a linear solve sees it: a ``Basis`` over the control offsets (bounds shifted by rest)."""
        return Basis(self.control_names, self.marker_names, self.neutral, self.secant(),
                     self.lower - self.rest, self.upper - self.rest)

    def subset_markers(self, names):
        """The model at the bound points ``names`` only (in that order)."""
        lookup = {n: i for i, n in enumerate(self.marker_names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise FacecapError(f"rig model: no bound point for marker(s) {missing}")
        idx = [lookup[n] for n in names]
        return RigModel(self.control_names, tuple(names), self.neutral[idx], self.linear[:, idx], self.square[:, idx],
                        self.cube[:, idx], self.pairs, self.pair_deltas[:, idx], self.rest, self.lower, self.upper)

    def is_linear(self, tol=0.0):
        """True when no square or pairwise term exceeds ``tol`` (metres at unit offsets)."""
        curv = [np.abs(a).max(initial=0.0) for a in (self.square, self.cube, self.pair_deltas)]
        return max(curv) <= tol


def features(u, pairs):
    """The model's regressors for offsets ``u`` (N, C): [u, u^2, u^3, u_a u_b] -> (N, 3C + Q)."""
    u = np.atleast_2d(np.asarray(u, dtype=np.float64))
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    return np.hstack([u, u * u, u * u * u, u[:, pairs[:, 0]] * u[:, pairs[:, 1]]])


def fit_model(control_names, marker_names, neutral, offsets, deltas, *, pairs=(), rest, lower, upper, ridge=1e-9):
    """Fit a ``RigModel`` to probes of a rig.

    Parameters
    ----------
    offsets : ndarray (N, C), the control offsets from rest of each probe
    deltas : ndarray (N, M, D), the bound points' displacement from ``neutral`` the rig gave
    pairs : (Q, 2) control index pairs with a pairwise term (from the rig's drivers, or found by probing)
    ridge : relative ridge on the regressors (keeps controls no probe moved at 0)

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
    pairs = np.array(sorted({(min(a, b), max(a, b)) for a, b in pairs if a != b}), dtype=np.intp).reshape(-1, 2)
    X = features(offsets, pairs)
    Y = deltas.reshape(N, -1)
    scale = np.sqrt(np.mean(X * X, axis=0)) + 1e-300
    Xs = X / scale
    G = Xs.T @ Xs
    G[np.diag_indices_from(G)] += ridge * max(np.trace(G) / len(G), 1e-300)
    coef = np.linalg.solve(G, Xs.T @ Y) / scale[:, None]
    rms = float(np.sqrt(np.mean((X @ coef - Y) ** 2)))
    _, M, D = deltas.shape
    Q = len(pairs)
    part = [coef[k * C:(k + 1) * C].reshape(C, M, D) for k in range(3)]
    model = RigModel(control_names, marker_names, neutral, *part, pairs, coef[3 * C:].reshape(Q, M, D), rest, lower,
                     upper)
    return model, rms
