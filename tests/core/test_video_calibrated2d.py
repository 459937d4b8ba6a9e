"""`calibrated` natively in 2D: actor poses filmed in a calibration take (frame ranges), a basis in pixels."""

import json
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers import Basis, FacecapError, MarkerSet, RetargetSettings
from facecap.solvers.pipeline import retarget
from facecap.solvers.strategies.options import CalibrationSettings, StrategyInputs
from facecap.solvers.tools.synthetic.synth import performance_weights

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"
HOLD, GAP, NEUTRAL = 8, 3, 20  # calibration: frames each pose is held, relaxed frames between, neutral frames


def filmed(face_basis, weights, *, px_per_m, noise_px=0.3, seed=0):
    """Image tracks of the actor's face (front view) with in-plane head motion, zoom and noise."""
    rng = np.random.default_rng(seed)
    F = len(weights)
    face = face_basis.neutral[None] + np.einsum("fk,kmd->fmd", weights, face_basis.deltas)
    t = np.arange(F) / 60
    ramp = np.clip((t - 1) / 0.8, 0, 1)
    roll = np.radians(6) * np.sin(0.7 * t) * ramp
    scale = px_per_m * (1 + 0.04 * np.sin(0.3 * t) * ramp)
    c, s = np.cos(roll), np.sin(roll)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    shift = np.stack([640 + 30 * np.sin(0.5 * t), 360 + 20 * np.cos(0.4 * t)], 1) * ramp[:, None] + \
        np.array([640.0, 360.0]) * (1 - ramp[:, None])
    px = scale[:, None, None] * (face @ R.transpose(0, 2, 1)) + shift[:, None]
    px += rng.normal(0, noise_px, px.shape)
    return MarkerSet(face_basis.marker_names, np.arange(1, F + 1), px, fps=60, units="px", source="filmed")


def calibration_session(shape_names):
    """Weights of a calibration take: a relaxed neutral, then every pose held HOLD frames."""
    K = len(shape_names)
    W = np.zeros((NEUTRAL + K * (HOLD + GAP), K))
    poses = []
    for k, name in enumerate(shape_names):
        first = NEUTRAL + k * (HOLD + GAP) + GAP
        W[first: first + HOLD, k] = 1.0
        poses.append((name, ((first + 2, first + HOLD),)))  # frame numbers are 1-based: skip the onset
    return W, tuple(poses)


@pytest.fixture(scope="module")
def sample():
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = tuple(m["name"] for m in layout["markers"] if m["stable"])
    return basis, stable


def test_calibrated_2d_from_a_filmed_calibration(sample):
    basis, stable = sample
    actor = basis.front_view()
    W_cal, poses = calibration_session(basis.shape_names)
    calibration = filmed(actor, W_cal, px_per_m=2200, seed=1)  # filmed closer/further than the take
    W = performance_weights(basis.shape_names, 600, seed=4)
    take = filmed(actor, W, px_per_m=2500, seed=2)
    settings = RetargetSettings(stable, (1, 50), strategy="calibrated",
                                calibration=CalibrationSettings(poses=poses, neutral_frames=(1, NEUTRAL),
                                                                align="similarity"))
    r = retarget(take, basis.shape_names, settings, inputs=StrategyInputs(calibration=calibration))  # dispatches 2D
    rmse = float(np.sqrt(np.mean((r.weights - W) ** 2)))
    print(f"calibrated 2D: weights RMSE {rmse:.4f}, median residual {np.nanmedian(r.residual_rms):.2f} px")
    assert rmse <= 0.06
    assert r.fitted.actor_basis.neutral.shape == (basis.n_markers, 2)  # the actor basis is 2D (pixels)
    assert np.nanmedian(r.residual_rms) < 1.0  # px: noise is 0.3 px
    # Without the zoom correction ("rigid" keeps the calibration's scale) the weights come out ~2500/2200 too big.
    rigid = retarget(take, basis.shape_names, settings.__class__(
        stable, (1, 50), strategy="calibrated",
        calibration=CalibrationSettings(poses=poses, neutral_frames=(1, NEUTRAL), align="rigid")),
        inputs=StrategyInputs(calibration=calibration))
    assert float(np.sqrt(np.mean((rigid.weights - W) ** 2))) > rmse


def test_2d_takes_need_2d_calibrations_and_fitted_strategies(sample):
    basis, stable = sample
    W = performance_weights(basis.shape_names, 80, seed=4)
    take = filmed(basis.front_view(), W, px_per_m=2500)
    three_d = MarkerSet(basis.marker_names, np.arange(1, 81), np.zeros((80, basis.n_markers, 3)), units="m")
    cal = CalibrationSettings(poses=(("jawOpen", ((5, 9),)),), neutral_frames=(1, 4))
    with pytest.raises(FacecapError, match=r"\[calibration\] markers: a 2D take needs 2D tracks"):
        retarget(take, basis.shape_names, RetargetSettings(stable, (1, 50), strategy="calibrated", calibration=cal),
                 inputs=StrategyInputs(calibration=three_d))
    with pytest.raises(FacecapError, match="does not solve 2D image tracks"):
        retarget(take, basis.shape_names, RetargetSettings(stable, (1, 50), strategy="refine", calibration=cal),
                 inputs=StrategyInputs(calibration=take))


def test_linear_from_2d_tracks_and_posed_frames(sample):
    from facecap.solvers.strategies.options import ExamplePairs

    basis, stable = sample
    W = performance_weights(basis.shape_names, 600, seed=5)
    take = filmed(basis.front_view(), W, px_per_m=2500, seed=3)
    posed = np.arange(1, 601, 5)  # an animator posed every 5th frame
    inputs = StrategyInputs(examples=ExamplePairs(posed.astype(float), W[posed - 1], basis.shape_names))
    r = retarget(take, basis.shape_names, RetargetSettings(stable, (1, 50), strategy="linear"), inputs=inputs)
    rest = np.setdiff1d(np.arange(600), posed - 1)
    rmse = float(np.sqrt(np.mean((r.weights[rest] - W[rest]) ** 2)))
    print(f"linear from 2D tracks: weights RMSE {rmse:.4f} on unposed frames")
    assert rmse <= 0.06


def test_take_config_accepts_a_filmed_calibration_in_pixels(tmp_path):
    from facecap.solvers import ConfigError, load_take_config

    text = """
[target]
object = "Face"
[source]
markers = "tracks.csv"
units = "px"
[stabilise]
markers = ["a", "b", "c"]
[neutral]
frames = [1, 30]
[solve]
strategy = "calibrated"
[calibration]
markers = "calibration_tracks.csv"
units = "px"
align = "similarity"
poses = { jawOpen = [40, 48] }
"""
    path = tmp_path / "take.toml"
    path.write_text(text)
    cfg = load_take_config(path)
    assert cfg.calibration_units == "px" and cfg.settings.calibration.align == "similarity"
    path.write_text(text.replace('units = "px"\nalign', 'units = "pixels"\nalign'))
    with pytest.raises(ConfigError, match=r"\[calibration.units\] expected one of m, cm, mm, px; got 'pixels'"):
        load_take_config(path)
