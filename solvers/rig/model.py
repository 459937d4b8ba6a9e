"""How the solver sees a rig: the bound points as a polynomial function of the rig's controls.

For control offsets u = c - rest (C,) the bound points move by::

    x(u) = sum_i (p_i L_i + p_i^2 S_i + p_i^3 T_i) + (n_i N1_i + n_i^2 N2_i + n_i^3 N3_i)
           + sum_q f_a(q) f_b(q) P_q                                                     (M, D) each

For most controls p_i = u_i and n_i = 0: a cubic. ``L`` is the first-order effect of each control,
``S`` and ``T`` its own curvature (a driver's ``s * s`` or smoothstep, a bone's rotation, an
in-between shape) and ``P`` the pairwise terms (a corrective or combination shape firing on
``w_a * w_b``, a product driver, a bone's rotation acting on another's offset), f = u. A control
whose two sides act differently (a joystick moving one shape up and another down, each through
its own curve) is *split*: p_i and n_i are its positive and negative halves (``halves``: blended
over a width ``kink_i`` about rest, so the model stays smooth) with a cubic each, and a pair
term's factor f may be either half (a corrective on "jaw down x smile" is the product of the
jaw's negative half and the smile's positive half).

The model is fitted from probes of the real rig (``fit_model``) or written down directly from
shape keys and their corrective drivers. ``solvers.rig.nonlinear`` solves it; its secant ``basis``
(each control's effect at the end of its range that moves the points most, divided by that
offset) is what a linear solve sees.
"""

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..character.basis import Basis
from ..errors import FacecapError


def halves(u, kink):
    """(p, n, dp, dn): the positive and negative halves of offsets ``u`` (F, C) (p + n = u), blended
    over ``kink`` (C,) about rest, and their derivatives; where ``kink`` is 0, p = u and n = 0."""
    split = np.flatnonzero(np.asarray(kink) > 0)
    if not split.size:
        return u, np.zeros_like(u), np.ones_like(u), np.zeros_like(u)
    p, dp = u.copy(), np.ones_like(u)
    us, eps = u[..., split], np.asarray(kink)[split]
    root = np.sqrt(us * us + eps * eps)
    p[..., split] = 0.5 * (us + root - eps)
    dp[..., split] = 0.5 * (1.0 + us / root)
    return p, u - p, dp, 1.0 - dp


def factors(u, kink, sides):
    """(f, df) (F, Q): the pair-term factor of side ``sides`` (Q,) (0: the offset, 1: its positive half, -1:
    its negative half) for the control of each column of ``u`` (F, Q)."""
    p, n, dp, dn = halves(u, kink)
    f = np.where(sides > 0, p, np.where(sides < 0, n, u))
    df = np.where(sides > 0, dp, np.where(sides < 0, dn, 1.0))
    return f, df


@dataclass(frozen=True, eq=False)
class RigModel:
    """The bound points of a rig as a polynomial function of its controls.

    Attributes
    ----------
    control_names : tuple of str, length C
    marker_names : tuple of str, length M
    neutral : ndarray (M, D), the bound points with every control at rest
    linear, square, cube : ndarray (C, M, D), the cubic (the positive half's, for a split control)
    pairs : ndarray (Q, 2) of control indices (a < b)
    pair_deltas : ndarray (Q, M, D)
    rest, lower, upper : ndarray (C,), the controls' rest values and limits (raw control values)
    negative : ndarray (3, C, M, D), optional: the negative half's cubic of split controls (else 0)
    kink : ndarray (C,), optional: the width (offset units) over which a split control's halves
        blend; 0 (the default): one cubic
    pair_sides : ndarray (Q, 2), optional: the factor of each pair term per control: 0 the offset
        (the default), 1 / -1 its positive / negative half
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
    negative: np.ndarray = None
    kink: np.ndarray = None
    pair_sides: np.ndarray = None

    def __post_init__(self):
        C, M = len(self.control_names), len(self.marker_names)
        neutral = np.asarray(self.neutral, dtype=np.float64)
        if neutral.ndim != 2 or neutral.shape[0] != M:
            raise FacecapError(f"rig model: neutral must have shape ({M}, D); got {neutral.shape}")
        D = neutral.shape[1]
        pairs = np.asarray(self.pairs, dtype=np.intp).reshape(-1, 2)
        Q = len(pairs)
        fields = {"neutral": neutral, "pairs": pairs}
        negative = np.zeros((3, C, M, D)) if self.negative is None else self.negative
        kink = np.zeros(C) if self.kink is None else self.kink
        sides = np.zeros((Q, 2)) if self.pair_sides is None else self.pair_sides
        for name, value, shape in (("linear", self.linear, (C, M, D)), ("square", self.square, (C, M, D)),
                                   ("cube", self.cube, (C, M, D)), ("pair_deltas", self.pair_deltas, (Q, M, D)),
                                   ("negative", negative, (3, C, M, D)), ("kink", kink, (C,))):
            arr = np.asarray(value, dtype=np.float64)
            if arr.shape != shape:
                raise FacecapError(f"rig model: {name} must have shape {shape}; got {arr.shape}")
            fields[name] = arr
        fields["pair_sides"] = np.asarray(sides, dtype=np.intp).reshape(Q, 2)
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
        if np.any(np.abs(fields["pair_sides"]) > 1) or np.any(fields["kink"] < 0):
            raise FacecapError("rig model: pair sides must be -1, 0 or 1 and kinks >= 0")
        for name, value in fields.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "control_names", tuple(self.control_names))
        object.__setattr__(self, "marker_names", tuple(self.marker_names))

    @property
    def n_controls(self):
        return len(self.control_names)

    @property
    def split(self):
        """(C,) bool: the controls whose two sides have a cubic each."""
        return self.kink > 0

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

    @cached_property
    def _terms(self):
        """(6C + Q, M * D): every fixed vector a column of the Jacobian is a combination of."""
        C = self.n_controls
        own = [self.linear, self.square, self.cube, *self.negative]
        return np.vstack([a.reshape(C, -1) for a in own] + [self.pair_deltas.reshape(len(self.pairs), self.linear[0].size)])

    def _pair_factors(self, u):
        """(fa, dfa, fb, dfb) (F, Q) of the pair terms at offsets ``u``."""
        out = []
        for k in (0, 1):
            c, sides = self.pairs[:, k], self.pair_sides[:, k]
            f, df = u[:, c], np.ones((u.shape[0], len(c)))
            halved = np.flatnonzero(sides)  # the others: the offset itself
            if halved.size:
                f[:, halved], df[:, halved] = factors(f[:, halved], self.kink[c[halved]], sides[halved])
            out += [f, df]
        return tuple(out)

    def deltas(self, u):
        """The bound points' displacement (F, M, D) for control offsets ``u`` (F, C)."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C, M, D = self.linear.shape
        T = self._terms
        p, n, _, _ = halves(u, self.kink)
        flat = p @ T[:C] + (p * p) @ T[C:2 * C] + (p * p * p) @ T[2 * C:3 * C]
        if self.split.any():
            flat += n @ T[3 * C:4 * C] + (n * n) @ T[4 * C:5 * C] + (n * n * n) @ T[5 * C:6 * C]
        if len(self.pairs):
            fa, _, fb, _ = self._pair_factors(u)
            flat += (fa * fb) @ T[6 * C:]
        return flat.reshape(-1, M, D)

    def jacobian(self, u):
        """d deltas / d u at ``u`` (F, C): shape (F, M * D, C)."""
        return self.jacobian_t(u).transpose(1, 2, 0)

    def _own_coefficients(self, u):
        """(F, C, 3 or 6): what multiplies each own term in the Jacobian's column of its control."""
        p, n, dp, dn = halves(u, self.kink)
        cols = [dp, 2.0 * p * dp, 3.0 * p * p * dp]
        if self.split.any():
            cols += [dn, 2.0 * n * dn, 3.0 * n * n * dn]
        return np.stack(cols, axis=2)

    def jacobian_t(self, u, dtype=np.float64):
        """The Jacobian control-major, (C, F, M * D) in ``dtype``: column c of frame f is the
        derivative of c's own cubic(s) plus, for each of c's pairs, the derivative of its factor
        times the other factor times P_q."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C = self.n_controls
        coef = self._own_coefficients(u).transpose(1, 0, 2).astype(dtype)  # (C, F, k)
        k = coef.shape[2]
        terms = self._terms.astype(dtype, copy=False)
        own = terms[: k * C].reshape(k, C, -1).transpose(1, 0, 2)  # (C, k, P)
        Jt = np.matmul(coef, own)  # (C, F, P): one small product per control, contiguous per control
        if len(self.pairs):
            P = terms[6 * C:]
            fa, dfa, fb, dfb = (x.astype(dtype, copy=False) for x in self._pair_factors(u))
            for c in np.unique(self.pairs):  # a (F, k) @ (k, P) product per control
                rows_a = np.flatnonzero(self.pairs[:, 0] == c)
                rows_b = np.flatnonzero(self.pairs[:, 1] == c)
                weight = np.concatenate([dfa[:, rows_a] * fb[:, rows_a], fa[:, rows_b] * dfb[:, rows_b]], axis=1)
                Jt[c] += weight @ P[np.concatenate([rows_a, rows_b])]
        return Jt

    def jacobian_t_dot(self, u, v):
        """J(u_f)' v_f for every frame: (F, C), exact in float64 without forming the Jacobian."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        C = self.n_controls
        y = np.asarray(v, dtype=np.float64) @ self._terms.T  # (F, 6C + Q)
        coef = self._own_coefficients(u)
        k = coef.shape[2]
        out = np.einsum("fck,fkc->fc", coef, y[:, : k * C].reshape(len(u), k, C))
        if len(self.pairs):
            a, b = self.pairs[:, 0], self.pairs[:, 1]
            fa, dfa, fb, dfb = self._pair_factors(u)
            yp = y[:, 6 * C:]
            np.add.at(out.T, a, (dfa * fb * yp).T)
            np.add.at(out.T, b, (fa * dfb * yp).T)
        return out

    def along(self, i, t):
        """(len(t), M, D): the bound points' displacement with control ``i`` alone at offsets ``t``."""
        u = np.zeros((len(t), self.n_controls))
        u[:, i] = t
        return self.deltas(u)

    @cached_property
    def _response(self):
        """(C, 2, 3): the cubic coefficients of each control's response ``response`` on its positive
        (or only) and negative half: t_end <x(t), x(t_end)> / |x(t_end)|^2 for the end t_end of
        that side (for an unsplit control, the secant's end)."""
        C = self.n_controls
        hi, lo = self.upper - self.rest, self.lower - self.rest
        out = np.zeros((C, 2, 3))
        out[:, :, 0] = 1.0  # a control that moves nothing, or not steadily one way: its offset
        secant_end = self.secant_ends()
        largest = max(float(np.sum(self.along(i, [t]) ** 2)) for i in range(C) for t in (hi[i], lo[i]))
        for i in range(C):
            sides = ((0, hi[i], (self.linear, self.square, self.cube)), (1, lo[i], tuple(self.negative))) \
                if self.split[i] else ((0, secant_end[i], (self.linear, self.square, self.cube)),)
            for k, end, terms in sides:
                e = self.along(i, [end])[0].ravel() if end != 0 else np.zeros(1)
                norm = float(e @ e)
                if norm <= 1e-9 * largest:  # unseen (a fit of noise): its offset
                    continue
                a = np.array([end * float(t[i].ravel() @ e) / norm for t in terms])
                t = np.linspace(0.0, end, 33)
                slope = (a[0] + 2 * a[1] * t + 3 * a[2] * t * t) * np.sign(end)
                if slope.min() >= -0.05 * abs(a[0] + a[1] * end + a[2] * end * end):  # rising towards the end
                    out[i, k] = a
        return out

    def response(self, u):
        """(z, dz) (F, C): how much of its full effect each control gives at offsets ``u`` (F, C), in
        the units of its offset (z = u for a control moving the points linearly; a smoothstep
        slider's z is its smoothstep), and the derivative. The solve's sparsity acts on z: a control
        is pulled to rest for what it does, like a shape-key weight, not for how far it is turned."""
        u = np.atleast_2d(np.asarray(u, dtype=np.float64))
        a = self._response
        p, n, dp, dn = halves(u, self.kink)
        z = a[:, 0, 0] * p + a[:, 0, 1] * p * p + a[:, 0, 2] * p ** 3
        dz = (a[:, 0, 0] + 2 * a[:, 0, 1] * p + 3 * a[:, 0, 2] * p * p) * dp
        if self.split.any():
            z = z + a[:, 1, 0] * n + a[:, 1, 1] * n * n + a[:, 1, 2] * n ** 3
            dz = dz + (a[:, 1, 0] + 2 * a[:, 1, 1] * n + 3 * a[:, 1, 2] * n * n) * dn
        return z, dz

    def secant_ends(self):
        """(C,) the end of each control's range that moves the points most (the larger limit on a tie)."""
        hi, lo = self.upper - self.rest, self.lower - self.rest
        out = np.zeros(self.n_controls)
        for i in range(self.n_controls):
            ends = [t for t in (hi[i], lo[i]) if t != 0]
            moved = [np.sum(self.along(i, [t]) ** 2) for t in ends]
            out[i] = ends[int(np.argmax(moved))] if ends else 0.0
        return out

    def secant(self):
        """(C, M, D): each control's displacement at the end of its range that moves the points most
        (the larger limit on a tie), divided by that offset: a joystick's side that moves its
        shape most, not an idle one."""
        out = np.zeros_like(self.linear)
        for i, end in enumerate(self.secant_ends()):
            if end != 0:
                out[i] = self.along(i, [end])[0] / end
        return out

    def basis(self):
        """The rig as a linear solve sees it: a ``Basis`` over the control offsets (bounds shifted by rest)."""
        return Basis(self.control_names, self.marker_names, self.neutral, self.secant(),
                     self.lower - self.rest, self.upper - self.rest)

    def normalised(self):
        """The model over v = (c - rest) / span, each control's offset in units of its own span (so
        that its limits are about -1..1 whatever it is: metres, radians, a slider): the solve's priors
        then weigh every control by its range, not by its effect per unit of its own."""
        s = self.span
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        powers = [s[:, None, None] ** k for k in (1, 2, 3)]
        return RigModel(self.control_names, self.marker_names, self.neutral, self.linear * powers[0],
                        self.square * powers[1], self.cube * powers[2], self.pairs,
                        self.pair_deltas * (s[a] * s[b])[:, None, None], np.zeros_like(s),
                        (self.lower - self.rest) / s, (self.upper - self.rest) / s,
                        np.stack([n * w for n, w in zip(self.negative, powers)]), self.kink / s, self.pair_sides)

    def subset_markers(self, names):
        """The model at the bound points ``names`` only (in that order)."""
        lookup = {n: i for i, n in enumerate(self.marker_names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise FacecapError(f"rig model: no bound point for marker(s) {missing}")
        idx = [lookup[n] for n in names]
        return RigModel(self.control_names, tuple(names), self.neutral[idx], self.linear[:, idx], self.square[:, idx],
                        self.cube[:, idx], self.pairs, self.pair_deltas[:, idx], self.rest, self.lower, self.upper,
                        self.negative[:, :, idx], self.kink, self.pair_sides)

    def is_linear(self, tol=0.0):
        """True when no square, cubic, split or pairwise term exceeds ``tol`` (metres at unit offsets)."""
        curv = [np.abs(a).max(initial=0.0) for a in (self.square, self.cube, self.pair_deltas, self.negative)]
        return max(curv) <= tol and not self.split.any()
