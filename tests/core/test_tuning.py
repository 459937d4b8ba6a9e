"""Animator feedback loop (issue 7): re-tune the actor library from a few corrected frames.

Scenario: an actor (``make_actor`` from the sample character) performs a 600-frame take (0.3 mm
noise, 5% gaps) in actor space; the calibration library has 4 poses performed at 40% strength.
The animator corrects the 8 worst-looking frames (largest weight error, >= 20 frames apart) to the
ground truth.
"""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import SAMPLE_BASIS, make_actor
from facecap.solvers.errors import FacecapError
from facecap.solvers.tools.synthetic.synth import performance_weights
from facecap.solvers.tuning.retune import (apply_gain_offset, closed_form_update, default_solver, fit_gain_offset,
                                    retune, spread_frames)

WEAK = ("jawOpen", "mouthSmileLeft", "browInnerUp", "eyeBlinkLeft")


def _rmse(a):
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))


def _scenario(seed=0, frames=600, strength=0.4, noise=0.0003, gaps=0.05):
    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=seed)
    W = performance_weights(character.shape_names, frames, seed=seed)
    rng = np.random.default_rng(seed + 10)
    D = np.einsum("fk,kmd->fmd", W, actor.deltas) + noise * rng.normal(size=(frames, actor.n_markers, 3))
    D[rng.random((frames, actor.n_markers)) < gaps] = np.nan
    lib = actor.deltas.copy()
    for name in WEAK:
        lib[actor.shape_names.index(name)] *= strength
    return actor, Basis(actor.shape_names, actor.marker_names, actor.neutral, lib), D, W


def _worst_frames(W, Ws, n=8, sep=20):
    return spread_frames(np.abs(Ws - W).max(axis=1), n, min_gap=sep)


@pytest.fixture(scope="module")
def weak():
    actor, lib, D, W = _scenario()
    Ws = default_solver(lib, D)
    frames = _worst_frames(W, Ws)
    other = np.setdiff1d(np.arange(len(W)), frames)
    return actor, lib, D, W, Ws, frames, other


@pytest.fixture(scope="module")
def tuned(weak):
    actor, lib, D, W, Ws, frames, other = weak
    before = lib.deltas.copy()
    inputs = (D.copy(), Ws.copy())
    result = retune(lib, D, Ws, {t: W[t].copy() for t in frames})
    return result, before, inputs


def test_weak_calibration_poses_are_retuned(weak, tuned):
    actor, lib, D, W, Ws, frames, other = weak
    r, _, _ = tuned
    c0, h0 = _rmse(Ws[frames] - W[frames]), _rmse(Ws[other] - W[other])
    c1, h1 = _rmse(r.weights[frames] - W[frames]), _rmse(r.weights[other] - W[other])
    gains = {n: round(float(r.gains[actor.shape_names.index(n)]), 3) for n in WEAK}
    print(f"\n40% strength: corrected {c0:.4f} -> {c1:.4f}, held-out {h0:.4f} -> {h1:.4f} "
          f"({(h1 - h0) / h0:+.1%}); model {r.model}, gains {gains}, {len(r.changed)} poses changed, "
          f"other frames moved {r.moved_relative:.1%}; LOO {r.cv}")
    assert c1 <= 0.05
    assert h1 <= 0.85 * h0
    assert r.corrected_rmse_before == pytest.approx(c0) and r.corrected_rmse_after == pytest.approx(c1)
    for name in WEAK:  # 1 / 0.4 = 2.5
        assert name in r.implicated and name in r.changed
        assert 2.1 <= gains[name] <= 2.9
    assert set(r.changed) <= set(r.implicated)
    assert r.version.startswith("v0+tune8f-") and r.version != "v0"
    assert r.moved_rms > 0 and r.pose_changes["jawOpen"]["relative"] > 1.0


def test_plain_closed_form_fits_but_does_not_generalise(weak, tuned):
    actor, lib, D, W, Ws, frames, other = weak
    r, _, _ = tuned
    h0 = _rmse(Ws[other] - W[other])
    h_tuned = _rmse(r.weights[other] - W[other])
    rows = []
    for mu in (0.1, 1.0, 10.0):
        Wc = default_solver(closed_form_update(lib, D, Ws, {t: W[t] for t in frames}, mu=mu), D)
        rows.append((mu, _rmse(Wc[frames] - W[frames]), _rmse(Wc[other] - W[other])))
    print("\nclosed form (mu, corrected, held-out): " + ", ".join(f"({m:g}, {c:.4f}, {h:.4f})" for m, c, h in rows)
          + f"; before held-out {h0:.4f}; retune held-out {h_tuned:.4f}")
    assert rows[0][2] > h0  # the closest fit of the corrected frames makes the other frames worse
    assert all(c > 0.05 for _, c, _ in rows)  # and no mu reaches the corrected-frame target after re-solving
    assert all(h_tuned < 0.5 * h for _, _, h in rows)


def test_random_corrected_frames_also_work():
    actor, lib, D, W = _scenario(seed=1)
    Ws = default_solver(lib, D)
    active = np.flatnonzero(W.max(axis=1) > 0.1)
    frames = sorted(np.random.default_rng(1).choice(active, 8, replace=False).tolist())
    other = np.setdiff1d(np.arange(len(W)), frames)
    r = retune(lib, D, Ws, {t: W[t] for t in frames})
    c1, h0, h1 = r.corrected_rmse_after, _rmse(Ws[other] - W[other]), _rmse(r.weights[other] - W[other])
    print(f"\nrandom frames, seed 1: corrected {r.corrected_rmse_before:.4f} -> {c1:.4f}, held-out {h0:.4f} -> {h1:.4f}")
    assert c1 <= 0.05 and h1 <= 0.85 * h0


def test_no_harm_when_corrections_agree_with_the_library():
    actor, _, D, W = _scenario()
    Ws = default_solver(actor, D)  # the library is right
    frames = _worst_frames(W, Ws)
    other = np.setdiff1d(np.arange(len(W)), frames)
    r = retune(actor, D, Ws, {t: W[t] for t in frames})  # corrections = truth
    h0, h1 = _rmse(Ws[other] - W[other]), _rmse(r.weights[other] - W[other])
    print(f"\nno harm (truth on a right library): held-out {h0:.4f} -> {h1:.4f}, moved {r.moved_relative:.2%}, "
          f"model {r.model}, LOO {r.cv}")
    assert r.moved_relative < 0.02 and abs(h1 - h0) < 0.02 * h0
    forced = retune(actor, D, Ws, {t: W[t] for t in frames}, force=True)  # skip the leave-one-out gate
    h2 = _rmse(forced.weights[other] - W[other])
    print(f"no harm, forced refit: model {forced.model}, held-out {h0:.4f} -> {h2:.4f}, moved {forced.moved_relative:.2%}, "
          f"gains {dict((n, round(float(g), 3)) for n, g in zip(actor.shape_names, forced.gains) if g != 1)}")
    assert forced.model == "gain" and forced.moved_relative < 0.02 and abs(h2 - h0) < 0.02 * h0
    same = retune(actor, D, Ws, {t: Ws[t] for t in frames})  # corrections = current solve
    print(f"no harm (corrections = solve): moved {same.moved_relative:.2%}, model {same.model}")
    assert same.moved_relative < 0.02 and same.model == "unchanged" and same.version == "v0"
    assert same.implicated == () and same.changed == ()
    assert_array_equal(same.library.deltas, actor.deltas)


def test_original_library_and_inputs_unchanged(weak, tuned):
    actor, lib, D, W, Ws, frames, other = weak
    r, before, (D0, Ws0) = tuned
    assert_array_equal(lib.deltas, before)
    assert_array_equal(D, D0)
    assert_array_equal(Ws, Ws0)
    assert r.library is not lib and r.library.deltas is not lib.deltas
    assert not np.shares_memory(r.library.deltas, lib.deltas)


def test_retune_is_deterministic(weak, tuned):
    actor, lib, D, W, Ws, frames, other = weak
    r, _, _ = tuned
    again = retune(lib, D, Ws, {t: W[t].copy() for t in reversed(frames)})
    assert_array_equal(again.library.deltas, r.library.deltas)
    assert_array_equal(again.weights, r.weights)
    assert again.version == r.version and again.cv == r.cv


def test_fixed_mu_and_partial_corrections(weak):
    actor, lib, D, W, Ws, frames, other = weak
    gains_only = retune(lib, D, Ws, {t: W[t] for t in frames}, mu=np.inf)
    assert gains_only.model == "gain" and not np.isfinite(gains_only.mu)
    markers = retune(lib, D, Ws, {t: W[t] for t in frames}, mu=3.0)
    assert markers.model == "gain+markers" and markers.mu == 3.0
    # the animator only touched jawOpen on the corrected frames: only jawOpen may change
    k = actor.shape_names.index("jawOpen")
    partial = {}
    for t in frames:
        row = np.full(actor.n_shapes, np.nan)
        row[k] = W[t, k]
        partial[t] = row
    r = retune(lib, D, Ws, partial)
    print(f"\njawOpen only: implicated {r.implicated}, gain {r.gains[k]:.3f}, "
          f"corrected {r.corrected_rmse_before:.4f} -> {r.corrected_rmse_after:.4f}")
    assert r.implicated == ("jawOpen",) and r.changed == ("jawOpen",)
    assert 2.0 <= r.gains[k] <= 3.0 and r.corrected_rmse_after < 0.5 * r.corrected_rmse_before


def test_bad_inputs(weak):
    actor, lib, D, W, Ws, frames, other = weak
    with pytest.raises(FacecapError, match="no corrected frames"):
        retune(lib, D, Ws, {})
    with pytest.raises(FacecapError, match="corrected frame indices"):
        retune(lib, D, Ws, {len(W): W[0]})
    with pytest.raises(FacecapError, match="must have 52 weights"):
        retune(lib, D, Ws, {0: W[0, :5]})
    with pytest.raises(FacecapError, match="mu must be > 0"):
        retune(lib, D, Ws, {0: W[0]}, mu=0.0)
    with pytest.raises(FacecapError, match="deltas must have shape"):
        retune(lib, D[:, :5], Ws, {0: W[0]})


def test_closed_form_with_a_strong_prior_keeps_the_library(weak):
    actor, lib, D, W, Ws, frames, other = weak
    new = closed_form_update(lib, D, Ws, {t: W[t] for t in frames}, mu=1e9)
    assert np.abs(new.deltas - lib.deltas).max() < 1e-9


def test_fit_gain_offset_recovers_a_linear_correction():
    rng = np.random.default_rng(3)
    solved = rng.uniform(0, 1, size=(100, 4))
    corrections = {}
    for t in (5, 17, 40, 66, 90):
        row = np.full(4, np.nan)
        row[0] = 0.7 * solved[t, 0] + 0.1
        row[1] = solved[t, 1] - 0.05
        corrections[t] = row
    corrections[90][2] = solved[90, 2] + 0.2  # one frame: offset only
    gain, offset = fit_gain_offset(solved, corrections)
    print(f"\nfit_gain_offset: gain {np.round(gain, 6)}, offset {np.round(offset, 6)}")
    np.testing.assert_allclose(gain, [0.7, 1.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(offset, [0.1, -0.05, 0.2, 0.0], atol=1e-12)
    out = apply_gain_offset(solved, gain, offset, lower=0.0, upper=1.0)
    np.testing.assert_allclose(out[:, 0], 0.7 * solved[:, 0] + 0.1)


def test_fit_gain_offset_on_the_weak_scenario(weak):
    actor, lib, D, W, Ws, frames, other = weak
    gain, offset = fit_gain_offset(Ws, {t: W[t] for t in frames})
    out = apply_gain_offset(Ws, gain, offset, lower=lib.lower, upper=lib.upper)
    c0, c1 = _rmse(Ws[frames] - W[frames]), _rmse(out[frames] - W[frames])
    h0, h1 = _rmse(Ws[other] - W[other]), _rmse(out[other] - W[other])
    print(f"\ngain/offset one-click: corrected {c0:.4f} -> {c1:.4f}, held-out {h0:.4f} -> {h1:.4f}")
    assert c1 < 0.5 * c0


def test_through_the_calibrated_strategy():
    """The 40% poses come from a synthetic calibration session (holds at 0.4) through
    ``actor_basis_from_poses``; the take is solved by ``CalibratedStrategy`` (head motion, rigid
    alignment onto the calibration neutral); the tuned library goes back in as ``actor_basis``."""
    from facecap.solvers.tools.compare import STABLE, actor_take, calibration_weights
    from facecap.solvers.strategies.sources import align_to, reorder
    from facecap.solvers.strategies.calibrated import CalibratedStrategy
    from facecap.solvers.tools.synthetic.synth import synthesize_take

    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    Wcal, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    for name in WEAK:
        Wcal[:, actor.shape_names.index(name)] *= 0.4
    calib = synthesize_take(actor, Wcal, rest=30, stable=STABLE, units="mm", actor_scale=1.0, gap_fraction=0.0,
                            max_deg=10.0, seed=5)
    s = CalibratedStrategy().fit(character, calibration=calib.markers, poses=poses, neutral=neutral,
                                 stable_markers=STABLE)
    take = actor_take(actor, performance_weights(character.shape_names, 600, seed=0), gaps=0.05, seed=2)
    res = s.solve(take.deltas, names=take.names, neutral=take.neutral)
    lib = s.actor_basis
    D = reorder(take.deltas, take.names, lib.marker_names)
    D, _ = align_to(D, reorder(take.neutral[None], take.names, lib.marker_names)[0], lib.neutral, mode=s.align)
    Ws, W = res.source_weights, take.weights
    assert np.nanmax(np.abs(default_solver(lib, D) - Ws)) < 1e-9  # default_solver = the strategy's solve
    frames = _worst_frames(W, Ws)
    other = np.setdiff1d(np.arange(len(W)), frames)
    r = retune(lib, D, Ws, {t: W[t] for t in frames}, parent="calib")
    again = CalibratedStrategy().fit(character, actor_basis=r.library).solve(take.deltas, names=take.names,
                                                                             neutral=take.neutral)
    h0, h1 = _rmse(Ws[other] - W[other]), _rmse(again.weights[other] - W[other])
    print(f"\nthrough CalibratedStrategy: corrected {r.corrected_rmse_before:.4f} -> {r.corrected_rmse_after:.4f}, "
          f"held-out {h0:.4f} -> {h1:.4f} ({(h1 - h0) / h0:+.1%}), {len(r.changed)} poses changed, LOO {r.cv}")
    assert r.corrected_rmse_after <= 0.05 and h1 <= 0.85 * h0
    assert np.allclose(again.source_weights, r.weights, equal_nan=True)
    assert r.version.startswith("calib+tune8f-") and r.candidate.startswith("gain")


def test_spread_frames_picks_the_worst_apart():
    scores = np.array([0.1, 0.9, 0.8, np.nan, 0.5, 0.05, 0.7])
    assert spread_frames(scores, 3, min_gap=2) == [1, 4, 6]
    assert spread_frames(scores, 10, min_gap=1) == [0, 1, 2, 4, 5, 6]  # NaN never picked
