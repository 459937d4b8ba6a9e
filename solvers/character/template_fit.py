"""The human template's identity and pose fitted to an actor's neutral markers, to convergence.

Unknowns: the similarity that carries the markers onto the template (rotation, translation, log scale) and the
identity coefficients of the template's person. Cost: each marker's point-to-plane distance (mm) from the
person's surface, Cauchy-weighted at a fixed scale (a marker a few mm off the face counts less), plus a ridge
towards the mean face and a prior on the scale: markers and template are both in metres, so a face of another
size is the identity modes' to explain, within what faces vary (``SCALE_SD``), not the similarity's. A fixed
cost with its own minimum: fits from different starts are compared by it, and a converged fit is the same
optimum whatever the arithmetic's rounding (a fixed number of alternations stopped wherever it was, and its
result moved with the numeric library's version).

Solved by Levenberg-Marquardt (a step is kept only when it lowers the cost), the closest points found anew at
every step among each marker's candidate triangles on the mean face (refreshed every ``REFRESH`` steps).
"""

import numpy as np

from ..transforms import Similarity
from .alignment import CAUCHY, rodrigues
from .surface import closest_on_triangles, interpolate, make_surface, nearest_triangles, smooth_normals, vertex_normals

#: Steps at most; the cost's relative decrease below which the fit has settled.
MAX_STEPS, SETTLED = 200, 1e-10
#: The scale (mm) of the Cauchy weights.
SIGMA_MM = 1.0
#: Standard deviation of the log of the similarity's scale around 1 (metres onto metres).
SCALE_SD = np.log(1.1)
#: Candidate triangles per marker (nearest centroids on the person), re-found every ``REFRESH`` steps.
CANDIDATES, REFRESH = 48, 10


def _cauchy(r):
    c = SIGMA_MM * CAUCHY
    return 0.5 * c**2 * np.log1p((r / c) ** 2), 1.0 / (1.0 + (r / c) ** 2)


class _State:
    """The cost and its Jacobian at one point of the unknowns."""

    def __init__(self, model, pc, R, t, log_s, coeffs, candidates, ridge, unit):
        self.R, self.t, self.log_s, self.coeffs = R, t, log_s, coeffs
        verts = model.person(coeffs)
        self.srp = np.exp(log_s) * pc @ R.T
        x = self.srp + t
        tris = model.triangles[candidates]  # (M, k, 3)
        M, k = candidates.shape
        corners = verts[tris.reshape(-1, 3)]
        p = np.repeat(x, k, axis=0)
        q, bary = closest_on_triangles(p, corners[:, 0], corners[:, 1], corners[:, 2])
        d2 = np.sum((p - q) ** 2, axis=1).reshape(M, k)
        best = np.argmin(d2, axis=1)
        rows = np.arange(M) * k + best
        self.tri, self.bary = candidates[np.arange(M), best], bary[rows]
        # normals interpolated from the vertices': no jump between triangles (nor with which of two the rounding of
        # an edge's closest point picks), so the cost is smooth and its minimum the same in every numeric library
        self.n = smooth_normals(vertex_normals(verts, model.triangles), model.triangles, self.tri, self.bary)
        self.r = np.sum(self.n * (x - q[rows]), axis=1) / unit
        cost, self.w = _cauchy(self.r)
        self.cost = float(cost.sum() + 0.5 * ridge * coeffs @ coeffs + 0.5 * (log_s / SCALE_SD) ** 2)


def fit_identity(model, X, start, *, modes, ridge, unit=1e-3):
    """Fit the similarity and ``modes`` identity coefficients of ``model`` (a FaceModel) to markers ``X`` (M, 3,
    metres, all finite) from Similarity ``start`` (markers -> template; its scale near 1: metres onto metres).

    Returns (Similarity, coefficients (modes,), cost, steps taken, settled)."""
    centre = X.mean(axis=0)
    pc = X - centre
    identity = model.identity[:modes]

    def candidates_at(state):
        surface = make_surface(model.person(state.coeffs), model.triangles)
        return nearest_triangles(surface, np.exp(state.log_s) * pc @ state.R.T + state.t, CANDIDATES)

    cand = nearest_triangles(make_surface(model.neutral, model.triangles), start.apply(X), CANDIDATES)
    state = _State(model, pc, start.rotation.copy(), start.apply(centre), np.log(start.scale), np.zeros(modes), cand,
                   ridge, unit)
    mu, settled, step = 1e-3, False, 0
    for step in range(1, MAX_STEPS + 1):
        modes_at = interpolate(identity, model.triangles, state.tri, state.bary)  # (modes, M, 3)
        srp = state.srp / unit
        J = np.concatenate([np.cross(srp, state.n), state.n, np.sum(state.n * srp, axis=1, keepdims=True),
                            -np.einsum("imd,md->mi", modes_at, state.n) / unit], axis=1)
        JW = J * state.w[:, None]
        A = JW.T @ J
        g = JW.T @ state.r
        A[6, 6] += 1.0 / SCALE_SD**2
        g[6] += state.log_s / SCALE_SD**2
        A[7:, 7:] += ridge * np.eye(modes)
        g[7:] += ridge * state.coeffs
        while True:
            delta = -np.linalg.solve(A + mu * np.diag(np.diag(A)), g)
            trial = _State(model, pc, rodrigues(delta[:3]) @ state.R, state.t + delta[3:6] * unit,
                           state.log_s + delta[6], state.coeffs + delta[7:], cand, ridge, unit)
            if trial.cost <= state.cost:
                break
            mu *= 4.0
            if mu > 1e8:  # no step lowers the cost: at the minimum (to the arithmetic's precision)
                trial = None
                break
        if trial is None:
            settled = True
            break
        decrease = (state.cost - trial.cost) / max(state.cost, 1e-300)
        state, mu = trial, max(mu / 3.0, 1e-9)
        if step % REFRESH == 0:
            cand = candidates_at(state)
            state = _State(model, pc, state.R, state.t, state.log_s, state.coeffs, cand, ridge, unit)
        if decrease < SETTLED:
            settled = True
            break
    s = float(np.exp(state.log_s))
    sim = Similarity(s, state.R, state.t - s * state.R @ centre)
    return sim, state.coeffs, state.cost, step, settled
