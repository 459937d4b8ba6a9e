"""calibrated and refine: an ACTOR with its own proportions and expressions drives the sample CHARACTER."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import STABLE, actor_take, calibration_weights, make_actor, SAMPLE_BASIS
from facecap.solvers.errors import FacecapError
from facecap.solvers.strategies import STRATEGY_NAMES, make_strategy
from facecap.solvers.strategies.calibrated import CalibratedStrategy, actor_basis_from_poses
from facecap.solvers.strategies.mapping import Mapping
from facecap.solvers.strategies.refine import RefineStrategy
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take
from facecap.solvers.transforms import fit_similarity


@pytest.fixture(scope="module")
def pair():
    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    Wc, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    calib = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, gap_fraction=0.0,
                            max_deg=10.0, seed=5)
    return character, actor, calib, poses, neutral


@pytest.fixture(scope="module")
def noisy_take(pair):
    character, actor, *_ = pair
    return actor_take(actor, performance_weights(character.shape_names, 600, seed=0), gaps=0.05, seed=2)


def test_actor_differs_from_character(pair):
    character, actor, *_ = pair
    sim = fit_similarity(actor.neutral, character.neutral)
    assert np.abs(sim.apply(actor.neutral) - character.neutral).max() > 0.005  # not a similarity away
    ratio = np.linalg.norm(actor.deltas, axis=2).sum(axis=1)[17] / np.linalg.norm(character.deltas, axis=2).sum(axis=1)[17]
    assert abs(ratio - 1) > 0.05  # jawOpen moves the actor's markers differently


def test_noiseless_calibration_recovers_the_actor_basis(pair):
    character, actor, _, poses, neutral = pair
    Wc, _, _ = calibration_weights(actor.shape_names, hold=30)
    clean = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, noise_sigma=0.0,
                            gap_fraction=0.0, max_deg=10.0, seed=5)
    basis, notes = actor_basis_from_poses(clean.markers, poses=poses, neutral=neutral, stable_markers=STABLE, shrink=0.0)
    sim = fit_similarity(actor.neutral, basis.neutral)
    assert sim.scale == pytest.approx(1.0, abs=1e-9)
    assert_allclose(basis.deltas, sim.apply_vectors(actor.deltas), atol=1e-9)
    assert notes == ()
    # the noise shrink reads a noiseless take's own motion as noise of a few micrometres: no visible change
    shrunk, _ = actor_basis_from_poses(clean.markers, poses=poses, neutral=neutral, stable_markers=STABLE)
    assert_allclose(shrunk.deltas, basis.deltas, atol=1e-5)


def test_pose_noise_is_shrunk_where_a_pose_moves_nothing(pair):
    """A pose's median over its hold carries the capture noise into every marker the pose does not move: the
    measured basis shrinks it there and keeps what the pose moves."""
    _, actor, calib, poses, neutral = pair
    shrunk, _ = actor_basis_from_poses(calib.markers, poses=poses, neutral=neutral, stable_markers=STABLE)
    raw, _ = actor_basis_from_poses(calib.markers, poses=poses, neutral=neutral, stable_markers=STABLE, shrink=0.0)
    truth = fit_similarity(actor.neutral, raw.neutral).apply_vectors(actor.deltas)
    size = np.linalg.norm(truth, axis=2)
    still, moving = size < 1e-4, size > 3e-3
    error = lambda b, sel: np.sqrt(np.mean(np.sum((b.deltas - truth) ** 2, axis=2)[sel]))  # noqa: E731
    # measured: the unmoved markers' false motion 0.194 -> 0.009 mm; what the poses move 0.212 -> 0.212 mm
    assert error(shrunk, still) < 0.5 * error(raw, still)
    assert error(shrunk, moving) < 1.05 * error(raw, moving)
    kept = np.linalg.norm(shrunk.deltas, axis=2)[moving] / np.linalg.norm(raw.deltas, axis=2)[moving]
    assert kept.min() > 0.97


def test_calibrated_cross_retarget_accuracy(pair, noisy_take):
    character, actor, calib, poses, neutral = pair
    s = CalibratedStrategy().fit(character, calibration=calib.markers, poses=poses, neutral=neutral,
                                 stable_markers=STABLE)
    r = s.solve(noisy_take.deltas, names=noisy_take.names, neutral=noisy_take.neutral)
    err = r.weights - noisy_take.weights
    rmse = np.sqrt(np.mean(err**2))
    print(f"calibrated cross-retarget: RMSE {rmse:.4f}, max {np.abs(err).max():.3f}")
    assert rmse <= 0.04
    assert r.shape_names == character.shape_names and r.source_names == actor.shape_names
    geometric = make_strategy("geometric").fit(character).solve(
        noisy_take.deltas, names=noisy_take.names, neutral=noisy_take.neutral)
    g_rmse = np.sqrt(np.mean((geometric.weights - noisy_take.weights) ** 2))
    assert g_rmse > 1.5 * rmse  # the character's own shapes do not explain the actor's markers


def test_facs_named_poses_map_through_aliases_and_split(pair):
    character, actor, calib, poses, neutral = pair
    facs = {"AU26": poses["jawOpen"], "AU12": [poses["mouthSmileLeft"], poses["mouthSmileRight"]],
            "mouthSmile": [poses["mouthSmileLeft"], poses["mouthSmileRight"]]}
    s = CalibratedStrategy().fit(character, calibration=calib.markers, poses=facs, neutral=neutral,
                                 stable_markers=STABLE, split=("mouthSmile",))
    assert s.actor_basis.shape_names == ("AU26", "AU12", "mouthSmileLeft", "mouthSmileRight")
    G = s.mapping.matrix
    k = character.shape_names.index
    assert G[k("jawOpen"), 0] == 1 and G[k("mouthSmileLeft"), 1] == 1 and G[k("mouthSmileRight"), 1] == 1
    assert G[k("mouthSmileLeft"), 2] == 1 and G[k("mouthSmileRight"), 3] == 1
    # a split pose moves only its side's markers (midline markers half)
    left = [i for i, n in enumerate(s.actor_basis.marker_names) if n.endswith("_R")]
    assert np.abs(s.actor_basis.deltas[2, left]).max() == 0


def test_many_to_many_mapping_with_gains():
    actor_names = ("jawOpen", "AU12", "smirk")
    target = ("jawOpen", "mouthLowerDownLeft", "mouthSmileLeft", "mouthSmileRight")
    m = Mapping.from_table({"jawOpen": {"jawOpen": 0.9, "mouthLowerDownLeft": 0.3}, "smirk": {"mouthSmileLeft": 0.5}},
                           actor_names, target)
    assert_allclose(m.matrix, [[0.9, 0, 0], [0.3, 0, 0], [0, 1, 0.5], [0, 1, 0]])
    by_target = Mapping.from_table({"mouthSmileLeft": {"AU12": 0.7, "smirk": 1.0}}, actor_names, target,
                                   keyed_by="target", default=None)
    assert_allclose(by_target.apply([[1.0, 1.0, 1.0]]), [[0, 0, 1.7, 0]])
    with pytest.raises(FacecapError, match="unknown character shape 'nose'"):
        Mapping.from_table({"jawOpen": "nose"}, actor_names, target)


def test_calibration_errors_name_the_pose(pair):
    character, actor, calib, poses, neutral = pair
    with pytest.raises(FacecapError, match="pose 'jawOpen' frames .* outside the take"):
        CalibratedStrategy().fit(character, calibration=calib.markers, poses={"jawOpen": [90000, 90010]}, neutral=neutral)
    with pytest.raises(FacecapError, match="pose 'jawOpen' needs"):
        CalibratedStrategy().fit(character, calibration=calib.markers, poses={"jawOpen": 5}, neutral=neutral)
    with pytest.raises(FacecapError, match="call fit"):
        CalibratedStrategy().solve(np.zeros((2, 68, 3)))


def test_refine_never_increases_the_fit_error_and_keeps_the_original(pair):
    character, actor, calib, poses, neutral = pair
    # Markers re-applied on another day: each marker sees a slightly different local deformation.
    rng = np.random.default_rng(7)
    local = np.eye(3) + 0.3 * rng.normal(size=(actor.n_markers, 3, 3))
    shifted = Basis(actor.shape_names, actor.marker_names, actor.neutral,
                    np.einsum("mij,kmj->kmi", local, actor.deltas))
    training = actor_take(shifted, performance_weights(character.shape_names, 400, seed=1), gaps=0.05, seed=3)
    start = CalibratedStrategy().fit(character, calibration=calib.markers, poses=poses, neutral=neutral,
                                     stable_markers=STABLE).actor_basis
    before = start.deltas.copy()
    s = RefineStrategy(max_iterations=4).fit(character, training=training.deltas, names=training.names,
                                             neutral=training.neutral, actor_basis=start)
    history = np.array(s.history)
    print("refine fit error (mm):", np.round(history * 1e3, 4))
    assert np.all(np.diff(history) <= 0)
    assert history[-1] < 0.7 * history[0]
    assert s.version == len(history) - 1 >= 1
    assert_allclose(s.original_basis.deltas, before, atol=0)
    assert s.refined_basis is s.actor_basis and np.abs(s.refined_basis.deltas - before).max() > 1e-4
    assert_allclose(start.deltas, before, atol=0)  # never modified


def test_every_strategy_is_registered():
    assert set(STRATEGY_NAMES) == {"semantic", "geometric", "calibrated", "parallel", "linear", "rbf", "pca", "refine"}
    for name in STRATEGY_NAMES:
        assert make_strategy(name).name == name
    with pytest.raises(FacecapError, match="unknown strategy 'magic'"):
        make_strategy("magic")
