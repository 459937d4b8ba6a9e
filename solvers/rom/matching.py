"""Which hold of a ROM take performs which pose of its sheet.

The holds were performed in the sheet's order, but a performer skips a pose, repeats one or adds an
expression, and a pose too subtle for the markers leaves no hold. Each hold's measured pattern is compared with
what each pose should look like on this face (the prior's shapes mixed as the pose asks: the human template, or
the character's shapes carried to the actor) by their cosine, and the holds are aligned with the poses in order
by dynamic programming (Needleman-Wunsch): a match scores its cosine, a skipped pose and an extra hold cost.
A pose the markers should barely see costs little to skip. A decision the alignment could as well have made
otherwise (forcing the other choice scores within ``AMBIGUOUS``) is not taken silently: it is reported as
ambiguous, and the caller refuses with the poses named.
"""

from dataclasses import dataclass

import numpy as np

#: The cost of a skipped pose the markers should see, of one they should barely see, and of an extra hold. An
#: extra costs twice a skip: with a prior rough at the markers (68 landmarks), an extra plus a subtle pose skipped
#: was cheaper than a run of poorly matched poses and slid them by one (benchmark draws 100-105, arkit-51 on 68
#: landmarks: 88.4 % of the holds found within 5 frames at 0.6, one draw 3 of 51; 99.0 % at 1.2; dense unchanged).
SKIP, SKIP_SUBTLE, EXTRA = 0.6, 0.05, 1.2
#: Two alignments whose scores differ by less than this cannot be told apart; a cost that forces a choice.
AMBIGUOUS, FORCE = 0.15, 1e3


@dataclass(frozen=True)
class Alignment:
    """``pose_of`` (H,) the sheet's pose each hold performs (-1: none, an extra expression); ``hold_of`` (J,) the
    hold of each pose (-1: not found); ``score`` (H,) each matched hold's cosine with its pose (NaN for extras);
    ``ambiguous``: poses whose skip or match another alignment explains as well (indices)."""

    pose_of: tuple
    hold_of: tuple
    score: tuple
    ambiguous: tuple

    @property
    def skipped(self):
        return tuple(j for j, h in enumerate(self.hold_of) if h < 0)

    @property
    def extra(self):
        return tuple(h for h, j in enumerate(self.pose_of) if j < 0)


def cosines(measured, predicted):
    """(H, J) cosine of each measured pattern (H, M, 3) with each predicted one (J, M, 3), over the markers both
    have (NaN: a gap); 0 where either is all zero."""
    A = np.nan_to_num(measured).reshape(len(measured), -1)
    B = np.nan_to_num(predicted).reshape(len(predicted), -1)
    na, nb = np.linalg.norm(A, axis=1), np.linalg.norm(B, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (A @ B.T) / (na[:, None] * nb[None])
    return np.nan_to_num(out)


def _align(score, skip):
    """The best alignment's total and its (hold, pose) matches for scores (H, J) and per-pose skip costs (J,).
    Row by row over the holds; within a row the chain of skipped poses is a running maximum."""
    H, J = score.shape
    S = np.concatenate([[0.0], np.cumsum(skip)])  # S[j]: the cost of skipping poses 0 .. j-1
    best = np.full((H + 1, J + 1), -np.inf)
    how = np.zeros((H + 1, J + 1), dtype=np.int64)  # 0 from the previous row, else 1 + the column it came from
    best[0] = -S
    how[0, 1:] = 1
    for h in range(1, H + 1):
        came = np.full(J + 1, -np.inf)
        came[1:] = best[h - 1, :-1] + score[h - 1]  # matched
        extra = best[h - 1] - EXTRA  # an extra hold
        matched = came > extra
        c = np.where(matched, came, extra)
        run = np.maximum.accumulate(c + S)  # then poses skipped up to j
        origin = np.maximum.accumulate(np.where(c + S >= run, np.arange(J + 1), 0))
        best[h] = run - S
        how[h] = np.where(origin == np.arange(J + 1), np.where(matched, -1, 0), 1 + origin)
    pairs, h, j = [], H, J
    while h or j:
        m = how[h, j]
        if m > 0:  # skipped poses back to the column the chain began at
            j = m - 1 if m - 1 < j else j - 1
            continue
        if m == -1:
            pairs.append((h - 1, j - 1))
            j -= 1
        h -= 1
    return float(best[H, J]), pairs[::-1]


def align_holds(measured, predicted, subtle):
    """Align the holds' ``measured`` patterns (H, M, 3) with the poses' ``predicted`` ones (J, M, 3), in order;
    ``subtle`` (J,) bool: poses the markers should barely see. Returns an Alignment."""
    score = cosines(measured, predicted)
    skip = np.where(np.asarray(subtle, dtype=bool), SKIP_SUBTLE, SKIP)
    total, pairs = _align(score, skip)
    H, J = score.shape
    pose_of, hold_of = np.full(H, -1), np.full(J, -1)
    for h, j in pairs:
        pose_of[h], hold_of[j] = j, h
    ambiguous = []
    if len(pairs) < max(H, J):  # a skip or an extra: would another choice for some pose do as well?
        for j in range(J):
            if subtle[j]:
                continue
            forced = skip.copy()
            forced[j] = -FORCE if hold_of[j] >= 0 else FORCE  # the other choice for this pose
            other, _ = _align(score, forced)
            if hold_of[j] >= 0:
                other -= FORCE + skip[j]  # its real cost
            if other > total - AMBIGUOUS:
                ambiguous.append(j)
    return Alignment(tuple(int(x) for x in pose_of), tuple(int(x) for x in hold_of),
                     tuple(float(score[h, j]) if j >= 0 else float("nan") for h, j in enumerate(pose_of)),
                     tuple(ambiguous))
