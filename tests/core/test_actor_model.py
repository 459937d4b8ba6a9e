"""What the semantic solve knows of the actor (``strategies.actor_model``): tiers, completion of unmeasured
shapes, unseen shapes, range normalisation, profiles."""

import numpy as np
import pytest

from facecap.solvers.character.basis import Basis
from facecap.solvers.errors import FacecapError
from facecap.solvers.strategies.actor_model import (
    NORMALISE_FULL,
    RANGE_FROM,
    ActorKnowledge,
    build_actor_model,
    fit_ratio,
    normalisation_share,
    profile_of,
    range_gains,
)

SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browInnerUp", "eyeBlinkLeft", "eyeLookInLeft")
MARKERS = tuple(f"m{i}" for i in range(12))


def _basis(rng, scale=0.005):
    deltas = rng.normal(scale=scale, size=(len(SHAPES), len(MARKERS), 3))
    deltas[SHAPES.index("eyeLookInLeft")] *= 0.05  # moves no marker by more than ~0.5 mm: unseen
    return Basis(SHAPES, MARKERS, rng.normal(scale=0.05, size=(len(MARKERS), 3)), deltas)


def test_character_tier_when_nothing_is_known_and_its_shapes_explain_the_take():
    rng = np.random.default_rng(1)
    char = _basis(rng)
    w = np.clip(rng.normal(0.3, 0.3, size=(300, len(SHAPES))), 0, 1)
    deltas = np.einsum("fk,kmd->fmd", w, char.deltas) + rng.normal(scale=3e-4, size=(300, len(MARKERS), 3))
    model = build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(), character_deltas=char.deltas,
                              deltas=deltas, noise=3e-4)
    assert model.tier == "character"
    assert model.fit_ratio < 1.5 and model.mismatch == 0.0  # its shapes explain the markers: used as they are
    np.testing.assert_allclose(model.basis.deltas, char.deltas)
    assert model.unseen == ("eyeLookInLeft",)
    assert "taken as the actor's" in model.statement()
    assert model.report()["sources"]["jawOpen"] == "character"


def test_character_tier_normalises_when_the_character_does_not_explain_the_actor():
    rng = np.random.default_rng(2)
    char, actor = _basis(rng), _basis(rng)  # unrelated shapes: the character explains little
    # ... and moves its markers over other ranges than the actor's (a stylised face: 3-10x less or more)
    spread = np.where(np.arange(len(MARKERS)) % 2 == 0, 5.0, 1.0)
    actor = type(actor)(actor.shape_names, actor.marker_names, actor.neutral, actor.deltas * spread[None, :, None])
    w = np.clip(rng.normal(0.3, 0.3, size=(300, len(SHAPES))), 0, 1)
    deltas = np.einsum("fk,kmd->fmd", w, actor.deltas) + rng.normal(scale=3e-4, size=(300, len(MARKERS), 3))
    model = build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(), character_deltas=char.deltas,
                              deltas=deltas, noise=3e-4)
    assert model.fit_ratio > 3.0 and model.mismatch == 1.0 and model.far >= 0.2
    assert model.gains is not None and np.all((model.gains >= 0.25) & (model.gains <= 4.0))
    assert "follow the character's geometry" in model.statement()
    assert not np.allclose(model.basis.deltas, char.deltas)


def test_a_residual_over_the_actors_own_ranges_is_the_captures_error():
    """A character whose shapes move every marker over the actor's range, though not in its exact pattern (a
    landmark detector's points slide on the face: their residual is far above their filtered noise), is taken
    as it is: normalising its ranges would only distort them (rendered footage onto another person)."""
    rng = np.random.default_rng(2)
    char = _basis(rng)
    slid = char.deltas + rng.normal(scale=0.4, size=char.deltas.shape) * np.abs(char.deltas)  # 40 % off, same range
    w = np.clip(rng.normal(0.3, 0.3, size=(300, len(SHAPES))), 0, 1)
    deltas = np.einsum("fk,kmd->fmd", w, slid) + rng.normal(scale=3e-4, size=(300, len(MARKERS), 3))
    model = build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(), character_deltas=char.deltas,
                              deltas=deltas, noise=3e-4)
    assert model.fit_ratio > NORMALISE_FULL and model.far <= RANGE_FROM and model.mismatch == 0.0
    np.testing.assert_allclose(model.basis.deltas, char.deltas)
    assert "the capture's error" in model.statement()
    assert model.report()["character_ranges_far_off"] == pytest.approx(model.far, abs=1e-3)


def test_normalisation_share_ramps_between_its_limits():
    assert normalisation_share(1.0) == 0.0 and normalisation_share(5.0) == 1.0
    assert 0.0 < normalisation_share(2.0) < 1.0
    assert normalisation_share(float("nan")) == 1.0  # no noise estimate: normalise (the safe side)


def test_fit_ratio_is_about_one_for_a_perfect_model():
    rng = np.random.default_rng(3)
    b = _basis(rng)
    w = rng.uniform(0, 1, size=(400, len(SHAPES)))
    d = np.einsum("fk,kmd->fmd", w, b.deltas) + rng.normal(scale=2e-4, size=(400, len(MARKERS), 3))
    assert 0.7 < fit_ratio(b.deltas, d, 2e-4) < 1.3


def test_range_gains_stay_bounded_and_scale_with_the_actor():
    rng = np.random.default_rng(4)
    prior = rng.normal(scale=0.004, size=(6, 10, 3))
    w = rng.random((500, 6)) * (rng.random((500, 6)) < 0.15)
    small = np.einsum("fk,kmd->fmd", w, prior) * 0.5  # the actor moves half as far
    gains = range_gains(prior, small)
    assert np.median(gains) == pytest.approx(2.0, rel=0.25)
    assert range_gains(prior, small * 1e-3).max() == 4.0  # clipped


def test_calibration_tier_measured_poses_and_completion():
    rng = np.random.default_rng(5)
    char, actor = _basis(rng), _basis(rng)
    all_poses = Basis(SHAPES, MARKERS, actor.neutral, actor.deltas)
    model = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(measured=all_poses),
                              character_deltas=char.deltas)
    assert model.tier == "calibration" and set(model.sources) == {"measured"}
    np.testing.assert_allclose(model.basis.deltas, actor.deltas, atol=1e-12)
    few = Basis(SHAPES[:3], MARKERS, actor.neutral, actor.deltas[:3])
    model = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(measured=few), character_deltas=char.deltas)
    assert model.tier == "poses"
    assert model.sources[:3] == ("measured",) * 3 and set(model.sources[3:]) == {"completed (character)"}
    assert "3 measured pose(s)" in model.statement() and "character's shapes" in model.statement()
    np.testing.assert_allclose(model.basis.deltas[:3], actor.deltas[:3], atol=1e-12)
    # the unposed shapes are the character's, not mapped through the posed ones (without the take's deltas
    # nothing is normalised)
    np.testing.assert_allclose(model.basis.deltas[3:], char.deltas[3:], atol=1e-12)


def test_few_poses_complete_the_others_from_the_characters_normalised_shapes():
    """With the take's deltas, the unposed shapes of a character whose ranges are far off the actor's are its
    shapes normalised to the actor's range, as when nothing is known."""
    rng = np.random.default_rng(6)
    char, actor = _basis(rng), _basis(rng)
    spread = np.where(np.arange(len(MARKERS)) % 2 == 0, 5.0, 1.0)  # the actor moves half its markers 5x more
    deltas_a = actor.deltas * spread[None, :, None]
    w = np.clip(rng.normal(0.3, 0.3, size=(300, len(SHAPES))), 0, 1)
    take = np.einsum("fk,kmd->fmd", w, deltas_a) + rng.normal(scale=3e-4, size=(300, len(MARKERS), 3))
    few = Basis(SHAPES[:3], MARKERS, actor.neutral, deltas_a[:3])
    model = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(measured=few), character_deltas=char.deltas,
                              deltas=take, noise=3e-4)
    nothing = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(), character_deltas=char.deltas,
                                deltas=take, noise=3e-4)
    assert model.tier == "poses" and nothing.tier == "character" and nothing.mismatch == 1.0
    np.testing.assert_allclose(model.basis.deltas[3:], nothing.basis.deltas[3:], atol=1e-12)
    np.testing.assert_allclose(model.basis.deltas[:3], deltas_a[:3], atol=1e-12)


def test_measured_poses_in_another_head_frame_are_rotated_onto_the_take():
    rng = np.random.default_rng(6)
    actor = _basis(rng)
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    turned = Basis(SHAPES, MARKERS, actor.neutral @ R.T + 0.3, actor.deltas @ R.T)
    model = build_actor_model(SHAPES, MARKERS, actor.neutral, ActorKnowledge(measured=turned))
    np.testing.assert_allclose(model.basis.deltas, actor.deltas, atol=1e-9)


def test_profile_of_keeps_only_measured_shapes_and_reads_back(tmp_path):
    rng = np.random.default_rng(7)
    char, actor = _basis(rng), _basis(rng)
    few = Basis(SHAPES[:3], MARKERS, actor.neutral, actor.deltas[:3])
    model = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(measured=few), character_deltas=char.deltas)
    profile = profile_of(model)
    assert profile.shape_names == SHAPES[:3]
    profile.save_npz(tmp_path / "alex.npz")
    again = Basis.load_npz(tmp_path / "alex.npz")
    reused = build_actor_model(char, MARKERS, actor.neutral, ActorKnowledge(profile=again), character_deltas=char.deltas)
    assert reused.sources[:3] == ("profile",) * 3
    np.testing.assert_allclose(reused.basis.deltas[:3], actor.deltas[:3], atol=1e-12)
    nothing = build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(), character_deltas=char.deltas)
    assert profile_of(nothing) is None


def test_unseen_shapes_can_be_solved_on_request():
    rng = np.random.default_rng(8)
    char = _basis(rng)
    model = build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(unseen="solve"), character_deltas=char.deltas)
    assert model.unseen == ()


def test_nothing_to_solve_against_is_an_error():
    rng = np.random.default_rng(9)
    char = _basis(rng)
    unbound = np.full_like(char.deltas, np.nan)
    with pytest.raises(FacecapError, match="no marker of the take is known"):
        build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(), character_deltas=unbound)


def test_poses_sharing_no_marker_with_the_characters_binding_are_one_clear_error():
    """Poses measured on markers the character does not bind, and a binding on markers the poses lack: no
    marker is known to every shape, said in one message (not a numpy error from the range normalisation)."""
    rng = np.random.default_rng(7)
    char = _basis(rng)
    bound = np.full_like(char.deltas, np.nan)
    bound[:, 6:] = char.deltas[:, 6:]  # the character binds m6..m11 only
    few = Basis(SHAPES[:3], MARKERS[:6], char.neutral[:6], char.deltas[:3, :6])  # the poses have m0..m5 only
    take = rng.normal(scale=3e-4, size=(50, len(MARKERS), 3))
    with pytest.raises(FacecapError, match="no marker of the take is known to every shape"):
        build_actor_model(char, MARKERS, char.neutral, ActorKnowledge(measured=few), character_deltas=bound,
                          deltas=take, noise=3e-4)
