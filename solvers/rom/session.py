"""A range-of-motion take turned into the actor's measured shapes: its holds found and named by its sheet
(``find_poses``), then the actor's shapes and what each pose gave estimated together (``fit_rom``).

Everything here is in the ROM take's own actor space (stabilised, metres, its neutral); the semantic solve
carries the result onto each later take by a rigid fit of the neutrals, as for any calibration.
"""

import warnings
from dataclasses import dataclass

import numpy as np

from ..capture.noise import MEDIAN_ERROR, marker_noise, shrink_pose_noise
from ..character.aliases import name_key
from ..character.basis import Basis
from ..errors import FacecapError
from .holds import ENTER, TOP, activity_unit, find_holds
from .joint import fit_examples
from .matching import align_holds, cosines
from .sheets import sheet_shapes

#: Frames (s) on each side of a middle the user gave (``[calibration] holds``) when no hold found covers it.
GIVEN_HALF_S = 0.2


@dataclass(frozen=True, eq=False)
class RomPoses:
    """The poses of a ROM take: ``poses`` (the sheet), ``frames`` per pose (first, last) measured or None (not
    found), ``middles`` per pose (NaN: not found), ``score`` per pose (cosine with the prior's prediction, NaN:
    none), ``measured`` (J, M, 3) per pose (NaN where not found or a marker unseen), ``counts`` (J, M) samples per
    marker, the ROM take's ``names``/``neutral``, its ``noise``, ``holds`` found (all of them) and ``notes``."""

    poses: tuple
    frames: tuple
    middles: np.ndarray
    score: np.ndarray
    measured: np.ndarray
    counts: np.ndarray
    names: tuple
    neutral: np.ndarray
    noise: float
    holds: tuple
    notes: tuple
    given: bool = False

    @property
    def found(self):
        return np.array([f is not None for f in self.frames])

    def report(self):
        """JSON-ready: each pose's label, frames and middle (None: not found) and its match."""
        return {"holds_found": len(self.holds), "poses_found": int(self.found.sum()), "poses": len(self.poses),
                "from": "given" if self.given else "found",
                "poses_table": [{"label": p.label, "frames": None if f is None else [int(f[0]), int(f[1])],
                                 "middle": None if not np.isfinite(m) else round(float(m), 1),
                                 "match": None if not np.isfinite(s) else round(float(s), 3)}
                                for p, f, m, s in zip(self.poses, self.frames, self.middles, self.score)]}


def prior_for(shapes, names, sources):
    """(K, M, 3) the prior's shapes for ``shapes`` (the sheet's ARKit names) at the markers ``names``: from the
    first of ``sources`` ((shape names, (K', M, 3) deltas) pairs, matched by name or alias) that has each; zeros
    where none has it."""
    out = np.zeros((len(shapes), len(names), 3))
    have = np.zeros(len(shapes), dtype=bool)
    for source_names, deltas in sources:
        if deltas is None:
            continue
        keyed = {name_key(n): i for i, n in enumerate(source_names)}
        for k, s in enumerate(shapes):
            i = keyed.get(name_key(s))
            if not have[k] and i is not None:
                out[k], have[k] = np.nan_to_num(deltas[i]), True
    return out, have


def asked_weights(poses, shapes):
    """(J, K) the weights each pose asks of ``shapes``."""
    index = {s: i for i, s in enumerate(shapes)}
    out = np.zeros((len(poses), len(shapes)))
    for j, p in enumerate(poses):
        for s, w in p.weights:
            out[j, index[s]] = w
    return out


def _measure(deltas, frames, first, last):
    sel = (frames >= first) & (frames <= last)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a marker never seen in the hold: NaN
        return np.nanmedian(deltas[sel], axis=0), np.isfinite(deltas[sel][:, :, 0]).sum(axis=0)


def find_poses(take, poses, prior, *, fps, given=None):
    """The sheet's ``poses`` in the ROM ``take`` (a PreparedTake).

    ``prior`` (K, M, 3) the prior's shapes for ``sheet_shapes(poses)`` at the take's markers (zeros: no prior:
    the holds are then taken in order and a count that differs from the sheet's is refused). ``given``: {label:
    middle frame} the user placed (``[calibration] holds``, Find Poses' timeline markers): only those poses are
    measured, there. Raises FacecapError naming the poses when the holds cannot be told apart."""
    deltas, frames = take.deltas, np.asarray(take.frames, dtype=np.float64)
    noise = marker_noise(deltas)
    holds = find_holds(deltas, frames, fps, noise)
    predicted = np.einsum("jk,kmd->jmd", asked_weights(poses, sheet_shapes(poses)), prior)
    if given is not None:
        spans, middles, notes = given_spans(poses, given, holds, fps)
    else:
        spans, middles, notes = _found_spans(poses, holds, predicted, deltas, frames, noise, fps)
    J = len(poses)
    E = np.full((J,) + deltas.shape[1:], np.nan)
    counts = np.zeros((J, deltas.shape[1]))
    for j, span in enumerate(spans):
        if span is not None:
            E[j], counts[j] = _measure(deltas, frames, *span)
    found = np.array([s is not None for s in spans])
    score = np.full(J, np.nan)
    score[found] = np.diag(cosines(E[found], predicted[found])) if np.any(prior) else np.nan
    return RomPoses(tuple(poses), tuple(None if s is None else (int(s[0]), int(s[1])) for s in spans), middles,
                    score, E, counts, tuple(take.names), take.neutral, noise, holds, tuple(notes),
                    given=given is not None)


def given_spans(poses, given, holds, fps):
    """(frames measured per pose, middles, notes) where the user put the poses: around the hold found at each
    given middle (moved there), else ``GIVEN_HALF_S`` either side of it."""
    labels = [p.label for p in poses]
    unknown = sorted(set(given) - set(labels))
    if unknown:
        raise FacecapError(f"[calibration] holds: {unknown} are not poses of the sheet; its poses: {labels}")
    spans, middles = [None] * len(poses), np.full(len(poses), np.nan)
    half = GIVEN_HALF_S * fps
    for j, p in enumerate(poses):
        if p.label not in given:
            continue
        m = float(given[p.label])
        cover = [h for h in holds if h.start <= m <= h.end]
        if cover:  # the found hold's extent, moved to where the user put its middle
            spans[j] = tuple(np.array(cover[0].measured()) + round(m - cover[0].middle))
        else:
            spans[j] = (int(np.floor(m - half)), int(np.ceil(m + half)))
        middles[j] = m
    return spans, middles, []


def _found_spans(poses, holds, predicted, deltas, frames, noise, fps):
    """(frames measured per pose, middles, notes) of the ``holds`` found, named by the sheet (``align_holds``
    against the ``predicted`` patterns); refused with the poses named when the alignment is ambiguous."""
    J = len(poses)
    measured = np.stack([_measure(deltas, frames, *h.measured())[0] for h in holds]) if holds else \
        np.zeros((0,) + deltas.shape[1:])
    if not np.any(predicted) and len(holds) != J:
        raise FacecapError(f"the ROM take holds {len(holds)} expressions and the sheet has {J} poses; without a "
                           "prior (the human template or a character with markers bound) facecap cannot tell "
                           "which were skipped or added: give [calibration] holds (the middle frame of each)")
    # a pose whose predicted motion stays below what finds a hold may well leave none
    size = np.sort(np.linalg.norm(predicted, axis=2), axis=1)[:, -TOP:].mean(axis=1)
    subtle = (size < ENTER * activity_unit(noise, fps)) & np.any(predicted)
    align = align_holds(measured, predicted, subtle)
    if align.ambiguous:
        raise FacecapError("the ROM take's holds do not follow the sheet clearly around pose(s) "
                           f"{[poses[j].label for j in align.ambiguous]} ({len(holds)} holds found for {J} poses): "
                           "a pose skipped, repeated or added there. Check the take, or give [calibration] holds "
                           "(the middle frame of each pose) or a sequence as performed")
    spans, middles, notes = [None] * J, np.full(J, np.nan), []
    for j, h in enumerate(align.hold_of):
        if h >= 0:
            spans[j], middles[j] = holds[h].measured(), holds[h].middle
    missed = [poses[j].label for j in align.skipped]
    if missed:
        notes.append(f"ROM: pose(s) not found in the take (skipped, or too subtle for the markers; their shapes "
                     f"come from the prior): {missed}")
    extra = [f"{holds[h].start:g}-{holds[h].end:g}" for h in align.extra]
    if extra:
        notes.append(f"ROM: expression(s) at frames {extra} match no pose of the sheet and are left out")
    return spans, middles, notes


def fit_rom(found, prior, *, neutral_counts=None):
    """The actor's measured shapes from the poses ``found`` (a RomPoses) with the ``prior`` (K, M, 3) for the
    sheet's shapes: a Basis of the shapes the poses measure (``joint.MEASURED``; the others are completed from the
    prior by the solve), in the ROM take's actor space, and the JointFit."""
    shapes = sheet_shapes(found.poses)
    use = found.found
    if not use.any():
        raise FacecapError("no pose of the sheet was found in the ROM take")
    rest = np.inf if neutral_counts is None else neutral_counts
    E = shrink_pose_noise(np.nan_to_num(found.measured[use]), found.counts[use], rest, found.noise)
    E[~np.isfinite(found.measured[use])] = np.nan
    n = max(float(np.median(found.counts[use])), 1.0)
    error = MEDIAN_ERROR * found.noise * np.sqrt(1.0 / n) if np.isfinite(found.noise) else 0.0
    fit = fit_examples(E, asked_weights(found.poses, shapes)[use], prior, error=error)
    keep = np.flatnonzero(fit.measured)
    basis = Basis(tuple(shapes[k] for k in keep), found.names, found.neutral, fit.shapes[keep])
    return basis, fit
