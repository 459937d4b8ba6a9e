"""The performer's response on this camera, from a ROM clip filmed with it.

The Face Landmarker's blendshape head reads every face and camera a little differently: on the project's renders
the ICT tuning faces' full outer brow raise scores about 0.5 and the Face Cap head's nearly 1 (fitted gains 1.97
and 1.04), a full look down about 0.5 on both. The ROM sheet (``solvers/rom/sheets.py``), performed once in front of the camera, says what each hold
asks; the clip says what the head scored there. Per shape::

    w = max(gain * c + offset, 0)      c the neutral-corrected score (fusion.neutral_corrected)

fitted over the neutral and every pose found (``fit_response``) and applied where the fusion plugs it in
(``FaceScores.response``, ``fusion.fuse``).

Finding the poses reuses the marker ROM's pieces on the score vector instead of the markers: the activity of a
frame is how far its most-moved scores are from the neutral in units of each score's noise on the neutral
frames (``rom.holds.find_holds`` with one coordinate per score), and the holds are named by the sheet in order
(``rom.matching.align_holds``; the prediction: what the reference faces score for the weights asked, below, else
the weights asked themselves: a score is named after the shape it reads), a skipped pose or an extra expression
named in the notes; poses whose holds another alignment would explain as well are left out of the fit and named
(a clip where that is more than half of the sheet is refused).

The fit is robust (Huber weights, so that one pose the head misreads does not set a gain) and shrinks to the
identity (gain 1, offset 0): a shape the sheet does not ask, or whose score never moves where it is asked
(``MIN_RESPONSE``), keeps its score as it is; gains stay within ``GAIN_RANGE``.

The fusion table's gains were fitted on the tuning faces' scores, whose own response is not the identity (their
look down's gain is 1.95 too, and the table's gains already make up for it over the mid-range). So the response
the fusion uses is relative (``relative``): this performer's scores read as the tuning faces would score the same
weights, ``reference^-1 o own``, with ``reference`` the same fit on the tuning faces' ROM clips, stored in the table
(``FusionTable.reference``; ``fusion_bench --fit-rom``).
"""

import warnings
import zipfile
from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError, InputFileError
from ..io.files import atomic_path
from ..rom.holds import find_holds, half_window
from ..rom.matching import Alignment, align_holds
from ..rom.session import given_spans
from .follow import PROFILE_KEYS as PERFORMER_KEYS
from .follow import PerformerMap
from .fusion import neutral_corrected
from .score_response import PROFILE_KEYS, ScoreResponse

#: The gains a response may give a score: a score that barely moves would turn noise into motion.
GAIN_RANGE = (0.3, 3.0)
#: The largest offset (weight units) a response may add or take away.
MAX_OFFSET = 0.3
#: A score that moves less than this (corrected, per unit of the weight asked) where the sheet asks its shape
#: does not respond.
MIN_RESPONSE = 0.05
#: The pull towards the identity: a gain's and an offset's weight against one hold's (weight units squared).
SHRINK_GAIN, SHRINK_OFFSET = 0.02, 0.5
#: The neutral's weight in the fit, in holds (it is measured over many frames), and the weight of a hold whose pose
#: does not ask the shape: what the score reads there is another expression's cross-talk, which a gain cannot undo
#: (a smile's score that reads 0.3 in a grimace must not halve the smile's gain); it only tempers the offset.
NEUTRAL_WEIGHT, UNASKED_WEIGHT = 3.0, 0.1
#: Huber's threshold (weight units) and the iterations of its reweighting.
HUBER, HUBER_STEPS = 0.1, 10
#: The smallest noise (score units) a score is measured against: a score that rests at exactly 0 has none.
NOISE_FLOOR = 0.03


@dataclass(frozen=True, eq=False)
class ResponseFit:
    """A fitted ``response`` (ScoreResponse) with how it was found: the sheet's ``poses``, the frames (first,
    last) measured per pose (None: not found), every hold found (``rom.holds.Hold``), the Alignment (None: the
    poses were placed by the user), per shape
    how many poses found ask it (``asked``), ``notes`` (poses skipped, expressions left out, shapes kept as
    scored) and a one-line ``summary``."""

    response: ScoreResponse
    poses: tuple
    frames: tuple
    holds: tuple
    alignment: object
    asked: dict
    notes: tuple
    summary: str

    def report(self):
        """JSON-ready: the poses found and each calibrated shape's gain and offset."""
        r = self.response
        return {"summary": self.summary, "holds_found": len(self.holds), "notes": list(self.notes),
                "poses": [{"label": p.label, "frames": None if f is None else [int(f[0]), int(f[1])]}
                          for p, f in zip(self.poses, self.frames)],
                "shapes": {n: [round(float(g), 3), round(float(o), 3)] for n, g, o in zip(r.names, r.gain, r.offset)
                           if n in r.changed()}}


def score_noise(scores, neutral, fps):
    """(S,) each score's noise on the ``neutral`` frames: the robust spread of its moving mean (the activity's
    smoothing) there, at least ``NOISE_FLOOR``."""
    s = np.asarray(scores, dtype=np.float64)
    half = half_window(fps)
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    filled = np.where(np.isfinite(s), s, np.nanmedian(s[neutral], axis=0))
    smooth = np.stack([np.convolve(np.pad(col, half, mode="edge"), kernel, mode="valid") for col in filled.T], axis=1)
    rest = smooth[neutral]
    mad = np.nanmedian(np.abs(rest - np.nanmedian(rest, axis=0)), axis=0)
    return np.maximum(np.nan_to_num(1.4826 * mad), NOISE_FLOOR)


def find_score_holds(scores, neutral, fps):
    """The holds of a ROM clip in its blendshape ``scores`` (F, S) with ``neutral`` frame indices: the marker
    ROM's hold finder (``rom.holds``) on the scores' deviations from their neutral level, one coordinate per
    score, each in units of its noise there. Frames are indices 0 .. F-1."""
    s = np.asarray(scores, dtype=np.float64)
    s0 = np.nanmedian(s[neutral], axis=0)
    noise = score_noise(s, neutral, fps)
    x = ((s - s0) / noise)[:, :, None]
    # find_holds measures smoothed 3D deltas against noise * sqrt(3 / n); ours are 1D and already per unit of
    # the smoothed noise, so the scale that makes its unit 1
    unit = np.sqrt((2 * half_window(fps) + 1) / 3.0)
    return find_holds(x, np.arange(len(s), dtype=np.float64), fps, unit)


def fit_response(scores, names, neutral, poses, *, fps, reference=None, sheet="", given=None):
    """The performer's score response from a ROM clip.

    Parameters
    ----------
    scores : (F, S) the clip's blendshape scores (NaN: no face), columns ``names`` (ARKit names)
    neutral : indices of the clip's neutral frames (the rests between the poses)
    poses : the sheet performed (``rom.sequence_poses``), in order
    fps : the clip's frame rate
    reference : ScoreResponse, optional
        The same fit on the faces the fusion table was measured on (``FusionTable.reference``): the response is
        then this performer's relative to theirs (``reference^-1 o own``), so that the table's gains, fitted on
        their scores, apply to this performer's. Without it the scores are calibrated to the weights asked.
    sheet : what to call the sheet in the response (a built-in sheet's name)
    given : {pose label: middle frame index}, optional
        Where the user put the poses (``[calibration] holds``, the ``ROM: `` timeline markers after Find Poses):
        only those poses are measured, there (around the hold found at each middle, moved there), and nothing is
        named by the sheet's order.

    Returns
    -------
    ResponseFit. Poses whose holds could be read more than one way (``Alignment.ambiguous``: a stretch of poses
    the camera barely sees) are left out and named, never guessed. Raises FacecapError when the clip has no
    neutral, no pose is found, or more than half of the sheet cannot be named for sure (the poses named).
    """
    s = np.asarray(scores, dtype=np.float64)
    names = tuple(str(n) for n in names)
    neutral = np.asarray(neutral, dtype=np.int64)
    if s.ndim != 2 or s.shape[1] != len(names):
        raise FacecapError(f"`scores` must have shape (F, {len(names)}) for its names; got {s.shape}")
    if neutral.size == 0:
        raise FacecapError("the ROM clip's neutral frames were not found (rest between the poses, or give "
                           "[calibration] neutral)")
    if not len(poses):
        raise FacecapError("the ROM sheet has no pose")
    holds = find_score_holds(s, neutral, fps)
    corrected = neutral_corrected(s, neutral)
    asked = _asked(poses, names)
    if given:
        spans, _, _ = given_spans(poses, given, holds, fps)
        found = [j for j in range(len(poses)) if spans[j] is not None]
        align, unsure, unseen = None, [], []
    else:
        align, spans, found, unsure, unseen = _named_holds(holds, corrected, asked, poses, names, reference)
    gain, offset, kept = _fit_shapes(np.stack([_median(corrected, spans[j]) for j in found]), asked[found],
                                     np.nanmedian(corrected[neutral], axis=0), names)
    own = ScoreResponse(names, gain, offset, sheet)
    response = own if reference is None else relative(own, reference)
    notes = []
    if unseen:
        notes.append(f"ROM clip: pose(s) of shapes no blendshape score names, left out: {unseen}")
    if unsure:
        notes.append(f"ROM clip: the holds around pose(s) {unsure} could be read more than one way (a pose the "
                     "camera barely sees, skipped or added there): left out of the calibration")
    missed = [] if align is None else [poses[j].label for j in align.skipped
                                       if j not in align.ambiguous and poses[j].label not in unseen]
    if missed:
        notes.append(f"ROM clip: pose(s) not found (skipped, or not seen by the camera; their shapes keep their "
                     f"scores unless another pose asks them): {missed}")
    if align is not None and align.extra:
        notes.append("ROM clip: expression(s) at frames "
                     f"{[f'{holds[h].start:g}-{holds[h].end:g}' for h in align.extra]} match no pose of the sheet "
                     "and are left out")
    if kept:
        notes.append(f"ROM clip: score(s) that do not move where the sheet asks them, kept as scored: {kept}")
    where = f"{len(found)} of {len(poses)} poses where they were placed" if given else \
        f"{len(found)} of {len(poses)} poses found ({len(holds)} holds in the clip)"
    summary = f"{where}; {len(response.changed())} scores calibrated"
    exercised = {n: int((asked[found][:, k] > 0).sum()) for k, n in enumerate(names)}
    return ResponseFit(response, tuple(poses), tuple(None if f is None else (int(f[0]), int(f[1])) for f in spans),
                       holds, align, exercised, tuple(notes), summary)


def fit_weights_response(values, names, neutral, frames, poses, *, sheet="", keep=()):
    """The same per-shape gain and offset as :func:`fit_response`, fitted on another reading of the ROM clip
    (``values`` (F, S) named ``names``: the landmark solve's weights, say) at the frames a score fit found each pose
    at (``ResponseFit.frames``, None for a pose not found); names in ``keep`` (shapes another step already measures
    against the take, such as the lids' locks) are left as they are. A ScoreResponse (not relative to anything)."""
    v = np.asarray(values, dtype=np.float64)
    names = tuple(str(n) for n in names)
    found = [j for j, f in enumerate(frames) if f is not None]
    if not found:
        raise FacecapError("no pose of the ROM clip was found to fit a response on")
    x = np.stack([_median(v, frames[j]) for j in found])
    x0 = np.nanmedian(v[np.asarray(neutral, dtype=np.int64)], axis=0)
    gain, offset, _ = _fit_shapes(x, _asked(poses, names)[found], x0, names)
    for k, name in enumerate(names):
        if name in keep:
            gain[k], offset[k] = 1.0, 0.0
    return ScoreResponse(names, gain, offset, sheet)


def _named_holds(holds, corrected, asked, poses, names, reference):
    """(Alignment, measured frames per pose, poses found, poses left out as ambiguous, poses no score names) of the
    ``holds`` found, named by the sheet in order against what the reference faces would score."""
    if not holds:
        raise FacecapError("no pose of the sheet was found in the ROM clip: its scores never leave their level on "
                           "the neutral frames")
    measured = np.stack([_median(corrected, h.measured()) for h in holds])
    predicted = asked if reference is None else expected_scores(asked, names, reference)
    # a pose the reference faces' scores do not read is predicted by its asked weights (what a score named after its
    # shapes would read); one no score names cannot be told from any other hold and is not aligned at all (matched by
    # a cosine of 0 it would take whatever hold is near, an extra expression or a neighbour's)
    predicted = np.where(predicted.any(axis=1, keepdims=True), predicted, asked)
    seen = np.flatnonzero(predicted.any(axis=1))
    unseen = [poses[j].label for j in range(len(poses)) if j not in set(seen)]
    part = align_holds(np.nan_to_num(measured)[:, :, None], predicted[seen][:, :, None], np.zeros(len(seen), bool))
    align = _widen(part, seen, len(poses))
    unsure = [poses[j].label for j in align.ambiguous]
    found = [j for j in range(len(poses)) if align.hold_of[j] >= 0 and j not in align.ambiguous]
    if len(unsure) * 2 > len(poses) or not found:
        raise FacecapError("the ROM clip's holds do not follow the sheet clearly" + (
            f" around pose(s) {unsure}" if unsure else "") + f" ({len(holds)} holds found for {len(poses)} poses, "
            f"{len(found)} named for sure): a pose skipped, repeated or added there. Check the clip, or film it again")
    spans = [holds[align.hold_of[j]].measured() if j in found else None for j in range(len(poses))]
    return align, spans, found, unsure, unseen


def _widen(align, seen, J):
    """The Alignment of the poses ``seen`` (indices into the sheet's J poses) on the whole sheet (the others
    unmatched)."""
    hold_of = np.full(J, -1)
    hold_of[seen] = align.hold_of
    pose_of = tuple(int(seen[j]) if j >= 0 else -1 for j in align.pose_of)
    return Alignment(pose_of, tuple(int(h) for h in hold_of), align.score, tuple(int(seen[j]) for j in align.ambiguous))


def expected_scores(asked, names, reference):
    """(J, S) what the ``reference`` faces' scores read for the weights ``asked`` (J, S) of each pose: the inverse
    of their response per score; 0 for a score they left as scored (it did not respond, or its pose was not found
    on their clips: a pose that only asks such scores is one the camera is not expected to see)."""
    out = np.array(asked, dtype=np.float64)
    ref = {n: k for k, n in enumerate(reference.names)}
    changed = set(reference.changed())
    for j, name in enumerate(names):
        if name not in ref:
            continue  # nothing known: the weight asked
        k = ref[name]
        out[:, j] = np.where(asked[:, j] > 0, np.maximum((asked[:, j] - reference.offset[k]) / reference.gain[k], 0.0),
                             0.0) if name in changed else 0.0
    return out


def relative(own, reference):
    """The response that reads ``own``'s scores as ``reference``'s faces would score the same weights:
    ``reference^-1 o own`` per name (gain own/ref, offset (own - ref) / ref); the identity where either left a
    score as it is (it did not respond, or its sheet did not ask it: the scales cannot be related)."""
    ref = {n: (g, o) for n, g, o in zip(reference.names, reference.gain, reference.offset)}
    changed = set(own.changed()) & set(reference.changed())
    gain, offset = np.ones(len(own.names)), np.zeros(len(own.names))
    for k, name in enumerate(own.names):
        if name in changed:
            g, o = ref[name]
            gain[k] = np.clip(own.gain[k] / g, *GAIN_RANGE)
            offset[k] = np.clip((own.offset[k] - o) / g, -MAX_OFFSET, MAX_OFFSET)
    return ScoreResponse(own.names, gain, offset, own.sheet)


def _fit_shapes(x, y, x0, names):
    """Per score (gain, offset) from the poses found: ``x`` (J, S) what each scored, ``y`` (J, S) the weights asked,
    ``x0`` (S,) the neutral's; and the names kept as scored because they did not respond."""
    gain, offset, kept = np.ones(len(names)), np.zeros(len(names)), []
    for k, name in enumerate(names):
        ask = y[:, k] > 0
        if not ask.any() or not np.isfinite(x0[k]):
            continue
        if not np.nanmax((x[ask, k] - x0[k]) / y[ask, k]) >= MIN_RESPONSE:
            kept.append(name)
            continue
        xs, ys = np.r_[x0[k], x[:, k]], np.r_[0.0, y[:, k]]
        weights = np.r_[NEUTRAL_WEIGHT, np.where(ask, 1.0, UNASKED_WEIGHT)]
        ok = np.isfinite(xs)
        gain[k], offset[k] = _robust_line(xs[ok], ys[ok], weights[ok])
    return gain, offset, kept


def _asked(poses, names):
    """(J, S) the weights each pose asks of the scores ``names`` (a pose's shapes without a score left out)."""
    index = {n: k for k, n in enumerate(names)}
    out = np.zeros((len(poses), len(names)))
    for j, pose in enumerate(poses):
        for shape, weight in pose.weights:
            if shape in index:
                out[j, index[shape]] = weight
    return out


def _median(values, span):
    first, last = span
    sel = values[max(0, first): last + 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a pose without a face: NaN
        return np.nanmedian(sel, axis=0)


def _robust_line(x, y, w):
    """(gain, offset) of y ~ gain * x + offset by weighted least squares with Huber reweighting, pulled towards
    (1, 0) (``SHRINK_GAIN``, ``SHRINK_OFFSET``); the gain clamped to ``GAIN_RANGE`` (the offset refitted then)
    and the offset to +-``MAX_OFFSET``."""
    prior = np.array([1.0, 0.0])
    ridge = np.diag([SHRINK_GAIN, SHRINK_OFFSET])
    A = np.stack([x, np.ones_like(x)], axis=1)
    huber = np.ones_like(x)
    p = prior
    for _ in range(HUBER_STEPS):
        ww = w * huber
        p = np.linalg.solve(A.T @ (ww[:, None] * A) + ridge, A.T @ (ww * y) + ridge @ prior)
        r = np.abs(y - A @ p)
        huber = np.where(r <= HUBER, 1.0, HUBER / np.maximum(r, 1e-12))
    gain = float(np.clip(p[0], *GAIN_RANGE))
    if gain != p[0]:
        ww = w * huber
        offset = (np.sum(ww * (y - gain * x))) / (np.sum(ww) + SHRINK_OFFSET)
    else:
        offset = p[1]
    return gain, float(np.clip(offset, -MAX_OFFSET, MAX_OFFSET))


def save_profile(path, *, basis=None, response=None, performer=None):
    """Write a performer profile (.npz, atomically): the actor's measured shapes (``basis``, a Basis: what
    ``Basis.save_npz`` writes), the blendshape scores' ``response`` (a ScoreResponse) and/or the performer's clip in
    the fusion map (``performer``, a ``follow.PerformerMap``: a guide followed)."""
    if basis is None and response is None and performer is None:
        raise FacecapError("a performer profile needs measured shapes, a score response or a guide followed")
    arrays = {} if response is None else response.to_arrays()
    if performer is not None:
        arrays.update(performer.to_arrays())
    if basis is not None:
        arrays.update(shape_names=np.array(basis.shape_names), marker_names=np.array(basis.marker_names),
                      neutral=basis.neutral, deltas=basis.deltas, lower=basis.lower, upper=basis.upper)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez_compressed(tmp, **arrays)


def profile_contents(path):
    """(has measured shapes, the ScoreResponse or None) of the performer profile ``path``; InputFileError naming
    the file when it is not one (``profile_performer`` reads a guide's clip it holds)."""
    shapes, response, _ = _profile(path)
    return shapes, response


def profile_performer(path):
    """The performer's clip in the fusion map (``follow.PerformerMap``: a guide followed) the profile ``path`` holds,
    or None."""
    return _profile(path)[2]


def _profile(path):
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            response = ScoreResponse.from_arrays({k: z[k] for k in PROFILE_KEYS if k in keys}, where=str(path))
            performer = PerformerMap.from_arrays({k: z[k] for k in PERFORMER_KEYS if k in keys}, where=str(path))
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise InputFileError(path, f"not a performer profile (.npz written by facecap): {exc}") from None
    except FacecapError as exc:
        raise InputFileError(path, str(exc).removeprefix(f"{path}: ")) from None
    shapes = {"shape_names", "marker_names", "deltas"} <= keys
    if not shapes and response is None and performer is None:
        raise InputFileError(path, "not a performer profile: it holds neither measured shapes, a score response nor "
                                   "a guide followed")
    return shapes, response, performer
