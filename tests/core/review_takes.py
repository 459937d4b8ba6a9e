"""Solved takes for the review page's tests: a real solve of a synthetic take on the sample character's
basis (its truth known), and a fabricated 10-minute result (realistic sizes and noise, made in a
second instead of the minute a 36,000-frame solve takes)."""

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from facecap.solvers import RetargetSettings, retarget
from facecap.solvers.capture.stabilise import StabiliseResult
from facecap.solvers.character.basis import Basis
from facecap.solvers.markers import MarkerSet
from facecap.solvers.pipeline.result import RetargetResult
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"


def sample_basis():
    return Basis.load_npz(SAMPLES / "character_basis.npz")


def stable_markers():
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    return tuple(m["name"] for m in layout["markers"] if m["stable"])


def sample_solve(frames=720, seed=5):
    """(RetargetResult, truth weights (F, K), settings, basis, SyntheticTake) of a geometric solve."""
    basis = sample_basis()
    truth = performance_weights(basis.shape_names, frames, seed=seed)
    take = synthesize_take(basis, truth, stable=list(stable_markers()), seed=seed + 1)
    settings = RetargetSettings(stable_markers(), (1, 50), strategy="geometric")
    return retarget(take.markers, basis, settings), truth, settings, basis, take


def fabricated_result(frames=36_000, shapes=52, markers=68, seed=0, spike=None, noise=0.01):
    """A RetargetResult with a solve's sizes: performance-like weights plus ``noise``, residuals around
    0.5 mm, a head swaying a few degrees, some flagged frames. ``spike`` = (row, shape, value) sets one
    frame of one shape (the decimation tests look for it). Returns (result, the weights before the noise)."""
    rng = np.random.default_rng(seed)
    names = tuple(f"shape{k:02d}" for k in range(shapes))
    clean = performance_weights(names, frames, seed=seed)
    w = np.clip(clean + rng.normal(0.0, noise, clean.shape), 0.0, 1.0)
    if spike is not None:
        row, k, value = spike
        w[:, k] = np.clip(w[:, k], 0.0, 0.2)
        w[row, k] = value
    f = np.arange(1, frames + 1, dtype=np.float64)
    marker_names = tuple(f"marker{m:02d}" for m in range(markers))
    per = np.abs(rng.normal(0.45e-3, 0.15e-3, (frames, markers)))
    t = np.arange(frames) / 60.0
    rotvec = np.stack([3 * np.sin(t / 3.0), 5 * np.sin(t / 5.0 + 1), 2 * np.sin(t / 7.0)], axis=1)
    R = Rotation.from_rotvec(rotvec, degrees=True).as_matrix().transpose(0, 2, 1)  # raw -> stabilised
    trans = np.stack([0.01 * np.sin(t / 4.0), 0.005 * np.cos(t / 6.0), 0.002 * np.sin(t)], axis=1)
    flagged = np.zeros(frames, dtype=bool)
    flagged[rng.choice(frames, size=frames // 500, replace=False)] = True
    stab = StabiliseResult(
        markers=MarkerSet(("s0", "s1", "s2"), f, np.zeros((frames, 3, 3)), fps=60.0, units="m"),
        stable_names=("s0", "s1", "s2"), reference=np.eye(3) * 0.05, rotations=R, translations=trans,
        rms=np.abs(rng.normal(0.2e-3, 0.05e-3, frames)), flagged=flagged, unreliable=np.zeros(frames, dtype=bool))
    return RetargetResult(
        frames=f, shape_names=names, weights=w, marker_names=marker_names,
        residual_rms=np.sqrt((per ** 2).mean(axis=1)), marker_residual=np.sqrt((per ** 2).mean(axis=0)),
        at_bound=rng.integers(0, 20, frames), stabilise=stab, alignment=None,
        alignment_residual=np.zeros(markers), warnings=("a warning in plain words",),
        timings={"stabilise": 1.0, "solve": 10.0}, frame_marker_residual=per), clean
