"""Actors built from a human face model: an identity from its modes and expressions *perturbed*, so that
an actor's face is not the model's (an exact model actor is a best case for any method that knows the
model).

Per expression: a global gain, a smooth per-vertex scale field, a smooth displacement field proportional
to the expression's own motion (its pattern turns by ~15 degrees), and combination terms ``w_i * w_j``
for pairs that real faces correct (jaw with smiles, blinks with squints, ...). Markers sit at a random
point within ~1.5 mm of their layout vertex (a hand-placed marker is never exactly on a vertex).
"""

from dataclasses import dataclass

import numpy as np

#: Pairs of ARKit shapes whose combination a real face does not simply add (corrective terms).
COMBINATIONS = (
    ("jawOpen", "mouthSmileLeft"), ("jawOpen", "mouthSmileRight"), ("jawOpen", "mouthFunnel"),
    ("jawOpen", "mouthPucker"), ("jawOpen", "mouthClose"), ("jawOpen", "mouthStretchLeft"),
    ("jawOpen", "mouthStretchRight"), ("eyeBlinkLeft", "eyeSquintLeft"), ("eyeBlinkRight", "eyeSquintRight"),
    ("mouthSmileLeft", "mouthSmileRight"), ("mouthSmileLeft", "cheekSquintLeft"),
    ("mouthSmileRight", "cheekSquintRight"), ("browInnerUp", "browDownLeft"), ("browInnerUp", "browDownRight"),
)


@dataclass(frozen=True)
class Perturbation:
    """How far an actor's expressions are from the model's. ``none()``: the exact model.

    gain : sigma of each expression's log gain
    scale : sigma of the log of a smooth per-vertex scale field
    displacement : size of a smooth displacement field, relative to the expression's motion at each vertex
    combination : size of the combination terms relative to the two expressions' motion
    length : correlation length of the smooth fields (metres)
    placement : radius (metres) within which a marker is placed around its layout vertex
    identity : sigma of the identity mode coefficients
    """

    gain: float = 0.1
    scale: float = 0.15
    displacement: float = 0.15
    combination: float = 0.25
    length: float = 0.025
    placement: float = 0.0015
    identity: float = 1.0

    @classmethod
    def none(cls, *, identity=1.0):
        return cls(0.0, 0.0, 0.0, 0.0, 0.025, 0.0, identity)


@dataclass(frozen=True, eq=False)
class ActorFace:
    """An actor's face at its markers: ``neutral`` (M, 3), ``deltas`` (K, M, 3) per shape, combination
    terms ``pair_deltas`` (P, M, 3) for the shape index pairs ``pairs`` (P, 2). Metres, facecap axes."""

    names: tuple
    shape_names: tuple
    neutral: np.ndarray
    deltas: np.ndarray
    pairs: np.ndarray
    pair_deltas: np.ndarray
    identity: np.ndarray
    vertex_weights: tuple  # per marker: (vertex indices, weights) on the model

    def positions(self, weights):
        """Marker positions (F, M, 3) for weights (F, K)."""
        w = np.asarray(weights, dtype=np.float64)
        K, M, _ = self.deltas.shape
        out = self.neutral[None] + (w @ self.deltas.reshape(K, -1)).reshape(-1, M, 3)
        if len(self.pairs):
            prod = w[:, self.pairs[:, 0]] * w[:, self.pairs[:, 1]]
            out += (prod @ self.pair_deltas.reshape(len(self.pairs), -1)).reshape(-1, M, 3)
        return out


def smooth_field(rng, points, *, length, n_centres=48, dims=1):
    """A smooth random field at ``points`` (N, 3) with unit RMS: Gaussian bumps of width ``length`` at
    random points with normal amplitudes. Shape (N,) or (N, dims)."""
    centres = points[rng.choice(len(points), size=min(n_centres, len(points)), replace=False)]
    centres = centres + rng.normal(scale=length, size=centres.shape)
    d2 = ((points[:, None, :] - centres[None]) ** 2).sum(axis=2)
    phi = np.exp(-0.5 * d2 / length**2)
    field = phi @ rng.normal(size=(len(centres), dims))
    field /= np.sqrt(np.mean(field**2, axis=0)) + 1e-12
    return field[:, 0] if dims == 1 else field


def marker_support(model, vertices, rng, radius):
    """Per layout vertex, the model vertices and weights of a marker placed within ``radius`` of it."""
    out = []
    for v in vertices:
        if radius <= 0:
            out.append((np.array([v]), np.array([1.0])))
            continue
        d = np.linalg.norm(model.neutral - model.neutral[v], axis=1)
        near = np.flatnonzero(d < 2.5 * radius)
        near = near[np.argsort(d[near], kind="stable")][:8]  # stable: ties the same in every NumPy
        w = rng.dirichlet(np.ones(len(near)))
        w[0] += 1.0  # biased towards the chosen vertex: the offset stays within ~radius
        out.append((near, w / w.sum()))
    return tuple(out)


def make_actor(model, vertices, names, *, seed=0, perturbation=Perturbation()):
    """An actor of ``model`` with markers ``names`` at ``vertices`` (see the module docstring)."""
    rng = np.random.default_rng(seed)
    p = perturbation
    coeffs = rng.normal(scale=p.identity, size=model.identity.shape[0]) if p.identity > 0 \
        else np.zeros(model.identity.shape[0])
    support = marker_support(model, vertices, rng, p.placement)
    used = np.unique(np.concatenate([s[0] for s in support]))
    at = {v: i for i, v in enumerate(used)}
    neutral_v = model.neutral[used] + np.einsum("i,ivd->vd", coeffs, model.identity[:, used])
    deltas_v = model.deltas[:, used].copy()
    K = len(model.shape_names)
    if p.gain or p.scale or p.displacement:
        for k in range(K):
            size = np.linalg.norm(deltas_v[k], axis=1, keepdims=True)
            gain = np.exp(rng.normal(scale=p.gain))
            scale = np.exp(p.scale * smooth_field(rng, neutral_v, length=p.length))[:, None]
            shift = p.displacement * size * smooth_field(rng, neutral_v, length=p.length, dims=3) / np.sqrt(3)
            deltas_v[k] = gain * scale * deltas_v[k] + shift
    pairs, pair_deltas = [], []
    if p.combination:
        index = {n: i for i, n in enumerate(model.shape_names)}
        for a, b in COMBINATIONS:
            if a not in index or b not in index:
                continue
            i, j = index[a], index[b]
            ei, ej = deltas_v[i], deltas_v[j]
            ni, nj = np.linalg.norm(ei, axis=1), np.linalg.norm(ej, axis=1)
            overlap_i, overlap_j = (nj / (nj.max() + 1e-12))[:, None], (ni / (ni.max() + 1e-12))[:, None]
            amount = p.combination * rng.uniform(0.5, 1.0)
            wander = np.sqrt(ni * nj)[:, None] * smooth_field(rng, neutral_v, length=p.length, dims=3) / np.sqrt(3)
            pairs.append((i, j))
            pair_deltas.append(amount * (-0.5 * (ei * overlap_i + ej * overlap_j) + 0.5 * wander))
    gather = np.zeros((len(support), len(used)))
    for m, (vs, ws) in enumerate(support):
        gather[m, [at[v] for v in vs]] = ws
    return ActorFace(
        names=tuple(names), shape_names=model.shape_names, neutral=gather @ neutral_v,
        deltas=np.einsum("mv,kvd->kmd", gather, deltas_v),
        pairs=np.array(pairs, dtype=np.int64).reshape(-1, 2),
        pair_deltas=np.einsum("mv,pvd->pmd", gather, np.array(pair_deltas).reshape(-1, len(used), 3)),
        identity=coeffs, vertex_weights=support)
