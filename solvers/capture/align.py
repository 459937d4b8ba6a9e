"""Actor -> character alignment: similarity fit of the actor's neutral onto the bound points,
optionally per region (upper / lower face) with separate scales, with per-marker residuals and
the bindings whose residual stands out flagged by name."""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError
from ..transforms import fit_similarity
from .normalise import match_landmarks

#: ``[align] regions = true``: the upper face (brows, eyes, nose, forehead); the rest is the lower face
UPPER_FACE = ("*brow*", "*forehead*", "*eye*", "*temple*", "*nose*", "*nostril*", "head_*", "*cheekbone*",
              "*glabella*", "*lid*")


@dataclass(frozen=True, eq=False)
class Alignment:
    """Similarity per marker (global, or that of the marker's region): x_char = s R x_actor + t.

    ``scale``/``rotation``/``translation`` are the global fit (over every marker); ``regions`` maps
    a region name to (Similarity, marker indices); ``residual`` (M,) is each marker's distance from
    its bound point after the alignment (metres); ``flagged`` the names whose residual stands out.
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    scales: np.ndarray  # (M,)
    rotations: np.ndarray  # (M, 3, 3)
    translations: np.ndarray  # (M, 3)
    regions: dict
    residual: np.ndarray
    flagged: tuple = ()

    def apply(self, points):
        return self.scales[:, None] * np.einsum("mij,mj->mi", self.rotations, points) + self.translations

    def apply_vectors(self, vectors):
        """s_m R_m v for displacements ``vectors`` (..., M, 3) (no translation)."""
        return self._map_vectors(vectors, inverse=False)

    def inverse_vectors(self, vectors):
        """Map displacements back (the inverse of :meth:`apply_vectors`)."""
        return self._map_vectors(vectors, inverse=True)

    def _map_vectors(self, vectors, *, inverse):
        # Markers share a similarity (the global fit, or their region's): one (K, 3) @ (3, 3)
        # product per distinct similarity rather than a 3x3 product per sample.
        v = np.asarray(vectors, dtype=np.float64)
        sims = np.concatenate([self.scales[:, None], self.rotations.reshape(-1, 9)], axis=1)
        _, first, group = np.unique(sims, axis=0, return_index=True, return_inverse=True)
        out = None if first.size == 1 else np.empty(np.broadcast_shapes(v.shape, self.translations.shape))
        for g, m in enumerate(first):
            idx = np.flatnonzero(group.reshape(-1) == g)
            part = v if out is None else np.take(v, idx, axis=-2)
            scale, rot = self.scales[m], self.rotations[m]
            mapped = part @ (rot / scale if inverse else rot.T * scale)
            if out is None:
                return mapped
            out[..., idx, :] = mapped
        return out

    def report(self, names):
        return {
            "scale": self.scale,
            "regions": {k: {"scale": round(sim.scale, 6), "markers": [names[i] for i in idx]}
                        for k, (sim, idx) in self.regions.items()},
            "residual_mm": {n: round(float(v) * 1e3, 4) for n, v in zip(names, self.residual)},
            "flagged": list(self.flagged),
        }


def region_patterns(regions):
    """``[align] regions``: True -> upper/lower face; a dict name -> patterns as given; False/None -> ()."""
    if regions is True:
        return (("upper", UPPER_FACE), ("lower", ("*",)))
    if not regions:
        return ()
    return tuple((name, tuple(p)) for name, p in dict(regions).items())


def align_actor(neutral, bound, names, *, regions=(), flag_mm=None):
    """Align the actor's neutral (M, 3) onto the bound points (M, 3) of the character.

    Parameters
    ----------
    regions : ((name, patterns), ...) in priority order; a marker belongs to the first region whose
        patterns match it. Markers in no region use the global fit. Each region needs >= 3 markers.
    flag_mm : residual (mm) above which a binding is flagged; default: median + 5 robust sigmas
        of the residuals, and at least 2 mm.

    Returns
    -------
    Alignment
    """
    neutral = np.asarray(neutral, dtype=np.float64)
    bound = np.asarray(bound, dtype=np.float64)
    M = len(names)
    glob_fit = fit_similarity(neutral, bound)
    scales = np.full(M, glob_fit.scale)
    rots = np.broadcast_to(glob_fit.rotation, (M, 3, 3)).copy()
    trans = np.broadcast_to(glob_fit.translation, (M, 3)).copy()
    taken = np.zeros(M, dtype=bool)
    fits = {}
    for name, patterns in regions:
        members = set(match_landmarks(names, patterns))
        idx = np.array([i for i, n in enumerate(names) if n in members and not taken[i]], dtype=int)
        if idx.size == 0:
            continue
        if idx.size < 3:
            raise FacecapError(f"align: region '{name}' has only {idx.size} marker(s) "
                               f"{[names[i] for i in idx]}; a similarity needs 3")
        sim = fit_similarity(neutral[idx], bound[idx])
        scales[idx], rots[idx], trans[idx] = sim.scale, sim.rotation, sim.translation
        taken[idx] = True
        fits[name] = (sim, idx)
    aligned = scales[:, None] * np.einsum("mij,mj->mi", rots, neutral) + trans
    residual = np.linalg.norm(aligned - bound, axis=1)
    if flag_mm is None:
        med = np.median(residual)
        limit = max(med + 5 * 1.4826 * np.median(np.abs(residual - med)), 2e-3)
    else:
        limit = flag_mm * 1e-3
    flagged = tuple(n for n, r in zip(names, residual) if r > limit)
    return Alignment(glob_fit.scale, glob_fit.rotation, glob_fit.translation, scales, rots, trans, fits,
                     residual, flagged)
