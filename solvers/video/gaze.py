"""Gaze from face landmarks: the ARKit eye-look weights from where each iris sits between its eye corners.

A character's eye-look shapes turn its eyeballs (or barely move its lids), so the geometric solve, which
compares how points on the skin move, cannot drive them from the irises. They are set directly instead,
as ARKit itself sets them: an iris displaced by ``d`` (a fraction of the eye's corner-to-corner width,
from where it sits in the neutral) turns the eye by ``asin(d / EYEBALL)`` (the eyeball's radius is about
0.42 of that width in adults), and ARKit's weights are linear in the angle: look out minus look in = 1 at
about 35 degrees of yaw, look up minus look down = 1 at about 30 degrees of pitch (measured on Live Link
Face recordings, which write both: correlation 0.999).

The lids likewise: the solve, given the skin points of the lids, left blinks far from closed (peaks of
0.3-0.45 where the recording closes the eyes), so ``eyeBlink`` is set from how far the lids have closed
from their gap in the neutral (ARKit's blink is that closure) and ``eyeWide`` from how far they open
beyond it (:func:`lid_weights`).
"""

import numpy as np

from ..character.aliases import match_names

#: Eyeball radius / eye corner-to-corner width (about 12 mm / 29 mm).
EYEBALL = 0.42
#: Degrees of yaw and pitch at which ARKit's eye-look weights reach 1.
YAW_FULL, PITCH_FULL = 35.0, 30.0
#: (iris centre, outer corner, inner corner, upper lid, lower lid, ARKit side) per eye; image x runs to the
#: subject's left.
EYES = ((468, 33, 133, 159, 145, "Right"), (473, 263, 362, 386, 374, "Left"))
#: An eye whose lids are closer than this fraction of their usual gap hides its iris: its gaze is held.
CLOSED = 0.5
SHAPES = tuple(f"eyeLook{d}{side}" for side in ("Left", "Right") for d in ("Up", "Down", "In", "Out"))
#: The lid shapes set from the lids' gap.
LID_SHAPES = ("eyeBlinkLeft", "eyeBlinkRight", "eyeWideLeft", "eyeWideRight")
#: Lids opened by this share of their neutral gap beyond it read as eyeWide = 1 (an assumption: the
#: recordings measured have no wide eyes to fit it on).
WIDE = 0.5
#: The detector's lid points never meet: a closed eye keeps about this share of its neutral gap (0.38-0.52 on
#: rendered closed eyes; eye-aspect-ratio studies of MediaPipe's mesh report closed eyes at 0.4-0.5 of open).
#: A closure up to ``BLINK_LINEAR`` of the gap is the blink weight as it is (a squint or a look down lowers
#: the lids that far), and from there the weight reaches 1 where the gap is down to ``CLOSED_GAP``. Rendered
#: footage, left / right blink peaks where the recording closes the eyes: 0.62 / 0.84 -> 1.00 / 1.00, held
#: out 0.54 / 0.85 -> 0.82 / 1.00; the lids' RMSE 0.080 -> 0.098 (the peaks now overshoot short blinks).
CLOSED_GAP, BLINK_LINEAR = 0.4, 0.4


def _rest_mask(n, neutral):
    """(n,) bool: the ``neutral`` frames (indices or a mask), every frame when none are given."""
    if neutral is None or not np.size(neutral):
        return np.ones(n, bool)
    rest = np.zeros(n, bool)
    rest[np.asarray(neutral)] = True
    return rest


def eye_angles(positions, neutral=None):
    """{side: (yaw towards the subject's left, pitch downwards) in degrees, each (F,)} from landmark
    pixels (F, 478, >=2), relative to the irises' place in the ``neutral`` frames (indices or a mask:
    the take's rest looks ahead; the camera's angle and the detector's bias cancel), else in the median
    frame. While the lids are closed (a blink hides the iris) the angles are carried over from the open
    frames around."""
    rest = _rest_mask(len(positions), neutral)
    out = {}
    for iris, outer, inner, upper, lower, side in EYES:
        p = positions[..., :2]
        a, b = p[:, outer], p[:, inner]
        axis = a - b if side == "Left" else b - a  # image left -> right across the eye
        width = np.linalg.norm(axis, axis=1)
        x = axis / width[:, None]
        y = np.stack([-x[:, 1], x[:, 0]], axis=1)  # image down
        d = p[:, iris] - 0.5 * (a + b)
        u, v = np.sum(d * x, axis=1) / width, np.sum(d * y, axis=1) / width
        lids = np.linalg.norm(p[:, upper] - p[:, lower], axis=1) / width
        shut = ~(lids >= CLOSED * np.nanmedian(lids))  # NaN (no face) counts as shut
        ref = rest & ~shut if (rest & ~shut).any() else ~shut
        if ref.any():
            u, v = u - np.nanmedian(u[ref]), v - np.nanmedian(v[ref])
        if shut.any() and (~shut).any():
            frames = np.arange(len(u))
            u = np.interp(frames, frames[~shut], u[~shut])
            v = np.interp(frames, frames[~shut], v[~shut])
        out[side] = (np.degrees(np.arcsin(np.clip(u / EYEBALL, -1, 1))),
                     np.degrees(np.arcsin(np.clip(v / EYEBALL, -1, 1))))
    return out


def gaze_weights(positions, neutral=None):
    """{ARKit eye-look shape: (F,) weight in [0, 1]} (:data:`SHAPES`) from landmark pixels (F, 478, >=2),
    zero in the ``neutral`` frames (see :func:`eye_angles`)."""
    weights = {}
    for side, (yaw, pitch) in eye_angles(positions, neutral).items():
        outward = yaw if side == "Left" else -yaw  # out = away from the nose
        weights[f"eyeLookOut{side}"] = np.clip(outward / YAW_FULL, 0, 1)
        weights[f"eyeLookIn{side}"] = np.clip(-outward / YAW_FULL, 0, 1)
        weights[f"eyeLookDown{side}"] = np.clip(pitch / PITCH_FULL, 0, 1)
        weights[f"eyeLookUp{side}"] = np.clip(-pitch / PITCH_FULL, 0, 1)
    return weights


def lid_weights(positions, neutral=None):
    """{eyeBlink/eyeWide Left/Right: (F,) weight in [0, 1]} from landmark pixels (F, 478, >=2): the lids'
    gap (upper to lower lid over the corner-to-corner width) against its median in the ``neutral``
    frames (else in the take): closed by a share ``c`` of it is a blink of ``c`` up to :data:`BLINK_LINEAR`,
    1 where the gap is down to :data:`CLOSED_GAP` (the detector's closed eye), opened by :data:`WIDE` of it is
    wide open. Frames without a face are 0."""
    rest = _rest_mask(len(positions), neutral)
    out = {}
    for _, outer, inner, upper, lower, side in EYES:
        p = positions[..., :2]
        gap = np.linalg.norm(p[:, upper] - p[:, lower], axis=1) / np.linalg.norm(p[:, outer] - p[:, inner], axis=1)
        ref = gap[rest] if np.isfinite(gap[rest]).any() else gap
        blink, wide = lids_from_gap(gap / np.nanmedian(ref))
        out[f"eyeBlink{side}"], out[f"eyeWide{side}"] = np.nan_to_num(blink), np.nan_to_num(wide)
    return out


def lids_from_gap(ratio):
    """(eyeBlink, eyeWide) weights in [0, 1] of the lids' gap as a share ``ratio`` of its neutral gap (see
    :func:`lid_weights`)."""
    closure = 1.0 - np.asarray(ratio, dtype=np.float64)
    steep = BLINK_LINEAR + (closure - BLINK_LINEAR) * (1.0 - BLINK_LINEAR) / (1.0 - CLOSED_GAP - BLINK_LINEAR)
    return (np.clip(np.where(closure <= BLINK_LINEAR, closure, steep), 0, 1), np.clip(-closure / WIDE, 0, 1))


def gap_from_lids(blink, wide):
    """The lids' gap (share of the neutral gap) that :func:`lids_from_gap` reads as ``blink`` and ``wide``: its
    inverse where neither weight is at a bound (a blink of 1 reads as the closed eye's gap, a wide of 1 as
    ``1 + WIDE``)."""
    blink, wide = np.asarray(blink, dtype=np.float64), np.asarray(wide, dtype=np.float64)
    closure = np.where(blink <= BLINK_LINEAR, blink,
                       BLINK_LINEAR + (blink - BLINK_LINEAR) * (1.0 - CLOSED_GAP - BLINK_LINEAR) / (1.0 - BLINK_LINEAR))
    return np.where(wide > 0, 1.0 + WIDE * wide, 1.0 - closure)


def lids_against_gaze(blink, wide, look_down, per_look_down):
    """(eyeBlink, eyeWide) of one eye read against its gaze: a look down lowers the upper lid with the eye (by
    ``per_look_down`` of the neutral gap at eyeLookDown 1, negative), which the lids' gap alone reads as a half
    blink, and a look back up from there as eyes wide. The gap is taken back to what the lids would show looking
    ahead (``gap - per_look_down * look_down``) and read again."""
    gap = gap_from_lids(blink, wide) - per_look_down * np.nan_to_num(np.asarray(look_down, dtype=np.float64))
    return lids_from_gap(gap)


def gaze_locks(shape_names, positions, neutral=None):
    """Per-frame locks ``((shape name, (F,) weights), ...)`` holding the character's eye-look shapes
    (:data:`SHAPES` matched by name or alias) at the irises' gaze and its blink and wide shapes
    (:data:`LID_SHAPES`) at the lids' gap, both relative to the ``neutral`` frames: the solve then
    explains the rest of the lids' motion (squints) instead of a blink by a look, or a look by a blink."""
    shapes = SHAPES + LID_SHAPES
    pairs, _, _ = match_names(shapes, shape_names)
    weights = {**gaze_weights(positions, neutral), **lid_weights(positions, neutral)}
    return tuple((shape_names[j], weights[shapes[i]]) for i, j in pairs)
