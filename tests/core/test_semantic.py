"""The semantic strategy (the default): right where the character's shapes describe the actor, exclusive opposing
shapes, unseen shapes at rest, a calibrated actor solved onto a different character, and the plausibility
check that follows every solve."""

from dataclasses import replace

import numpy as np
import pytest

from facecap.solvers.character.basis import Basis
from facecap.solvers.pipeline import RetargetSettings, retarget
from facecap.solvers.pipeline.plausibility import check, marker_noise
from facecap.solvers.strategies.options import ActorSettings, CalibrationSettings, StrategyInputs
from facecap.solvers.engine import solve_bounded
from facecap.solvers.strategies.semantic import CONJUGATE_WEIGHT, exclusive_locks, opposing_pairs, with_conjugate_gaze
from facecap.solvers.tools.compare import SAMPLE_BASIS, STABLE, calibration_weights, make_actor
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

N = 480


@pytest.fixture(scope="module")
def sample():
    return Basis.load_npz(SAMPLE_BASIS)


def rmse(result, truth):
    ok = np.isfinite(result.weights).all(axis=1)
    return float(np.sqrt(np.mean((result.weights[ok] - truth[ok]) ** 2)))


@pytest.mark.parametrize("seed", [0, 1])
def test_default_is_semantic_and_as_good_as_geometric_on_a_self_retarget(sample, seed):
    W = performance_weights(sample.shape_names, N, seed=seed)
    take = synthesize_take(sample, W, stable=STABLE, seed=10 + seed)
    settings = RetargetSettings(STABLE, (1, 50))
    assert settings.strategy == "semantic"
    semantic = retarget(take.markers, sample, settings)
    geometric = retarget(take.markers, sample, replace(settings, strategy="geometric"))
    # measured: 0.018-0.020 semantic, 0.019-0.021 geometric
    assert rmse(semantic, W) <= 1.05 * rmse(geometric, W) and rmse(semantic, W) < 0.025
    actor = semantic.report()["actor"]
    assert actor["tier"] == "character" and actor["character_mismatch"] == 0.0
    assert set(actor["unseen"]) >= {"eyeLookInLeft", "tongueOut"}  # gaze rotates the eyeballs: no skin marker sees it
    assert np.all(semantic.weights[:, semantic.shape_names.index("tongueOut")] == 0.0)
    assert semantic.report()["plausibility"]["plausible"]


def test_freed_unseen_shapes_are_solved(sample):
    W = performance_weights(sample.shape_names, N, seed=3)
    take = synthesize_take(sample, W, stable=STABLE, seed=13)
    settings = RetargetSettings(STABLE, (1, 50), actor=ActorSettings(unseen_shapes="solve"))
    res = retarget(take.markers, sample, settings)
    assert res.report()["actor"]["unseen"] == []
    assert not any("held at rest" in w for w in res.warnings)


def test_opposing_shapes_are_exclusive():
    names = ("jawLeft", "jawRight", "jawOpen", "eyeBlinkLeft", "eyeWideLeft")
    assert opposing_pairs(names) == [(0, 1), (3, 4)]
    W = np.array([[0.4, 0.35, 0.2, 0.0, 0.1]] * 20 + [[0.1, 0.5, 0.2, 0.6, 0.0]] * 20)
    locks = exclusive_locks(W, opposing_pairs(names), np.full(W.shape, np.nan))
    assert np.all(locks[:10, 1] == 0) and np.all(np.isnan(locks[:10, 0]))  # jawLeft wins the first frames
    assert np.all(locks[-10:, 0] == 0) and np.all(np.isnan(locks[-10:, 1]))  # jawRight the last
    assert np.all(locks[:10, 3] == 0) and np.all(locks[-10:, 4] == 0)  # wide leads the first frames, blink the last
    assert np.isnan(locks[:, 2]).all()


def test_the_eyes_turn_together():
    """Gaze driven by markers (lid markers that the template's or the measured gaze shapes move): where one eye's
    markers are lost, its gaze follows the other eye's (look in with the other's look out, up with up) instead of
    falling to rest; where both are seen the coupling costs the fit nothing."""
    names = ("eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
             "jawOpen")
    R = with_conjugate_gaze(1e-3, names)
    assert R.shape == (7, 7) and np.allclose(R, R.T) and np.linalg.eigvalsh(R).min() > 0
    assert R[0, 4] == -CONJUGATE_WEIGHT and R[2, 5] == -CONJUGATE_WEIGHT and R[0, 3] == 0 and R[6, 6] == 1e-3
    assert with_conjugate_gaze(1e-3, ("jawOpen", "eyeBlinkLeft")) == 1e-3  # no gaze pair: unchanged
    rng = np.random.default_rng(0)
    A = np.zeros((18, 7))  # each shape moves its own three coordinates (left eye 0-8, right eye 9-17, jaw none)
    for k, rows in enumerate([(0, 1, 2), (3, 4, 5), (6, 7, 8), (9, 10, 11), (12, 13, 14), (15, 16, 17)]):
        A[list(rows), k] = 1.0
    t = np.linspace(0, 1, 120)
    W = np.zeros((120, 7))
    W[:, 0] = W[:, 4] = np.clip(np.sin(6 * t), 0, None)  # both eyes to the subject's right, together
    W[:, 2] = W[:, 5] = 0.5 * t
    D = W @ A.T + rng.normal(scale=0.01, size=(120, 18))
    mask = np.ones_like(D)
    mask[60:, 9:] = 0.0  # the right eye's markers lost for the second half
    free = solve_bounded(A, D, mask=mask, regularisation=1e-3, relative=True)
    tied = solve_bounded(A, D, mask=mask, regularisation=with_conjugate_gaze(1e-3, names), relative=True)
    assert np.abs(free.weights[60:, 4]).max() < 0.05  # uncoupled, the lost eye rests
    np.testing.assert_allclose(tied.weights[60:, [4, 5]], W[60:, [4, 5]], atol=0.06)  # coupled, it follows
    np.testing.assert_allclose(tied.weights[:60], W[:60], atol=0.03)
    np.testing.assert_allclose(free.weights[:60], W[:60], atol=0.03)


def test_calibrated_actor_on_a_different_character(sample):
    """An actor whose proportions and expressions are not the character's: with a calibration pose per shape the
    semantic solve recovers the weights; with nothing known it is safe (nothing pinned) and says so."""
    actor = make_actor(sample, seed=4)
    W = performance_weights(sample.shape_names, N, seed=4)
    take = synthesize_take(actor, W, stable=STABLE, seed=14)
    calib_w, poses, neutral = calibration_weights(sample.shape_names)
    calib = synthesize_take(actor, calib_w, stable=STABLE, seed=15, rest=30)
    table = tuple((name, (tuple(r),)) for name, r in poses.items())
    settings = RetargetSettings(STABLE, (1, 50), calibration=CalibrationSettings(poses=table, neutral_frames=tuple(neutral)))
    inputs = StrategyInputs(calibration=calib.markers)
    calibrated = retarget(take.markers, sample, settings, inputs=inputs)
    old = retarget(take.markers, sample, replace(settings, strategy="calibrated"), inputs=inputs)
    nothing = retarget(take.markers, sample, RetargetSettings(STABLE, (1, 50)))
    geometric = retarget(take.markers, sample, RetargetSettings(STABLE, (1, 50), strategy="geometric"))
    assert calibrated.report()["actor"]["tier"] == "calibration"
    # measured: 0.037 semantic calibrated, 0.036 the calibrated strategy (both 0.045-0.047 before the poses' noise
    # was shrunk), 0.052 nothing known, 0.060 geometric
    assert rmse(calibrated, W) < 0.042 and rmse(calibrated, W) <= 1.05 * rmse(old, W)
    assert rmse(calibrated, W) < rmse(nothing, W) <= rmse(geometric, W)
    assert nothing.report()["plausibility"]["at_upper"] <= 0.01


def test_noise_estimate_and_plausibility_warnings():
    rng = np.random.default_rng(0)
    t = np.arange(2000) / 60.0
    motion = 0.004 * np.sin(2 * np.pi * 0.7 * t)[:, None, None] * rng.normal(size=(1, 20, 3))
    noisy = motion + rng.normal(scale=3e-4, size=motion.shape)
    assert marker_noise(noisy) == pytest.approx(3e-4, rel=0.1)
    names = ("jawLeft", "jawRight", "jawOpen")
    upper = np.ones(3)
    good = np.column_stack([np.zeros(2000), rng.uniform(0, 0.3, 2000), rng.uniform(0, 0.8, 2000)])
    report, warning = check(good, names, upper, np.full(2000, 4e-4), 3e-4)
    assert warning is None and report["plausible"]
    bad = good.copy()
    bad[:, 0] = 0.4
    bad[:, 1] = 0.35
    bad[:500, 2] = 1.0
    report, warning = check(bad, names, upper, np.full(2000, 2e-3), 3e-4)
    assert not report["plausible"] and warning.count("\n") == 0
    assert "3.8x their noise" in warning and "jawOpen 25%" in warning and "jawLeft and jawRight" in warning
    assert "[solve] locks" in warning
    _, held = check(bad, names, upper, np.full(2000, 4e-4), 3e-4, held=("jawOpen", "jawLeft"))
    assert held is None  # held shapes are the user's, not the solve's


def test_poses_labelled_in_the_take_are_measured_without_its_noise():
    """Frames of the take labelled as poses: each pose is the median of its frames, the capture noise on the
    markers it does not move shrunk away, what it moves kept."""
    from facecap.solvers.strategies.base import PreparedTake
    from facecap.solvers.strategies.semantic_wiring import poses_in_take

    rng = np.random.default_rng(5)
    F, M = 400, 30
    deltas = rng.normal(scale=3e-4, size=(F, M, 3))  # 0.3 mm noise everywhere
    moved = np.zeros((M, 3))
    moved[:6, 1] = 4e-3  # the pose lifts six markers by 4 mm
    deltas[200:230] += moved
    deltas[210, 3] = np.nan  # a gap inside the pose
    take = PreparedTake(deltas, np.zeros((M, 3)), tuple(f"m{i}" for i in range(M)), np.arange(1.0, F + 1), None)
    basis = poses_in_take(take, {"jawOpen": [(201, 230)]}, (1, 100))
    got = basis.deltas[0]
    assert np.abs(got[6:]).max() < 1e-5  # ~0.09 mm of false motion per coordinate before (the hold's median)
    np.testing.assert_allclose(got[:6], moved[:6], atol=3e-4)
    assert basis.shape_names == ("jawOpen",)
