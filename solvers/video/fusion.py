"""Two signals from one video, combined: the Face Landmarker's blendshape scores and facecap's solve from the
landmarks.

They fail on different shapes (docs/video.md): the blendshape head reads brow raises, ``browInnerUp``,
the look down, the jaw's sideways and forward motion and lip presses that the landmarks barely move; the
landmark solve is better on the jaw opening, the lower lip, smiles and blinks. And each misreads one shape as
another (the head's lower-lip score rises with the jaw, its frown with a stretch). So every fused shape is read
from the corrected scores and solved weights of its half of the face (``face_half``)::

    c = (s - s0) / (1 - s0)          each score s corrected by its level s0 on the take's neutral frames
    c = response(c)                  the performer's response on this camera (a ROM calibration; identity)
    l = lids against gaze(l)         the solve's blinks and wide eyes read against its look down (``lid_gaze``)
    w = W' [c, l]                    l the landmark solve's weights, W the fusion map (with the performer's
                                     clip in it when they followed a guide: ``follow.py``)
    w = smooth(w), clip(w, lower, upper)  smoothed over time (SMOOTHING_S; blinks left sharp), within bounds

The map ``W`` (``CrossMap``) is ridge regression towards the per-shape table (``w_k = a_k c_k + b_k l_k``, ``a``
and ``b`` >= 0 fitted per shape by ``fit_table``): the off-diagonal terms only undo the cross-talk the tuning
clips show within a half of the face. It is kept as the tuning clips' normal equations (``fusion_map.npz``), so a
take whose character lacks some ARKit shapes gets the map solved for the inputs it has. The map, the table and the
lids' slope are measured, not chosen: ``python -m facecap.facecap_addon.bench.fusion_bench --fit`` fits them on
rendered clips with known weights (two ICT identities, two cameras, two performers' recordings, the same faces
performing the ROM sheet and firing shapes at random, so that the map learns the head's cross-talk rather than one
performance's habits; ``fusion_table.json`` says which clips) and never on the clips it reports. The result keeps
the landmark take's own path onto the character: the semantic solve's weights are the actor's activations keyed on
the character's shapes of the same name (``strategies/semantic``), and the fused weight of a shape replaces its
solved one by that name (aliases matched as ``parallel`` matches them); shapes without a score (``tongueOut``, a
character's own shapes) keep the solve.
"""

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..character.aliases import canonical_names
from ..errors import FacecapError
from ..io.files import atomic_path, write_text_atomic
from . import gaze
from .score_response import ScoreResponse

TABLE_FILE = Path(__file__).resolve().parent / "fusion_table.json"
#: The fusion map beside its table (``CrossMap``).
MAP_FILE_NAME = "fusion_map.npz"
#: The fused weights' smoothing over time (Gaussian sigma, seconds): each frame's scores come from its own landmarks,
#: so the fused weights jitter (mean |second difference| 0.0090 on the tuning clips against their truth's 0.0042);
#: one frame at 30 frames/s makes them as rough as the truth there (0.0040; visible RMSE 0.1139 -> 0.1133;
#: ``fusion_bench --smoothing``).
SMOOTHING_S = 1.0 / 30.0
#: Shapes left unsmoothed: a blink closes and opens in a few frames, and the smoothing took 0.05-0.1 off its peak.
UNSMOOTHED = frozenset(("eyeBlinkLeft", "eyeBlinkRight"))
#: The largest gain a table gives a signal: a score that barely moves in the tuning clips (eyeLookUp: 12x
#: unbounded) would turn another face's noise into motion.
MAX_GAIN = 2.0


@dataclass(frozen=True)
class FusionTable:
    """Per shape (ARKit names) the gains of the corrected score (``score``) and of the landmark solve (``solve``);
    ``reference``: how the tuning faces' scores respond to a ROM sheet (a ``ScoreResponse``, or None),
    which a performer's ROM clip is calibrated against (``response.fit_response``); ``map``: the fusion map
    (``CrossMap``, or None: per shape only), loaded from ``fusion_map.npz`` beside the table; ``lid_gaze``: how
    the landmark solve's lid gap (a share of its neutral gap) changes per unit of its eyeLookDown (negative: a look
    down closes it; 0: the solve's lids as they are), by which its blinks and wide eyes are read against its gaze
    before they are fused (``lids_against_gaze``)."""

    score: dict
    solve: dict
    measured_on: dict = field(default_factory=dict)
    reference: object = None
    map: object = None
    lid_gaze: float = 0.0

    @classmethod
    def load(cls, path=TABLE_FILE):
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            ref = data.get("rom_reference")
            reference = None if ref is None else ScoreResponse(
                tuple(ref["shapes"]), [v[0] for v in ref["shapes"].values()], [v[1] for v in ref["shapes"].values()],
                ref["sheet"])
            table = cls({k: float(v[0]) for k, v in data["shapes"].items()},
                        {k: float(v[1]) for k, v in data["shapes"].items()}, data.get("measured_on", {}), reference,
                        lid_gaze=float(data.get("lid_gaze", 0.0)))
            if not -1.0 <= table.lid_gaze <= 0.0:
                raise ValueError(f"lid_gaze must be from -1 to 0; got {table.lid_gaze}")
        except (OSError, ValueError, KeyError, IndexError, TypeError, FacecapError) as exc:
            raise FacecapError(f"{path}: not a fusion table ({exc})") from None
        beside = path.with_name(MAP_FILE_NAME)
        return replace(table, map=CrossMap.load(beside)) if beside.is_file() else table

    def save(self, path=TABLE_FILE):
        rows = ",\n".join(f'  "{k}": [{self.score[k]:.4f}, {self.solve[k]:.4f}]' for k in self.score)
        head = json.dumps({"format": "facecap-fusion-table", "measured_on": self.measured_on,
                           "lid_gaze": round(self.lid_gaze, 4), "columns": ["score gain a", "solve gain b"]})
        text = head[:-1] + ', "shapes": {\n' + rows + "\n}"
        if self.reference is not None:
            r = self.reference
            refs = ",\n".join(f'  "{n}": [{g:.4f}, {o:.4f}]' for n, g, o in zip(r.names, r.gain, r.offset))
            text += (f', "rom_reference": {{"sheet": {json.dumps(r.sheet)}, "columns": ["gain", "offset"], '
                     f'"shapes": {{\n{refs}\n}}}}')
        text += "}"
        write_text_atomic(path, text + "\n")


@dataclass(frozen=True, eq=False)
class CrossMap:
    """The fusion map: each shape of ``names`` (ARKit) from the corrected scores and the solved weights of ``names``
    in its half of the face (inputs: the scores, then the solve), by ridge regression towards the per-shape table.
    Kept as the tuning clips' normal equations, each clip weighing the same: ``gram`` (2S, 2S) the inputs' mean
    products, ``moment`` (2S, S) the inputs' with the truth, ``ridge`` the pull towards the table (the clips' count
    times lambda)."""

    names: tuple
    gram: np.ndarray
    moment: np.ndarray
    ridge: float

    def allowed(self):
        """(2S, S) which inputs may read each shape: its own score and solve, and those of its half of the face."""
        half = np.array([face_half(n) for n in self.names])
        same = half[:, None] == half[None, :]
        return np.r_[same, same]

    def weights(self, table, have_score, have_solve):
        """(P, S) the map for the inputs a take has (``have_score``, ``have_solve``: (S,) bools; P the count of
        inputs had, scores first), solved from the normal equations with the others left out; 0 for an input
        another half of the face (``allowed``)."""
        S = len(self.names)
        prior = np.zeros((2 * S, S))
        prior[np.arange(S), np.arange(S)] = [table.score.get(n, 0.0) for n in self.names]
        prior[S + np.arange(S), np.arange(S)] = [table.solve.get(n, 1.0) for n in self.names]
        use = np.flatnonzero(np.r_[np.asarray(have_score, bool), np.asarray(have_solve, bool)])
        allowed = self.allowed()[use]
        out = np.zeros((use.size, S))
        for j in range(S):
            rows = np.flatnonzero(allowed[:, j])
            u = use[rows]
            A = self.gram[np.ix_(u, u)] + self.ridge * np.eye(u.size)
            out[rows, j] = np.linalg.solve(A, self.moment[u, j] + self.ridge * prior[u, j])
        return out

    @classmethod
    def load(cls, path):
        try:
            with np.load(path, allow_pickle=False) as z:
                names = tuple(str(n) for n in z["names"])
                out = cls(names, np.asarray(z["gram"], np.float64), np.asarray(z["moment"], np.float64),
                          float(z["ridge"]))
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise FacecapError(f"{path}: not a fusion map ({exc})") from None
        S = len(out.names)
        if out.gram.shape != (2 * S, 2 * S) or out.moment.shape != (2 * S, S) or not out.ridge > 0:
            raise FacecapError(f"{path}: a fusion map of {S} shapes needs a ({2 * S}, {2 * S}) gram and a "
                               f"({2 * S}, {S}) moment and a positive ridge")
        return out

    def save(self, path):
        """Write atomically (``io.files.atomic_path``)."""
        with atomic_path(Path(path), suffix=".npz") as tmp:
            np.savez_compressed(tmp, names=np.array(self.names, dtype=str), gram=self.gram, moment=self.moment,
                                ridge=np.float64(self.ridge))


def face_half(name):
    """"upper" (brows, lids, gaze: ARKit ``brow*`` and ``eye*``) or "lower" (cheeks, nose, jaw, mouth, tongue).
    What the head misreads stays within a half (a lower lid's score moves with a squint, a lip's with the jaw);
    what goes with what across the halves (a frown with raised brows) is how the tuning faces performed, not
    how the head reads, and the map leaves it out."""
    return "upper" if name.startswith(("brow", "eye")) else "lower"


def fit_map(clips, names, lam):
    """The fusion map from tuning ``clips``: [(truth, solved, corrected) each (F, S) on ARKit ``names``], each clip
    weighing the same whatever its length; ``lam`` the ridge per clip (towards the table the map is solved with).
    NaN inputs count as 0 (a score or a shape a clip lacks); NaN truth frames are left out."""
    S = len(names)
    gram, moment = np.zeros((2 * S, 2 * S)), np.zeros((2 * S, S))
    for truth, solved, corrected in clips:
        g, m, _ = clip_equations(truth, np.concatenate([corrected, solved], axis=1))
        gram += g
        moment += m
    return CrossMap(tuple(names), gram, moment, lam * len(clips))


def clip_equations(truth, inputs):
    """One clip's share of the map's normal equations: (gram (2S, 2S), moment (2S, S), frames used) of its
    ``inputs`` (F, 2S: the scores, then the solve; NaN counts as 0) against ``truth`` (F, S), the frames where the
    truth is known, as means (each clip weighs the same whatever its length)."""
    ok = np.isfinite(truth).all(axis=1)
    X = np.nan_to_num(np.asarray(inputs, dtype=np.float64)[ok])
    n = max(int(ok.sum()), 1)
    return X.T @ X / n, X.T @ truth[ok] / n, int(ok.sum())


@dataclass(frozen=True, eq=False)
class FaceScores:
    """A take's blendshape scores: ``values`` (F, S) named ``names`` (NaN at frames without a face), the take's
    neutral frames (indices) they are corrected by, and the performer's ``response`` on this camera, if known:
    ``response(corrected (F, S), names) -> (F, S)`` (per shape gain/offset or a monotone curve, from the
    performer's ROM clip; the calibration issue's performer profile will provide it). It is applied to the
    neutral-corrected scores and nowhere else (:func:`fuse`)."""

    values: np.ndarray
    names: tuple
    neutral: np.ndarray
    response: object = None
    fps: float = None  # the take's frame rate: the fused weights are smoothed over time when it is known
    smoothing: bool = True  # ``[tracking] smoothing``: the detector's jitter filtered out of the fused weights too
    performer: object = None  # the performer's clip in the map (``follow.PerformerMap``: a guide followed), if known


def neutral_corrected(scores, neutral):
    """(F, S) scores corrected by their median over the ``neutral`` frame indices: (s - s0) / (1 - s0), >= 0."""
    s = np.asarray(scores, dtype=np.float64)
    idx = np.asarray(neutral, dtype=np.int64)
    if idx.size == 0:
        raise FacecapError("the blendshape scores need the take's neutral frames; none was given or detected")
    s0 = np.nanmedian(s[idx], axis=0)
    s0 = np.where(np.isfinite(s0), np.clip(s0, 0.0, 0.95), 0.0)
    return np.clip((s - s0) / (1.0 - s0), 0.0, None)


def fuse(weights, shape_names, scores, *, table=None, response=None, lower=0.0, upper=1.0, cross=True):
    """The solve's ``weights`` (F, K) on ``shape_names`` combined with ``scores`` (FaceScores).

    Parameters
    ----------
    table : FusionTable (default: the measured one, ``fusion_table.json`` and its map)
    response : callable(corrected (F, S), names) -> (F, S), optional
        The performer's response calibration (per shape gain/offset or monotone curve for this performer and
        camera), applied to the neutral-corrected scores before they are combined: the one place it plugs in
        (default: ``scores.response``).
    lower, upper : scalar or (K,) bounds of the character's shapes
    cross : read the shapes the table's map names through the map (every score and solved weight); False: each
        shape from its own score and solve only (the per-shape table, as without a map)

    Returns
    -------
    (weights (F, K), list of the fused shape names)
    """
    table = FusionTable.load() if table is None else table
    if scores.performer is not None:
        table = scores.performer(table)
    w = np.array(weights, dtype=np.float64)
    if len(scores.values) != len(w):
        raise FacecapError(f"the blendshape scores have {len(scores.values)} frames; the solve has {len(w)}")
    corrected, column, solve, arkit = _prepared(w, shape_names, scores, table, response)
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (w.shape[1],))
    hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (w.shape[1],))
    mapped = {}
    if cross and table.map is not None and any(n in column for n in table.map.names):
        mapped = _through_map(table, corrected, column, solve, arkit)
    sigma = SMOOTHING_S * scores.fps if scores.smoothing and scores.fps else 0.0
    fused = []
    for k, name in enumerate(shape_names):
        if arkit[k] in mapped:
            seen, values = mapped[arkit[k]]
        elif arkit[k] in column and arkit[k] in table.score:
            a, b = table.score[arkit[k]], table.solve[arkit[k]]
            c = corrected[:, column[arkit[k]]]
            seen = np.isfinite(c)  # frames without a face keep the solve (a gap stays a gap)
            values = a * c[seen] + b * np.nan_to_num(solve[seen, k])
        else:
            continue
        if sigma > 0 and arkit[k] not in UNSMOOTHED:
            values = smooth_runs(values, seen, sigma)
        w[seen, k] = np.clip(values, lo[k], hi[k])
        fused.append(name)
    return w, fused


def lids_against_gaze(weights, names, per_look_down):
    """A copy of solved ``weights`` (F, K) on ARKit ``names`` with each eye's eyeBlink and eyeWide read against its
    eyeLookDown (``gaze.lids_against_gaze``; ``per_look_down`` 0 or an eye without the three shapes: as they are).
    The landmark solve sets all three from the landmarks (``gaze.gaze_locks``), and a look down lowers the lid."""
    out = np.array(weights, dtype=np.float64)
    column = {}
    for k, n in enumerate(names):
        column.setdefault(n, k)
    for side in ("Left", "Right") if per_look_down else ():
        blink, wide, down = (column.get(f"eye{s}{side}") for s in ("Blink", "Wide", "LookDown"))
        if None not in (blink, wide, down):
            seen = np.isfinite(out[:, blink]) & np.isfinite(out[:, wide])
            b, w = gaze.lids_against_gaze(out[seen, blink], out[seen, wide], out[seen, down], per_look_down)
            out[seen, blink], out[seen, wide] = b, w
    return out


def smooth_runs(values, seen, sigma):
    """``values`` (one row per True of ``seen``, (F,) bools; (n,) or (n, K)) smoothed by a Gaussian of ``sigma``
    frames within each run of consecutive seen frames (no frame is smoothed across a gap; a run's ends repeat its
    first and last value). Every run at once: each offset of the kernel reads its neighbour clipped to the run."""
    values = np.asarray(values, dtype=np.float64)
    half = int(np.ceil(3 * sigma))
    n = len(values)
    if half < 1 or n < 2:
        return values
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    kernel /= kernel.sum()
    starts = np.r_[0, np.flatnonzero(np.diff(np.flatnonzero(seen)) != 1) + 1]  # where each run of seen frames starts
    run = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, n]))
    first, last = starts[run], np.r_[starts[1:], n][run] - 1
    rows = np.arange(n)
    return sum(k * values[np.clip(rows + offset, first, last)] for offset, k in zip(range(-half, half + 1), kernel))


def _prepared(weights, shape_names, scores, table, response=None):
    """What the fusion reads of a take: (the corrected scores (F, S) read through the performer's response, {score
    name: column}, the solve (F, K) with its lids read against its gaze, the ARKit name of each of ``shape_names``
    (None: not one ARKit shape))."""
    corrected = neutral_corrected(scores.values, scores.neutral)
    response = scores.response if response is None else response
    if response is not None:
        corrected = np.asarray(response(corrected, tuple(scores.names)), dtype=np.float64)
    column = {n: j for j, n in enumerate(scores.names)}
    arkit = arkit_names(shape_names)
    solve = lids_against_gaze(np.array(weights, dtype=np.float64), arkit, table.lid_gaze)
    return corrected, column, solve, arkit


def arkit_names(shape_names):
    """The ARKit name of each of a character's ``shape_names``, through the alias tables (None: not one ARKit
    shape)."""
    out = []
    for name in shape_names:
        names = canonical_names(name)
        out.append(names[0] if len(names) == 1 else None)
    return out


def map_inputs(table, scores, weights, shape_names):
    """(inputs (n, 2S), frames (F,) bools): the map's inputs (``table.map.names``: the scores, then the solve; 0 for
    one the take lacks) at the ``n`` frames with a face, of the solve ``weights`` (F, K) on ``shape_names`` and the
    take's ``scores`` (FaceScores), prepared as :func:`fuse` prepares them: what a performer's clip adds to the map
    (``follow.py``)."""
    corrected, column, solve, arkit = _prepared(weights, shape_names, scores, table)
    names = table.map.names
    solve_of = {}
    for k, n in enumerate(arkit):
        solve_of.setdefault(n, k)
    S = len(names)
    X = np.zeros((len(solve), 2 * S))
    for j, n in enumerate(names):
        if n in column:
            X[:, j] = corrected[:, column[n]]
        if n in solve_of:
            X[:, S + j] = np.nan_to_num(solve[:, solve_of[n]])
    scored = [column[n] for n in names if n in column]
    seen = np.isfinite(corrected[:, scored]).all(axis=1)
    return X[seen], seen


def _through_map(table, corrected, column, solve, arkit):
    """{ARKit name: (frames with a face, values there)} of every shape the map names, from the scores it has and
    the character's solved shapes of its names (the first by that name)."""
    names = table.map.names
    have_score = np.array([n in column for n in names])
    solve_of = {}
    for k, n in enumerate(arkit):
        solve_of.setdefault(n, k)
    have_solve = np.array([n in solve_of for n in names])
    W = table.map.weights(table, have_score, have_solve)
    scored = corrected[:, [column[n] for n, h in zip(names, have_score) if h]]
    seen = np.isfinite(scored).all(axis=1)  # frames without a face keep the solve
    X = np.concatenate([scored[seen], np.nan_to_num(solve[np.ix_(seen, [solve_of[n] for n, h in zip(names, have_solve)
                                                                       if h])])], axis=1)
    values = X @ W
    return {n: (seen, values[:, j]) for j, n in enumerate(names)}


def fit_table(truth, solved, corrected, names, *, measured_on=None):
    """The fusion table from tuning clips: per shape, non-negative (a, b) minimising
    ||a * corrected + b * solved - truth||^2 over every frame of every clip (``truth``, ``solved``,
    ``corrected`` (F, S) stacked over the clips, columns ``names``), each gain at most ``MAX_GAIN``. A shape's
    Left and Right share their gains (fitted on both sides' frames together): the face and the models are
    symmetric, and a gain that differs between the sides would be the tuning clips' noise."""
    from scipy.optimize import lsq_linear  # scipy: imported on first use (only the benchmark fits tables)

    groups = {}
    for j, name in enumerate(names):
        groups.setdefault(_unsided(name), []).append(j)
    score, solve = {}, {}
    for columns in groups.values():
        A = np.concatenate([np.stack([corrected[:, j], solved[:, j]], axis=1) for j in columns])
        y = np.concatenate([truth[:, j] for j in columns])
        ok = np.isfinite(A).all(axis=1) & np.isfinite(y)
        if ok.sum() < 10 or np.ptp(y[ok]) < 1e-6:
            a, b = 0.0, 1.0  # nothing to learn from: the solve as it is
        else:
            a, b = lsq_linear(A[ok], y[ok], bounds=(0.0, MAX_GAIN)).x
        for j in columns:
            score[names[j]], solve[names[j]] = float(a), float(b)
    return FusionTable(score, solve, measured_on or {})


def fit_lid_gaze(truth, solved, names):
    """``FusionTable.lid_gaze`` from tuning clips (``truth``, ``solved`` (F, S) stacked, columns ARKit ``names``):
    the least-squares slope through 0 of the solve's lid gap (``gaze.gap_from_lids``, less 1) on its eyeLookDown,
    over the frames where the truth neither blinks, widens nor squints that eye (every change of the gap there is
    the gaze's) and the gap is read unclipped. 0 when no frame looks down (or no eye has the four shapes)."""
    column = {n: j for j, n in enumerate(names)}
    x, y = [], []
    for side in ("Left", "Right"):
        blink, wide, down, squint = (column.get(f"eye{s}{side}") for s in ("Blink", "Wide", "LookDown", "Squint"))
        if None in (blink, wide, down, squint):
            continue
        gap = gaze.gap_from_lids(np.nan_to_num(solved[:, blink]), np.nan_to_num(solved[:, wide]))
        still = (truth[:, blink] < 0.02) & (truth[:, wide] < 0.02) & (truth[:, squint] < 0.05)
        unclipped = (gap > gaze.CLOSED_GAP + 0.01) & (gap < 1.0 + 0.99 * gaze.WIDE)
        ok = still & unclipped & np.isfinite(solved[:, down])
        x.append(solved[ok, down])
        y.append(gap[ok] - 1.0)
    x, y = (np.concatenate(v) if v else np.zeros(0) for v in (x, y))
    return float(np.clip(x @ y / (x @ x), -1.0, 0.0)) if x @ x > 0 else 0.0


def _unsided(name):
    for side in ("Left", "Right"):
        if name.endswith(side):
            return name[: -len(side)]
    return name
