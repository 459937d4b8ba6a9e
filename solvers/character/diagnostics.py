"""Solve diagnostics, pure numpy: residual statistics and basis conditioning.

``basis_warnings`` names shapes that the available markers cannot tell apart, one line each, ending in
what to do: "mouthLeft and jawLeft move these markers the same way, so their weights trade off; lock
the one you do not need: [solve] locks = { jawLeft = 0 }".
"""

from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class ResidualStats:
    """frame_rms : (F,) RMS residual per observed marker (NaN where nothing observed);
    marker_rms : (M,) RMS residual per marker over the frames it was observed (NaN if never);
    at_bound : (F,) weights at a bound (copied from the solve)."""

    frame_rms: np.ndarray
    marker_rms: np.ndarray
    at_bound: np.ndarray


def residual_stats(result, *, dims=3, observed=None):
    """Per-frame and per-marker residual RMS of a ``SolveResult``.

    Parameters
    ----------
    result : SolveResult, residuals (F, P) with P = M * dims
    dims : int, coordinates per marker
    observed : (F, P) or (F, M) bool, optional. Default: coordinates with a non-zero residual
        or (more robustly) pass the solve's confidence > 0.
    """
    R = np.asarray(result.residuals, dtype=float)
    F, P = R.shape
    if P % dims:
        raise FacecapError(f"`dims`={dims} does not divide the {P} residual coordinates")
    M = P // dims
    sq = (R.reshape(F, M, dims) ** 2).sum(axis=2)
    if observed is None:
        seen = sq > 0
    else:
        obs = np.asarray(observed, dtype=bool)
        if obs.shape == (F, P):
            seen = obs.reshape(F, M, dims).any(axis=2)
        elif obs.shape == (F, M):
            seen = obs
        else:
            raise FacecapError(f"`observed` must have shape ({F}, {P}) or ({F}, {M}); got {obs.shape}")
    with np.errstate(invalid="ignore", divide="ignore"):
        frame = np.sqrt(np.where(seen, sq, 0).sum(1) / seen.sum(1))
        marker = np.sqrt(np.where(seen, sq, 0).sum(0) / seen.sum(0))
    return ResidualStats(frame, marker, np.asarray(result.at_bound))


@dataclass(frozen=True, eq=False)
class Conditioning:
    """cosine : (K, K) |cosine| between weighted basis columns;
    singular_values : singular values of the column-normalised weighted basis, descending;
    pairs : ((a, b, cosine), ...) above the threshold;
    groups : ((shape indices, relative singular value), ...) spanning near-null directions;
    unseen : shape indices whose column is (almost) zero;
    warnings : tuple of str."""

    cosine: np.ndarray
    singular_values: np.ndarray
    pairs: tuple
    groups: tuple
    unseen: tuple
    warnings: tuple


def basis_conditioning(A, shape_names, mask=None, *, threshold=0.98, rel_singular=1e-2, share=0.95):
    """Find shapes that cannot be told apart from the available markers.

    Parameters
    ----------
    A : (P, K) basis
    shape_names : K names
    mask : (P,) or (F, P) confidence per coordinate, optional (0 = not seen). An (F, P) mask is
        averaged over frames (the visibility of an average frame).
    threshold : |cosine| between two weighted columns above which a pair is reported.
    rel_singular : a singular value of the column-normalised basis below ``rel_singular`` times the
        largest marks a near-null direction; the fewest shapes carrying ``share`` of that direction's
        squared weight are reported together (unless the direction is just an already reported pair).

    Returns
    -------
    Conditioning
    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 2:
        raise FacecapError(f"`A` must have shape (P, K); got {A.shape}")
    P, K = A.shape
    names = list(shape_names)
    if len(names) != K:
        raise FacecapError(f"`shape_names` must have {K} names; got {len(names)}")
    if mask is not None:
        c = np.asarray(mask, dtype=float)
        if c.shape == (P,):
            pass
        elif c.ndim == 2 and c.shape[1] == P:
            c = np.nan_to_num(c).mean(axis=0)
        else:
            raise FacecapError(f"`mask` must have shape ({P},) or (F, {P}); got {c.shape}")
        A = np.sqrt(np.maximum(c, 0))[:, None] * A
    norms = np.linalg.norm(A, axis=0)
    unseen = tuple(int(k) for k in np.flatnonzero(norms <= 1e-9 * max(norms.max(initial=0), 1e-300)))
    seen = np.setdiff1d(np.arange(K), unseen)
    An = A[:, seen] / norms[seen]
    cos = np.zeros((K, K))
    cos[np.ix_(seen, seen)] = np.abs(An.T @ An)
    notes = [f"{names[k]} moves none of these markers, so it stays at its lowest value; to animate it, add a "
             "marker where it moves or key it by hand" for k in unseen]
    pairs = []
    iu = np.triu_indices(K, 1)
    for a, b in zip(*iu):
        if cos[a, b] >= threshold:
            pairs.append((int(a), int(b), float(cos[a, b])))
    for a, b, _ in sorted(pairs, key=lambda p: -p[2]):
        notes.append(f"{names[a]} and {names[b]} move these markers the same way, so their weights trade off; "
                     f"lock the one you do not need: {lock_line([names[b]])}")
    groups = []
    sv = np.zeros(0)
    if seen.size:
        _, sv, Vt = np.linalg.svd(An, full_matrices=False)
        in_pairs = {k for p in pairs for k in p[:2]}
        for s, v in zip(sv, Vt):
            if s >= rel_singular * sv[0]:
                continue
            order = np.argsort(-(v**2))
            n_keep = int(np.searchsorted(np.cumsum(v[order] ** 2), share, side="left")) + 1
            members = tuple(sorted(int(seen[j]) for j in order[:n_keep]))
            if len(members) < 2:
                continue
            groups.append((members, float(s / sv[0])))
            if set(members) <= in_pairs:  # already said, pair by pair
                continue
            main = int(seen[order[0]])  # the shape most of that direction is made of
            notes.append(
                f"{', '.join(names[k] for k in members)} together move these markers almost like fewer shapes "
                f"would, so their weights trade off; lock those you do not need, starting with {names[main]}: "
                f"{lock_line([names[main]])}"
            )
    return Conditioning(cos, sv, tuple(pairs), tuple(groups), unseen, tuple(notes))


def lock_line(shapes, value=0):
    """The take-config line that holds ``shapes`` at ``value``: ``[solve] locks = { jawLeft = 0 }``."""
    return "[solve] locks = { " + ", ".join(f"{_toml_key(s)} = {value:g}" for s in shapes) + " }"


def _toml_key(name):
    return name if name.replace("_", "").replace("-", "").isalnum() and name.isascii() else f'"{name}"'


def basis_warnings(A, shape_names, mask=None, threshold=0.98, **kwargs):
    """Warnings (tuple of str) naming shapes the markers cannot tell apart; see ``basis_conditioning``."""
    return basis_conditioning(A, shape_names, mask, threshold=threshold, **kwargs).warnings
