"""End-to-end core pipeline on synthetic takes with known weights and head motion."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from synthetic_face import make_basis

from facecap.solvers import FacecapError, RetargetSettings, retarget
from facecap.solvers.synth import synthesize_take
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
