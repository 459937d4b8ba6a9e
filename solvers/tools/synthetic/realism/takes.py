"""Takes of an actor performing real curves: Live Link Face recordings (ARKit weights from an iPhone)
drive an ``ActorFace``; the head moves, the capture adds noise and gaps. The truth is the recording.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ....errors import FacecapError
from ....io.weights import read_weights
from ....markers import MarkerSet
from ..synth import head_motion

FPS = 60.0
REST = 60  # neutral frames at the start of every take (the T-pose the solve normalises against)
RAMP = 30  # frames over which the performance fades in after the neutral


@dataclass(frozen=True, eq=False)
class Performance:
    """Real weight curves (F, K) on ``shape_names`` at ``fps``, and where they came from."""

    weights: np.ndarray
    shape_names: tuple
    fps: float
    source: str


def load_performances(folder, shape_names):
    """Every Live Link Face CSV in ``folder``, as curves on ``shape_names`` (missing channels are 0)."""
    paths = sorted(Path(folder).glob("*.csv"))
    if not paths:
        raise FacecapError(f"{folder}: no Live Link Face recordings (*.csv)")
    out = []
    for path in paths:
        track = read_weights(path)
        index = {n: i for i, n in enumerate(track.names)}
        w = np.zeros((track.values.shape[0], len(shape_names)))
        for k, name in enumerate(shape_names):
            if name in index:
                w[:, k] = track.values[:, index[name]]
        w = np.clip(np.nan_to_num(w), 0.0, 1.0)
        out.append(Performance(w, tuple(shape_names), float(track.fps), path.name))
    return out


def performance_segment(performances, n_frames, rng, *, fps=FPS):
    """``n_frames`` at ``fps`` from a random recording and offset, resampled (linear), after a neutral of
    ``REST`` frames and a fade-in of ``RAMP`` frames. Returns (weights (F, K), description)."""
    perf = performances[int(rng.integers(len(performances)))]
    body = n_frames - REST
    length = body * perf.fps / fps
    start = float(rng.uniform(0.0, max(0.0, len(perf.weights) - 1 - length)))
    t = start + np.arange(body) * perf.fps / fps
    src = np.arange(len(perf.weights))
    curves = np.stack([np.interp(t, src, perf.weights[:, k]) for k in range(perf.weights.shape[1])], axis=1)
    fade = np.clip(np.arange(body) / RAMP, 0.0, 1.0)
    curves *= (fade * fade * (3 - 2 * fade))[:, None]
    weights = np.concatenate([np.zeros((REST, curves.shape[1])), curves])
    return weights, f"{perf.source} from {start / perf.fps:.1f} s"


@dataclass(frozen=True)
class CaptureSettings:
    """What the capture does to the face: head motion (degrees, metres), noise (metres RMS per
    coordinate), gaps (fraction of the moving markers' samples, runs of 2..``max_gap`` frames)."""

    max_deg: float = 15.0
    max_offset: float = 0.03
    noise: float = 0.0003
    gaps: float = 0.04
    max_gap: int = 30


def capture(actor, weights, rng, *, settings=CaptureSettings(), stable=(), fps=FPS, source="realistic take"):
    """The markers (MarkerSet, millimetres, capture axes: Y up) of ``actor`` performing ``weights``."""
    F = len(weights)
    face = actor.positions(weights)
    rotvec, offset = head_motion(F, fps=fps, rest=REST, max_deg=settings.max_deg, max_offset=settings.max_offset,
                                 seed=int(rng.integers(1 << 31)))
    pivot = np.array([0.0, 0.02, -0.1])  # near the top of the neck
    R = Rotation.from_rotvec(rotvec).as_matrix()
    moved = np.einsum("fij,fmj->fmi", R, face - pivot) + pivot + offset[:, None]
    # The model is Blender's way up (Z up, facing -Y); the capture volume is Y up, the actor facing a random
    # heading about its vertical (a turn about Z here would roll the actor onto the side or upside down).
    to_capture = Rotation.from_euler("xy", [-90.0, rng.uniform(-180.0, 180.0)], degrees=True).as_matrix()
    positions = (moved @ to_capture.T + [rng.uniform(-0.5, 0.5), 1.6, rng.uniform(-0.5, 0.5)]) * 1e3
    positions += rng.normal(scale=settings.noise * 1e3, size=positions.shape)
    still = set(stable)
    for m, name in enumerate(actor.names):
        share = settings.gaps * (0.2 if name in still else 1.0)
        target = int(round(share * rng.uniform(0.5, 1.5) * (F - REST)))
        while np.isnan(positions[REST:, m, 0]).sum() < target:
            length = int(rng.integers(2, settings.max_gap + 1))
            start = int(rng.integers(REST, max(REST + 1, F - length)))
            positions[start : start + length, m] = np.nan
    return MarkerSet(actor.names, np.arange(1, F + 1, dtype=np.float64), positions, fps=fps, units="mm",
                     source=source)


def calibration_weights(shape_names, poses, rng, *, ramp=12, hold=24, crosstalk=0.06):
    """A calibration session: ``REST`` neutral frames, then each pose in ``poses`` (shape names) ramped up,
    held and released. An actor never holds exactly one shape: up to ``crosstalk`` of two others fire.
    Returns (weights (F, K), {pose: [first, last]} of the holds, 1-based frames)."""
    index = {n: i for i, n in enumerate(shape_names)}
    rows, ranges, t = [np.zeros((REST, len(shape_names)))], {}, REST
    for pose in poses:
        target = np.zeros(len(shape_names))
        target[index[pose]] = 1.0
        others = rng.choice([i for i in range(len(shape_names)) if i != index[pose]], size=2, replace=False)
        target[others] = rng.uniform(0.0, crosstalk, size=2)
        s = np.linspace(0.0, 1.0, ramp)
        s = s * s * (3 - 2 * s)
        block = np.concatenate([s[:, None] * target, np.repeat(target[None], hold, axis=0),
                                s[::-1, None] * target, np.zeros((ramp, len(shape_names)))])
        ranges[pose] = [t + ramp + 3 + 1, t + ramp + hold - 3]  # the hold, 3 frames in from each end
        rows.append(block)
        t += len(block)
    return np.concatenate(rows), ranges
