"""End-to-end core pipeline on synthetic takes with known weights and head motion."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from synthetic_face import make_basis

from facecap.solvers import FacecapError, RetargetSettings, retarget
from facecap.solvers.tools.synthetic.synth import synthesize_take
from facecap.solvers.transforms import rotation_angle_deg

# No priors and no smoothing: exact data must give exact weights.
EXACT = dict(regularisation=0.0, sparsity=0.0, symmetry=0.0, head_smoothing=0.0, smoothing=(0.0, 0.0))


@pytest.fixture(scope="module")
def setup():
    basis, stable = make_basis()
    rng = np.random.default_rng(3)
    W = np.clip(rng.uniform(-0.5, 1.0, size=(300, basis.n_shapes)), 0, 1)
    W[:60] = 0
    return basis, stable, W


def test_noise_free_recovery_with_head_motion_and_scale(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W, stable=stable, noise_sigma=0.0, gap_fraction=0.0, actor_scale=1.2)
    r = retarget(take.markers, basis, RetargetSettings(stable, (1, 50), **EXACT))
    assert np.abs(r.weights - W).max() <= 1e-6
    assert r.alignment.scale == pytest.approx(1 / 1.2, rel=1e-9)
    true_R = Rotation.from_rotvec(take.head_rotvec_deg, degrees=True).as_matrix()
    assert rotation_angle_deg(r.stabilise.head_rotations() @ true_R.transpose(0, 2, 1)).max() < 1e-4


def test_noise_free_recovery_with_gaps(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W, stable=stable, noise_sigma=0.0, gap_fraction=0.15)
    r = retarget(take.markers, basis, RetargetSettings(stable, (1, 50), **EXACT))
    assert np.isnan(take.markers.positions).any()
    assert np.abs(r.weights - W).max() <= 1e-6


def test_bounds_hold_on_noisy_take(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W, stable=stable, noise_sigma=0.0005)
    r = retarget(take.markers, basis, RetargetSettings(stable, (1, 50)))
    assert np.nanmin(r.weights) >= 0.0 and np.nanmax(r.weights) <= 1.0
    report = r.report()
    assert report["residual_rms_mm"]["mean"] > 0
    assert len(report["residual_rms_mm"]["per_frame"]) == W.shape[0]


def test_unbound_markers_are_named(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W[:80], stable=stable, noise_sigma=0.0, gap_fraction=0.0)
    sub = basis.subset_markers(basis.marker_names[:-2])
    r = retarget(take.markers, sub, RetargetSettings(stable, (1, 50)))
    assert any(basis.marker_names[-1] in w for w in r.warnings)


def test_too_few_bound_markers_is_an_error(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W[:80], stable=stable, noise_sigma=0.0, gap_fraction=0.0)
    renamed = take.markers.with_positions(take.markers.positions, names=tuple(f"x{i}" for i in range(basis.n_markers)))
    with pytest.raises(FacecapError, match="bound on the character"):
        retarget(renamed, basis, RetargetSettings(stable, (1, 50)))


def _frame_rms(frame_marker):
    """RMS over the measured markers of each frame (NaN where none)."""
    seen = np.isfinite(frame_marker)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt((np.where(seen, frame_marker, 0.0) ** 2).sum(axis=1) / seen.sum(axis=1))


def test_frame_marker_residual_is_the_per_marker_split_of_residual_rms(setup):
    basis, stable, W = setup
    take = synthesize_take(basis, W, stable=stable, noise_sigma=0.0005, gap_fraction=0.1)
    r = retarget(take.markers, basis, RetargetSettings(stable, (1, 50)))
    fm = r.frame_marker_residual
    assert fm.shape == (W.shape[0], len(r.marker_names))
    gaps = np.isnan(take.markers.positions[:, take.markers.index(r.marker_names), 0])
    assert gaps.any()
    np.testing.assert_array_equal(np.isnan(fm), gaps | ~np.isfinite(r.residual_rms)[:, None])
    ok = np.isfinite(r.residual_rms)
    np.testing.assert_allclose(_frame_rms(fm)[ok], r.residual_rms[ok], rtol=1e-9, atol=0)
    assert np.nanmin(fm) >= 0.0 and np.nanmax(fm) < 0.01  # metres: 0.5 mm noise, not centimetres


def test_frame_marker_residual_of_a_marker_strategy_and_none_for_parallel():
    from dataclasses import replace

    from facecap.solvers.tools.compare import STABLE, build_scenario
    from facecap.solvers.io.weights import WeightTrack
    from facecap.solvers.strategies.options import CalibrationSettings, StrategyInputs

    sc = build_scenario(frames=240, n_examples=20)
    poses = tuple((k, (tuple(v),)) for k, v in sc.poses.items())
    cal = CalibrationSettings(poses=poses, neutral_frames=tuple(sc.calibration_neutral))
    settings = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 60), calibration=cal)
    r = retarget(sc.test.markers, sc.character, replace(settings, strategy="calibrated"),
                 inputs=StrategyInputs(calibration=sc.calibration))
    fm = r.frame_marker_residual
    assert r.residual_space == "actor" and fm.shape == (240, len(r.marker_names))
    ok = np.isfinite(r.residual_rms)
    assert ok.sum() > 200
    np.testing.assert_allclose(_frame_rms(fm)[ok], r.residual_rms[ok], rtol=1e-9, atol=0)

    track = WeightTrack(frames=np.arange(1.0, 4.0), fps=60.0, names=("jawOpen",), values=np.full((3, 1), 0.5))
    p = retarget(None, ("jawOpen",), replace(settings, strategy="parallel"), inputs=StrategyInputs(weights=track))
    assert p.frame_marker_residual is None
