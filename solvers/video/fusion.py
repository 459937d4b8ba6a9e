"""Two signals from one video, combined per shape: the Face Landmarker's blendshape scores and facecap's
solve from the landmarks.

They fail on different shapes (docs/video.md): the blendshape head reads brow raises, ``browInnerUp``,
the look down, the jaw's sideways and forward motion and lip presses that the landmarks barely move; the
landmark solve is better on the jaw opening, the lower lip, smiles and blinks. Per shape::

    c = (s - s0) / (1 - s0)          the score s corrected by its level s0 on the take's neutral frames
    c = response(c)                  the performer's response on this camera (a later ROM calibration; identity)
    w = a * c + b * l                l the landmark solve's weight; a, b >= 0 from the fusion table
    w = clip(w, lower, upper)

``a`` and ``b`` are measured, not chosen: ``python -m facecap.facecap_addon.bench.fusion_bench --fit`` fits them by
non-negative least squares per shape on rendered clips with known weights (two ICT identities, two
cameras, one recording; ``fusion_table.json`` beside this module says which) and never on the clips it
reports. The result keeps the landmark take's own path onto the character: the semantic solve's weights
are the actor's activations keyed on the character's shapes of the same name (``strategies/semantic``),
and the fused weight of a shape replaces its solved one by that name (aliases matched as ``parallel``
matches them); shapes without a score (``tongueOut``, a character's own shapes) keep the solve.
"""

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..character.aliases import canonical_names
from ..errors import FacecapError
from .score_response import ScoreResponse

TABLE_FILE = Path(__file__).resolve().parent / "fusion_table.json"
#: The largest gain a table gives a signal: a score that barely moves in the tuning clips (eyeLookUp: 12x
#: unbounded) would turn another face's noise into motion.
MAX_GAIN = 2.0


@dataclass(frozen=True)
class FusionTable:
    """Per shape (ARKit names) the gains of the corrected score (``score``) and of the landmark solve (``solve``);
    ``reference``: how the tuning faces' scores respond to a ROM sheet (a ``ScoreResponse``, or None),
    which a performer's ROM clip is calibrated against (``response.fit_response``)."""

    score: dict
    solve: dict
    measured_on: dict = field(default_factory=dict)
    reference: object = None

    @classmethod
    def load(cls, path=TABLE_FILE):
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            ref = data.get("rom_reference")
            reference = None if ref is None else ScoreResponse(
                tuple(ref["shapes"]), [v[0] for v in ref["shapes"].values()], [v[1] for v in ref["shapes"].values()],
                ref["sheet"])
            return cls({k: float(v[0]) for k, v in data["shapes"].items()},
                       {k: float(v[1]) for k, v in data["shapes"].items()}, data.get("measured_on", {}), reference)
        except (OSError, ValueError, KeyError, IndexError, TypeError, FacecapError) as exc:
            raise FacecapError(f"{path}: not a fusion table ({exc})") from None

    def save(self, path=TABLE_FILE):
        rows = ",\n".join(f'  "{k}": [{self.score[k]:.4f}, {self.solve[k]:.4f}]' for k in self.score)
        head = json.dumps({"format": "facecap-fusion-table", "measured_on": self.measured_on,
                           "columns": ["score gain a", "solve gain b"]})
        text = head[:-1] + ', "shapes": {\n' + rows + "\n}"
        if self.reference is not None:
            r = self.reference
            refs = ",\n".join(f'  "{n}": [{g:.4f}, {o:.4f}]' for n, g, o in zip(r.names, r.gain, r.offset))
            text += (f', "rom_reference": {{"sheet": {json.dumps(r.sheet)}, "columns": ["gain", "offset"], '
                     f'"shapes": {{\n{refs}\n}}}}')
        text += "}"
        tmp = Path(path).with_name(Path(path).name + ".part")
        tmp.write_text(text + "\n", encoding="utf-8")
        tmp.replace(path)


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


def neutral_corrected(scores, neutral):
    """(F, S) scores corrected by their median over the ``neutral`` frame indices: (s - s0) / (1 - s0), >= 0."""
    s = np.asarray(scores, dtype=np.float64)
    idx = np.asarray(neutral, dtype=np.int64)
    if idx.size == 0:
        raise FacecapError("the blendshape scores need the take's neutral frames; none was given or detected")
    s0 = np.nanmedian(s[idx], axis=0)
    s0 = np.where(np.isfinite(s0), np.clip(s0, 0.0, 0.95), 0.0)
    return np.clip((s - s0) / (1.0 - s0), 0.0, None)


def fuse(weights, shape_names, scores, *, table=None, response=None, lower=0.0, upper=1.0):
    """The solve's ``weights`` (F, K) on ``shape_names`` combined per shape with ``scores`` (FaceScores).

    Parameters
    ----------
    table : FusionTable (default: the measured one, ``fusion_table.json``)
    response : callable(corrected (F, S), names) -> (F, S), optional
        The performer's response calibration (per shape gain/offset or monotone curve for this performer and
        camera), applied to the neutral-corrected scores before they are combined: the one place it plugs in
        (default: ``scores.response``).
    lower, upper : scalar or (K,) bounds of the character's shapes

    Returns
    -------
    (weights (F, K), list of the fused shape names)
    """
    table = FusionTable.load() if table is None else table
    w = np.array(weights, dtype=np.float64)
    if len(scores.values) != len(w):
        raise FacecapError(f"the blendshape scores have {len(scores.values)} frames; the solve has {len(w)}")
    corrected = neutral_corrected(scores.values, scores.neutral)
    response = scores.response if response is None else response
    if response is not None:
        corrected = np.asarray(response(corrected, tuple(scores.names)), dtype=np.float64)
    column = {n: j for j, n in enumerate(scores.names)}
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (w.shape[1],))
    hi = np.broadcast_to(np.asarray(upper, dtype=np.float64), (w.shape[1],))
    fused = []
    for k, name in enumerate(shape_names):
        arkit = canonical_names(name)  # the character's name for an ARKit shape, through the alias tables
        if len(arkit) != 1 or arkit[0] not in column or arkit[0] not in table.score:
            continue
        a, b = table.score[arkit[0]], table.solve[arkit[0]]
        c = corrected[:, column[arkit[0]]]
        seen = np.isfinite(c)  # frames without a face keep the solve (a gap stays a gap)
        w[seen, k] = np.clip(a * c[seen] + b * np.nan_to_num(w[seen, k]), lo[k], hi[k])
        fused.append(name)
    return w, fused


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


def _unsided(name):
    for side in ("Left", "Right"):
        if name.endswith(side):
            return name[: -len(side)]
    return name
