"""Calibration by following a guide: the performer, filmed with the camera of the takes to come, imitates a
performance whose ARKit weights are known (the guide: any ARKit weights file, shown to them as it plays), and
the clip's frames, with the guide's weights as their truth, join the fusion map's tuning clips for this performer
and camera (``fusion.CrossMap``).

Why the map and not a gain per score (``response.py``): what is left after the fusion is cross-talk between
shapes in mixtures (a lower lip read with the jaw, a frown with a stretch), which a gain per score cannot undo and
a ROM's isolated poses do not show; a performance followed has the mixtures of a performance. Nothing is fitted
that the map does not already fit: the performer's clip adds its normal equations, weighing as a few tuning
clips (``FOLLOW_SHARE``), so shapes the guide barely moves stay as the tuning clips read them; the eyes' blinks and
looks (``NOT_FOLLOWED``), which a performer does not take from a guide, stay as the map reads them.

The guide is placed in the clip by the weights the uncalibrated fusion reads: the frame offset where they
correlate best with the guide's (the performer's reaction time is part of it), over every placement that
overlaps the guide by ``MIN_OVERLAP`` of its length, then refined window by window (a performer drifts from a long
guide's timing: ``follow_timing``).
"""

from dataclasses import dataclass, replace

import numpy as np

from ..errors import FacecapError
from .fusion import CrossMap, FusionTable, arkit_names, clip_equations, fuse, map_inputs

#: What the performer's clip weighs in the map, as a share of the tuning clips it has (24 tuning clips and a share
#: of 1/3: as 8 of them). Chosen on the tuning faces alone (``fusion_bench --follow-weight``: each tuning identity's
#: performances of a performer the guide is not from, through a map fitted without that identity, with its own clip
#: following the guide, their eyes their own: 0.098 without, 0.095, 0.094, 0.092, 0.091 at 1/24, 1/12, 1/6, 1/3, no
#: lower above), never on the reported clips.
FOLLOW_SHARE = 1.0 / 3.0
#: The share of the guide that must be in the clip at a placement, and the least correlation (mean over the
#: guide's moving shapes) that says the performer followed it.
MIN_OVERLAP, MIN_CORRELATION = 0.8, 0.3
#: A guide shape counts in the placement when it moves at least this much (its standard deviation).
MOVING = 0.03
#: The guide's timing is refined in windows of this many seconds, each moved at most this far from the one before
#: (``follow_timing``): a performer drifts from a long guide's timing.
WINDOW_S, LOCAL_S = 4.0, 0.25
#: The shapes a performer does not take from the guide: their blinks are their own, and their eyes are on the screen
#: the guide plays on. The performer's clip teaches the map nothing of these (they stay as the map reads them).
NOT_FOLLOWED = ("eyeBlinkLeft", "eyeBlinkRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeLookDownLeft",
                "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight")
#: What a performer profile keeps of a performer's map.
PROFILE_KEYS = ("performer_names", "performer_gram", "performer_moment", "performer_ridge", "performer_clips",
                "performer_guide")


def resample(values, fps_from, fps_to, frames=None):
    """``values`` (G, S) at ``fps_from`` on the frame grid of ``fps_to`` (linear in time; NaN stays out of the
    interpolation of its column), ``frames`` long (default: as long as the guide lasts)."""
    values = np.asarray(values, dtype=np.float64)
    t_from = np.arange(len(values)) / float(fps_from)
    n = int(np.floor(t_from[-1] * fps_to + 1e-9)) + 1 if frames is None else int(frames)
    t_to = np.arange(n) / float(fps_to)
    out = np.full((n, values.shape[1]), np.nan)
    for j in range(values.shape[1]):
        ok = np.isfinite(values[:, j])
        if ok.sum() >= 2:
            out[:, j] = np.interp(t_to, t_from[ok], values[ok, j], left=np.nan, right=np.nan)
    return out


def find_offset(guide, read, *, min_overlap=MIN_OVERLAP):
    """(offset, correlation): the clip frame (index) where the guide's first frame is performed, and the mean
    Pearson correlation over the guide's moving shapes there, of ``guide`` (G, S) and what the clip ``read`` (F, S)
    (same columns and frame rate; NaN frames left out). Every offset with at least ``min_overlap`` of the guide in
    the clip is tried (the guide may start before the clip or run past its end); the best wins."""
    guide, read = np.asarray(guide, dtype=np.float64), np.asarray(read, dtype=np.float64)
    G, F = len(guide), len(read)
    moving = np.nanstd(guide, axis=0) >= MOVING
    if not moving.any():
        raise FacecapError(f"the guide moves no shape by {MOVING} or more: nothing to follow")
    guide, read = guide[:, moving], read[:, moving]
    need = max(2, int(np.ceil(min_overlap * G)))
    if need > F:
        raise FacecapError(f"the clip has {F} frames and the guide {G}: film at least {need} frames of it")
    best = (None, -np.inf)
    for offset in range(need - G, F - need + 1):
        g0, g1 = max(0, -offset), min(G, F - offset)
        r = _correlation(guide[g0:g1], read[g0 + offset:g1 + offset], need // 2)
        if r > best[1]:
            best = (offset, r)
    if best[0] is None:
        raise FacecapError("the clip has no stretch of frames with a face as long as the guide")
    return best


def follow_timing(guide, read, offset, fps):
    """(F,) the guide frame (fractional; NaN where the clip performs none) that each clip frame performs: the whole
    guide's ``offset`` (:func:`find_offset`) refined window by window (:data:`WINDOW_S`, half overlapping), so that
    a performer drifting from a long guide's timing is followed. The window that follows best near ``offset``
    anchors it; from there each window is moved at most :data:`LOCAL_S` from its neighbour, outwards both ways; a
    window that correlates under :data:`MIN_CORRELATION` takes its neighbours' timing. ``guide`` (G, S) and
    ``read`` (F, S) as :func:`find_offset` takes them, at ``fps`` frames/s."""
    guide, read = np.asarray(guide, dtype=np.float64), np.asarray(read, dtype=np.float64)
    G, F = len(guide), len(read)
    moving = np.nanstd(guide, axis=0) >= MOVING
    guide, read = guide[:, moving], read[:, moving]
    win = min(G, max(8, int(round(WINDOW_S * fps))))
    reach = max(1, int(round(LOCAL_S * fps)))
    starts = list(range(0, max(G - win, 0) + 1, max(1, win // 2)))

    def near(g0, around):  # (shift, correlation) of the window at guide frame g0, within reach of ``around``
        best = (None, MIN_CORRELATION)
        part = guide[g0:g0 + win]
        cols = np.nanstd(part, axis=0) >= MOVING  # the shapes this window moves (the others read noise)
        if not cols.any():
            return best
        for d in sorted(range(around - reach, around + reach + 1), key=lambda d: abs(d - around)):
            if g0 + d >= 0 and g0 + d + win <= F:
                r = _correlation(part[:, cols], read[g0 + d:g0 + d + win, cols], win // 2)
                if r > best[1]:
                    best = (d, r)
        return best

    first = [near(g0, int(offset)) for g0 in starts]
    anchor = int(np.argmax([r for _, r in first]))
    shifts = {}
    if first[anchor][0] is not None:
        shifts[anchor] = first[anchor][0]
        for order in (range(anchor + 1, len(starts)), range(anchor - 1, -1, -1)):
            shift = shifts[anchor]
            for i in order:
                d, _ = near(starts[i], shift)
                if d is not None:
                    shifts[i] = shift = d
    done = sorted(shifts)
    found = np.array([shifts[i] for i in done], dtype=np.float64)
    if len(found) >= 3:  # a running median of 3: a window with little motion may pick a shift a few frames off
        found[1:-1] = np.median(np.stack([found[:-2], found[1:-1], found[2:]]), axis=0)
    centres = [starts[i] + shifts[i] + 0.5 * (win - 1) for i in done]  # each window's middle, as a clip frame
    clip = np.arange(F, dtype=np.float64)
    when = clip - (np.interp(clip, centres, found) if done else float(offset))
    return np.where((when >= 0) & (when <= G - 1), when, np.nan)


def _correlation(a, b, least):
    """The mean Pearson correlation over the columns of ``a`` and ``b`` (frames where both are finite; -inf with
    fewer than ``least`` of them); a column that does not move counts as 0."""
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    if ok.sum() < max(least, 2):
        return -np.inf
    a, b = a[ok] - a[ok].mean(axis=0), b[ok] - b[ok].mean(axis=0)
    den = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    return float(np.mean(np.where(den > 0, (a * b).sum(axis=0) / np.where(den > 0, den, 1.0), 0.0)))


@dataclass(frozen=True, eq=False)
class PerformerMap:
    """A performer's clip for the fusion map: its normal equations (``gram`` (2S, 2S), ``moment`` (2S, S) on the map's
    ``names``, as ``fusion.fit_map`` keeps a tuning clip's), the ``ridge`` it adds (one clip's) and how many tuning
    clips it weighs as (``clips``); ``guide`` says what it was measured with."""

    names: tuple
    gram: np.ndarray
    moment: np.ndarray
    ridge: float
    clips: float = 1.0
    guide: str = ""

    def __post_init__(self):
        S = len(self.names)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        gram, moment = np.asarray(self.gram, np.float64), np.asarray(self.moment, np.float64)
        if gram.shape != (2 * S, 2 * S) or moment.shape != (2 * S, S):
            raise FacecapError(f"a performer's map of {S} shapes needs a ({2 * S}, {2 * S}) gram and a "
                               f"({2 * S}, {S}) moment; got {gram.shape} and {moment.shape}")
        if not (np.isfinite(gram).all() and np.isfinite(moment).all()) or not self.ridge >= 0 or not self.clips > 0:
            raise FacecapError("a performer's map needs finite equations, a ridge >= 0 and a positive weight")
        object.__setattr__(self, "gram", gram)
        object.__setattr__(self, "moment", moment)

    def __call__(self, table):
        """``table`` (FusionTable) with this performer's clip in its map (the map's names matched by name: a
        shape the performer's clip lacks adds nothing there)."""
        if table.map is None:
            raise FacecapError("the fusion table has no map to add the performer's clip to")
        names = table.map.names
        mine = {n: j for j, n in enumerate(self.names)}
        pick = np.array([mine.get(n, -1) for n in names])
        have = pick >= 0
        rows = np.r_[pick, np.where(have, pick + len(self.names), -1)]
        inputs = rows >= 0
        gram = np.zeros_like(table.map.gram)
        gram[np.ix_(inputs, inputs)] = self.gram[np.ix_(rows[inputs], rows[inputs])]
        moment = np.zeros_like(table.map.moment)
        moment[np.ix_(inputs, have)] = self.moment[np.ix_(rows[inputs], pick[have])]
        w = self.clips
        return replace(table, map=CrossMap(names, table.map.gram + w * gram, table.map.moment + w * moment,
                                           table.map.ridge + w * self.ridge))

    def to_arrays(self):
        """{key: array} for a performer profile (:data:`PROFILE_KEYS`)."""
        return {"performer_names": np.array(self.names, dtype=str), "performer_gram": self.gram,
                "performer_moment": self.moment, "performer_ridge": np.float64(self.ridge),
                "performer_clips": np.float64(self.clips), "performer_guide": np.array(self.guide)}

    @classmethod
    def from_arrays(cls, data, *, where="the performer profile"):
        """The map saved by ``to_arrays`` in ``data`` (a mapping), or None when it holds none."""
        if "performer_gram" not in data:
            return None
        try:
            return cls(tuple(str(n) for n in data["performer_names"]), data["performer_gram"],
                       data["performer_moment"], float(data["performer_ridge"]), float(data["performer_clips"]),
                       str(data["performer_guide"]) if "performer_guide" in data else "")
        except (KeyError, ValueError, TypeError, FacecapError) as exc:
            raise FacecapError(f"{where}: its performer's map is damaged ({exc})") from None


@dataclass(frozen=True)
class FollowFit:
    """What following a guide measured: the performer's map, where the guide was found (``offset``: the clip
    frame index of its first frame), how well the clip followed it (``correlation``) and the frames used."""

    performer: PerformerMap
    offset: int
    correlation: float
    frames: int
    fps: float
    drift: float = 0.0  # the most the performer's timing moved from the whole guide's placement (seconds)

    @property
    def summary(self):
        return (f"the guide found from clip frame {self.offset + 1} ({self.offset / self.fps:+.2f} s; correlation "
                f"{self.correlation:.2f}; the timing followed within {self.drift:.2f} s of that), {self.frames} frames "
                f"in the fusion map as {self.performer.clips:g} tuning clip(s)")

    def report(self):
        return {"guide": self.performer.guide, "offset_frames": int(self.offset),
                "correlation": round(self.correlation, 3), "drift_s": round(self.drift, 3), "frames": int(self.frames),
                "weighs_as_clips": self.performer.clips, "summary": self.summary}


def fit_follow(guide, guide_names, guide_fps, solved, shape_names, scores, *, table=None, offset=None,
               clips=None, guide_label=""):
    """The performer's map from a clip that follows a guide.

    Parameters
    ----------
    guide : (G, S_g) the guide's ARKit weights at ``guide_fps``, columns ``guide_names``
    solved : (F, K) the clip's landmark solve on ``shape_names`` (unfused)
    scores : FaceScores of the clip (its blendshape scores, neutral frames and frame rate; no response)
    table : FusionTable (default: the measured one), whose map the clip joins
    offset : the clip frame index of the guide's first frame when known (else found: :func:`find_offset`)
    clips : how many tuning clips the performer's clip weighs as (default: :data:`FOLLOW_SHARE` of the map's)
    """
    table = FusionTable.load() if table is None else table
    if table.map is None:
        raise FacecapError("the fusion table has no map: following a guide calibrates the map")
    if not scores.fps:
        raise FacecapError("the clip's frame rate is unknown: the guide cannot be placed in it")
    names = table.map.names
    column = {n: j for j, n in enumerate(guide_names)}
    missing = [n for n in names if n not in column]
    if missing:
        raise FacecapError(f"the guide lacks {len(missing)} of the ARKit shapes the fusion reads "
                           f"({', '.join(missing[:6])}{', ...' if len(missing) > 6 else ''}): a guide names all 52 "
                           "(a Live Link Face CSV does)")
    truth = resample(np.asarray(guide, np.float64)[:, [column[n] for n in names]], guide_fps, scores.fps)
    F = len(solved)
    fused, _ = fuse(solved, shape_names, scores, table=table)
    arkit = {n: k for k, n in reversed(list(enumerate(arkit_names(shape_names))))}
    read = np.full((F, len(names)), np.nan)
    for j, n in enumerate(names):
        if n in arkit:
            read[:, j] = fused[:, arkit[n]]
    if offset is None:
        offset, r = find_offset(truth, read)
        if r < MIN_CORRELATION:
            raise FacecapError(f"the clip does not follow the guide: its best placement (clip frame {offset + 1}) "
                               f"correlates {r:.2f} with it, below {MIN_CORRELATION}; is it the guide it was filmed "
                               "with, at its speed?")
    else:
        offset, r = int(offset), float("nan")
    when = follow_timing(truth, read, offset, scores.fps)  # the guide frame each clip frame performs
    placed = np.isfinite(when)
    if placed.sum() < 2:
        raise FacecapError(f"the guide placed at clip frame {offset + 1} does not overlap the clip's {F} frames")
    lo = np.floor(when[placed]).astype(int)
    t = (when[placed] - lo)[:, None]
    aligned = np.full((F, len(names)), np.nan)
    aligned[placed] = (1 - t) * truth[lo] + t * truth[np.minimum(lo + 1, len(truth) - 1)]
    drift = float(np.nanmax(np.abs(np.arange(F) - when - offset))) / scores.fps
    X, seen = map_inputs(table, scores, solved, shape_names)
    target = aligned[seen]
    mine = [j for j, n in enumerate(names) if n in NOT_FOLLOWED]
    if mine:  # what the map reads there now, not the guide's (S ones: every input had, 0 for one the clip lacks)
        ones = np.ones(len(names), bool)
        read_now = X @ table.map.weights(table, ones, ones)[:, mine]
        target[:, mine] = np.where(np.isfinite(target[:, mine]), read_now, np.nan)
    gram, moment, used = clip_equations(target, X)
    if used < 2:
        raise FacecapError("no frame of the clip has both a face and the guide")
    n_clips = max(len(table.measured_on.get("map_clips", ())), 1)
    lam = float(table.measured_on.get("map_ridge", table.map.ridge / n_clips))
    clips = FOLLOW_SHARE * n_clips if clips is None else float(clips)
    performer = PerformerMap(names, gram, moment, lam, clips, guide_label)
    return FollowFit(performer, int(offset), float(r), int(used), float(scores.fps), drift)

