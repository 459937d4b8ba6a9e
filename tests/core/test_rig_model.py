"""The Blender-free side of rig targets: the rig model and its fit, probing, the bounded nonlinear
solve with the temporal term, pose libraries, ``RigTarget`` through ``solvers.solve``, ``[rig]``."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers.character.basis import Basis
from facecap.solvers.config import load_take_config
from facecap.solvers.engine import solve_bounded
from facecap.solvers.errors import ConfigError, FacecapError
from facecap.solvers.pipeline import RetargetSettings
from facecap.solvers.rig import PoseLibrary, RigModel, RigTarget, fit_model, probe_rig, solve_nonlinear
from facecap.solvers.rig.fit import features
from facecap.solvers.solve import SolveRequest, solve
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

ROOT = Path(__file__).resolve().parents[2]
STABLE = ("head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
          "head_nose_bridge_C", "head_side_L", "head_side_R")
#: Corrective pairs on the sample character's ARKit shapes (a * b fires a corrective shape).
CORRECTIVE_PAIRS = (("jawOpen", "mouthSmileLeft"), ("jawOpen", "mouthSmileRight"), ("jawOpen", "mouthFunnel"),
                    ("eyeBlinkLeft", "cheekSquintLeft"), ("browInnerUp", "browDownLeft"))


def random_model(C=6, M=8, seed=0, cubic=True):
    rng = np.random.default_rng(seed)
    pairs = np.array([(0, 1), (2, 4)])
    return RigModel([f"c{i}" for i in range(C)], [f"m{i}" for i in range(M)], rng.normal(size=(M, 3)) * 0.05,
                    rng.normal(size=(C, M, 3)) * 0.005, rng.normal(size=(C, M, 3)) * 0.002,
                    rng.normal(size=(C, M, 3)) * 0.001 * cubic, pairs, rng.normal(size=(2, M, 3)) * 0.004,
                    np.zeros(C), -np.ones(C), np.ones(C))


@pytest.fixture(scope="module")
def corrective_rig():
    """The sample character's shape keys plus corrective shapes on products of five pairs."""
    basis = Basis.load_npz(ROOT / "sample_blends" / "character_basis.npz")
    index = {n: i for i, n in enumerate(basis.shape_names)}
    pairs = np.array([sorted((index[a], index[b])) for a, b in CORRECTIVE_PAIRS])
    rng = np.random.default_rng(3)
    fix = []
    for a, b in pairs:
        both = basis.deltas[a] + basis.deltas[b]
        moving = np.linalg.norm(both, axis=1, keepdims=True) > 1e-4
        fix.append(-0.4 * both + 0.002 * rng.normal(size=both.shape) * moving)
    C = basis.n_shapes
    zero = np.zeros_like(basis.deltas)
    return RigModel(basis.shape_names, basis.marker_names, basis.neutral, basis.deltas, zero, zero, pairs,
                    np.array(fix), np.zeros(C), basis.lower, basis.upper)


def take_of(model, weights, seed=5):
    """A marker take of ``model`` performing ``weights`` (head motion, noise, gaps)."""
    C = model.n_controls
    terms = features(weights, model.pairs)
    extended = Basis(tuple(f"f{i}" for i in range(terms.shape[1])), model.marker_names, model.neutral,
                     np.concatenate([model.linear, model.square, model.cube, model.pair_deltas]),
                     np.full(terms.shape[1], -10.0), np.full(terms.shape[1], 10.0))
    assert terms.shape[1] == 3 * C + len(model.pairs)
    return synthesize_take(extended, terms, stable=STABLE, seed=seed)


def test_model_jacobian_matches_finite_differences():
    model = random_model()
    u = np.random.default_rng(1).uniform(-0.8, 0.8, size=(4, model.n_controls))
    J = model.jacobian(u)
    h = 1e-6
    for i in range(model.n_controls):
        step = np.zeros_like(u)
        step[:, i] = h
        fd = (model.deltas(u + step) - model.deltas(u - step)).reshape(len(u), -1) / (2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-9)


def test_fit_recovers_every_term_of_a_cubic_pairwise_rig():
    model = random_model()
    rng = np.random.default_rng(2)
    u = rng.uniform(-1, 1, size=(400, model.n_controls)) * (rng.uniform(size=(400, model.n_controls)) < 0.5)
    fitted, rms = fit_model(model.control_names, model.marker_names, model.neutral, u, model.deltas(u),
                            pairs=[(1, 0), (2, 4)], rest=model.rest, lower=model.lower, upper=model.upper)
    assert rms < 1e-9  # a nanometre: the ridge that keeps unprobed terms at 0
    for name in ("linear", "square", "cube", "pair_deltas"):
        np.testing.assert_allclose(getattr(fitted, name), getattr(model, name), atol=1e-8)


def test_probing_finds_the_pairs_and_the_controls_that_are_not_cubic():
    model = random_model(cubic=False)
    tent = np.zeros(model.n_controls)

    def evaluate(offsets):  # the model, plus an in-between on control 3 (a tent: not a cubic)
        bump = np.maximum(0.0, 1.0 - np.abs(2.0 * offsets[:, 3] - 1.0))
        return model.deltas(offsets) + bump[:, None, None] * 0.004

    fitted, report = probe_rig(evaluate, model.control_names, model.marker_names, model.neutral, rest=tent,
                               lower=model.lower, upper=model.upper, n_random=300)
    assert set(report.pairs) == {("c0", "c1"), ("c2", "c4")}
    assert report.uneven == ("c3",) and report.unseen == ()
    assert report.holdout_rms > 1e-4  # the held-out poses show what a cubic misses of the tent (4 mm peak)
    exact, only_pairs = probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral, rest=tent,
                                  lower=model.lower, upper=model.upper, pairs=[(0, 1)], find_pairs=False, n_random=50)
    assert only_pairs.pairs == (("c0", "c1"),) and only_pairs.uneven == ()
    assert only_pairs.holdout_rms > 1e-4  # the (2, 4) pair was neither read from drivers nor looked for
    pairs_found = probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral, rest=tent,
                            lower=model.lower, upper=model.upper, n_random=50)[1]
    assert pairs_found.holdout_rms < 1e-9 and pairs_found.fit_rms < 1e-9


def test_probing_refuses_an_empty_range_and_can_be_cancelled():
    model = random_model()
    with pytest.raises(FacecapError, match=r"empty range"):
        probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral, rest=np.zeros(6),
                  lower=np.r_[0.0, -np.ones(5)], upper=np.r_[0.0, np.ones(5)])
    with pytest.raises(FacecapError, match="cancelled"):
        probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral, rest=np.zeros(6),
                  lower=model.lower, upper=model.upper, progress=lambda done, total: False)


def test_nonlinear_solve_halves_the_error_where_correctives_fire(corrective_rig):
    """With correctives firing, the weight RMSE of the nonlinear solve is at most half the linear one's."""
    model = corrective_rig
    weights = performance_weights(model.control_names, 600, seed=4)
    take = take_of(model, weights)
    settings = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 50))
    firing = (features(weights, model.pairs)[:, 3 * model.n_controls:] > 0.05).any(axis=1)
    assert firing.sum() > 50
    errors = {}
    for nonlinear in (False, True):
        result = solve(SolveRequest(character=None, settings=settings, markers=take.markers,
                                    rig=RigTarget("probed", model=model, nonlinear=nonlinear)))
        assert result.shape_names == model.control_names
        errors[nonlinear] = np.sqrt(np.nanmean((result.weights[firing] - weights[firing]) ** 2))
        assert (result.weights >= model.lower - 1e-9).all() and (result.weights <= model.upper + 1e-9).all()
    assert result.info["rig"]["iterations"] >= 1 and result.info["rig"]["converged"]
    assert errors[True] <= 0.5 * errors[False], errors


def test_nonlinear_solve_keeps_the_temporal_term_locks_and_bounds():
    model = random_model()
    rng = np.random.default_rng(6)
    F = 200
    t = np.linspace(0, 1, F)
    truth = 0.8 * np.sin(2 * np.pi * (t[:, None] * (1 + np.arange(6)) / 2 + np.arange(6) / 6))
    data = model.deltas(truth) + rng.normal(size=(F, 8, 3)) * 2e-4
    start = np.zeros((F, 6))
    rough = solve_nonlinear(model, data, start=start, smoothing=(0.0, 0.0), regularisation=1e-6)
    smooth = solve_nonlinear(model, data, start=start, smoothing=(0.0, 0.3), regularisation=1e-6)
    jitter = [np.abs(np.diff(r.offsets, 2, axis=0)).mean() for r in (rough, smooth)]
    assert jitter[1] < 0.5 * jitter[0]
    assert np.sqrt(np.mean((smooth.offsets - truth) ** 2)) < 0.05
    locks = np.full(6, np.nan)
    locks[2] = 0.25
    held = solve_nonlinear(model, data, start=start, locks=locks)
    np.testing.assert_array_equal(held.offsets[:, 2], 0.25)
    assert held.offsets.min() >= -1.0 and held.offsets.max() <= 1.0
    with pytest.raises(FacecapError, match=r"start must have shape \(200, 6\)"):
        solve_nonlinear(model, data, start=np.zeros((10, 6)))


def test_linear_solve_of_the_secant_basis_is_the_engine_solve():
    model = random_model(cubic=False)
    basis = model.basis()
    # each control's effect at the end of its range (+-1) that moves the points most, over that offset
    up, down = model.linear + model.square, -model.linear + model.square
    bigger = (up ** 2).sum(axis=(1, 2)) >= (down ** 2).sum(axis=(1, 2))
    assert bigger.any() and not bigger.all()
    np.testing.assert_allclose(basis.deltas, np.where(bigger[:, None, None], up, -down))
    assert np.array_equal(basis.lower, model.lower) and np.array_equal(basis.upper, model.upper)
    d = model.deltas(np.full((3, 6), 0.5))
    res = solve_bounded(basis.matrix(), d.reshape(3, -1), lower=basis.lower, upper=basis.upper)
    assert res.weights.shape == (3, 6)


def test_pose_library_turns_pose_weights_into_clipped_control_values():
    lib = PoseLibrary(("jawOpen", "smile"), ("jaw", "cornerL", "cornerR"), [[0.3, 0.0, 0.0], [0.0, 0.8, 0.8]],
                      rest=[0.0, 0.0, 0.0], lower=[-1.0, -1.0, -1.0], upper=[1.0, 1.0, 1.0])
    np.testing.assert_allclose(lib.controls([[1.0, 0.5], [0.0, 2.0]]), [[0.3, 0.4, 0.4], [0.0, 1.0, 1.0]])
    with pytest.raises(FacecapError, match=r"pose\(s\) \['idle'\] leave every control at rest"):
        PoseLibrary(("idle",), ("jaw",), [[0.0]], rest=[0.0], lower=[-1.0], upper=[1.0])
    with pytest.raises(FacecapError, match=r"poses must have shape \(1, 2\)"):
        PoseLibrary(("a",), ("jaw", "x"), [[0.1]], rest=[0.0, 0.0], lower=[-1.0, -1.0], upper=[1.0, 1.0])


def test_rig_model_names_bad_shapes_and_rest_outside_the_limits():
    m = random_model()
    with pytest.raises(FacecapError, match=r"rest value of control\(s\) \['c0'\]"):
        RigModel(m.control_names, m.marker_names, m.neutral, m.linear, m.square, m.cube, m.pairs, m.pair_deltas,
                 np.r_[2.0, np.zeros(5)], m.lower, m.upper)
    with pytest.raises(FacecapError, match=r"linear must have shape \(6, 8, 3\)"):
        RigModel(m.control_names, m.marker_names, m.neutral, m.linear[:2], m.square, m.cube, m.pairs,
                 m.pair_deltas, m.rest, m.lower, m.upper)


def write(tmp_path, rig):
    (tmp_path / "take.csv").write_text("frame,a_x,a_y,a_z\n1,0,0,0\n")
    path = tmp_path / "take.toml"
    path.write_text(f'[target]\nobject = "Face"\n[source]\nmarkers = "take.csv"\n[stabilise]\nmarkers = ["a", "b", "c"]\n'
                    f'[neutral]\nframes = [1, 1]\n[rig]\n{rig}')
    return path


@pytest.mark.parametrize("rig, message", [
    ('method = "probed"\n', r"\[rig.preset\] name the controls"),
    ('preset = "rigify_face"\n', r"\[rig.object\] preset \"rigify_face\" needs the rig"),
    ('preset = "shape_keys"\nmethod = "poses"\n', r"\[rig.poses\] method = \"poses\" needs poses"),
    ('preset = "shape_keys"\npreset2 = 1\n', r"\[rig.preset2\] unknown key"),
    ('controls = [{object = "rig"}]\n', r"\[rig.controls\[0\]\] needs path"),
    ('controls = [{object = "rig", path = "x", axes = [3]}]\n', r"axes must be a list of 0, 1, 2"),
    ('controls = [{object = "rig", path = "x", lower = 1, upper = 0}]\n', r"lower \(1\) must be below upper"),
    ('preset = "bones"\n', r"\[rig.preset\] expected one of rigify_face"),
])
def test_rig_section_errors_name_the_key(tmp_path, rig, message):
    with pytest.raises(ConfigError, match=message):
        load_take_config(write(tmp_path, rig))


def test_rig_section_reads_presets_and_controls(tmp_path):
    config = load_take_config(write(tmp_path, 'preset = "rigify_face"\nobject = "rig"\nprobes = 50\nrefine = false\n'
                                    'controls = [{object = "rig", path = \'pose.bones["jaw"].rotation\', axes = [0]}]\n'))
    rig = config.rig
    assert (rig.preset, rig.object, rig.method, rig.probes, rig.refine, rig.nonlinear) == \
        ("rigify_face", "rig", "probed", 50, False, True)
    assert rig.controls == ({"object": "rig", "path": 'pose.bones["jaw"].rotation', "axes": [0]},)
    assert load_take_config(write(tmp_path, 'preset = "shape_keys"\n')).rig.preset == "shape_keys"


def test_gradient_without_the_jacobian_is_the_jacobian_product():
    """The fast path's gradient (J' v from the model's terms) against the formed Jacobian."""
    model = random_model()
    rng = np.random.default_rng(2)
    u = rng.uniform(-0.8, 0.8, size=(5, model.n_controls))
    v = rng.normal(size=(5, 8 * 3))
    expected = np.einsum("fpc,fp->fc", model.jacobian(u), v)
    np.testing.assert_allclose(model.jacobian_t_dot(u, v), expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(model.jacobian_t(u, np.float32), model.jacobian(u).transpose(2, 0, 1), rtol=1e-5,
                               atol=1e-9)


def test_fast_gauss_newton_gives_the_reference_solution(corrective_rig):
    """float32 blocks kept while a frame's controls barely move: the same offsets as float64 blocks
    formed every iteration, within 1 % of each control's range, and the same final objective."""
    model = corrective_rig
    weights = performance_weights(model.control_names, 300, seed=4)
    data = model.deltas(weights) + np.random.default_rng(7).normal(size=(300,) + model.neutral.shape) * 3e-4
    start = np.clip(weights + 0.1, model.lower, model.upper)
    ref = solve_nonlinear(model, data, start=start)
    fast = solve_nonlinear(model, data, start=start, hessian=np.float32, reuse=0.02)
    assert ref.converged and fast.converged
    span = model.upper - model.lower
    assert np.abs((fast.offsets - ref.offsets) / span).max() < 0.01
    assert fast.cost_end <= ref.cost_end * 1.001


def test_refinement_windows_hold_two_frames_each_side_and_defect_only_where_asked():
    from facecap.solvers.rig.retarget import refine_windows, rig_defect

    bad = np.zeros(40, dtype=bool)
    bad[[10, 11, 30]] = True
    window, held = refine_windows(bad, pad=3)
    assert np.flatnonzero(window).tolist() == list(range(5, 17)) + list(range(25, 36))
    assert np.flatnonzero(held).tolist() == [5, 6, 15, 16, 25, 26, 34, 35]
    model = random_model()
    u = np.random.default_rng(3).uniform(-0.5, 0.5, size=(40, model.n_controls))
    asked = []

    def evaluate(offsets):  # the "real rig": the model plus 1 mm on every point
        asked.append(len(offsets))
        return model.deltas(offsets) + 1e-3

    frames = np.zeros(40, dtype=bool)
    frames[12:20] = True
    defect, flagged = rig_defect(evaluate, model, u, model.marker_names, model.marker_names, 0.05, stride=5,
                                 frames=frames)
    assert asked == [3]  # grid frame 15 and the run's ends 12 and 19; the grid outside it is not evaluated
    np.testing.assert_array_equal(flagged, frames)
    np.testing.assert_allclose(defect[frames], 1e-3)
    assert not defect[~frames].any()


def test_probing_steps_report_progress_and_stop_when_closed():
    from facecap.solvers.rig import probe_rig_steps

    model = random_model()
    calls = []

    def evaluate(offsets):
        calls.append(len(offsets))
        return model.deltas(offsets)

    steps = probe_rig_steps(evaluate, model.control_names, model.marker_names, model.neutral, rest=np.zeros(6),
                            lower=model.lower, upper=model.upper, n_random=50, chunk=16)
    seen = [next(steps) for _ in range(3)]
    assert [d for d, _ in seen] == [16, 32, 48] and all(total >= 48 + 50 for _, total in seen)
    steps.close()  # as Esc does: nothing more is evaluated
    assert calls == [16, 16, 16]
    model_all, report = probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral,
                                  rest=np.zeros(6), lower=model.lower, upper=model.upper, n_random=50)
    done = []
    chunked, chunked_report = probe_rig(model.deltas, model.control_names, model.marker_names, model.neutral,
                                        rest=np.zeros(6), lower=model.lower, upper=model.upper, n_random=50,
                                        chunk=7, progress=lambda d, t: done.append((d, t)) or True)
    assert done[-1][0] == report.probes == chunked_report.probes and len(done) > 5
    np.testing.assert_allclose(chunked.linear, model_all.linear, atol=1e-15)


def _in_units(model, scale):
    """``model`` with control k measured in units ``1 / scale[k]`` of its own (a slider turned into
    metres, radians...): offsets and limits times scale, each term divided by its power of it."""
    s = np.asarray(scale, dtype=np.float64)
    a, b = model.pairs[:, 0], model.pairs[:, 1]
    powers = [s[:, None, None] ** k for k in (1, 2, 3)]
    return RigModel(model.control_names, model.marker_names, model.neutral, model.linear / powers[0],
                    model.square / powers[1], model.cube / powers[2], model.pairs,
                    model.pair_deltas / (s[a] * s[b])[:, None, None], model.rest * s, model.lower * s,
                    model.upper * s, np.stack([n / p for n, p in zip(model.negative, powers)]), model.kink * s,
                    model.pair_sides)


def test_the_solved_controls_do_not_depend_on_each_controls_units(corrective_rig):
    """Regression (issue 39): the priors were scaled by the controls' mean effect per unit, so a rig
    whose bones move in metres and turn in radians beside 0..1 sliders pinned the sliders. The same
    rig with some controls in other units (x0.01, x0.4, x100) gives the same controls, converted."""
    model = corrective_rig
    weights = performance_weights(model.control_names, 300, seed=4)
    take = take_of(model, weights)
    settings = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 50))
    scale = np.ones(model.n_controls)
    names = list(model.control_names)
    for name, s in (("jawOpen", 0.01), ("mouthSmileLeft", 0.4), ("browInnerUp", 100.0), ("eyeBlinkLeft", 0.01)):
        scale[names.index(name)] = s
    plain, scaled = (solve(SolveRequest(character=None, settings=settings, markers=take.markers,
                                        rig=RigTarget("probed", model=m))) for m in (model, _in_units(model, scale)))
    np.testing.assert_allclose(scaled.weights / scale, plain.weights, atol=1e-6)
    error = np.sqrt(np.nanmean((plain.weights - weights) ** 2, axis=0))
    assert error[names.index("browInnerUp")] < 0.05, error  # not pinned at rest


def _joystick_rig():
    """A rig of 3 controls on 6 points: c0 a joystick (up: a smoothstep of shape A; down: a clamp of
    shape B), c1 a slider (sin of shape C), c2 a slider; a corrective on (c0 down) x (c1)."""
    rng = np.random.default_rng(5)
    A, B, C, E, fix = (rng.normal(size=(6, 3)) * 0.004 for _ in range(5))

    def evaluate(u):
        up, down = np.clip(u[:, 0], 0, 1), np.clip(-u[:, 0], 0, 1)
        s1 = np.sin(np.clip(u[:, 1], 0, 1) * np.pi / 2)
        w = [up * up * (3 - 2 * up), np.clip(1.25 * down, 0, 1), s1, u[:, 2], down * u[:, 1]]
        return sum(wk[:, None, None] * d[None] for wk, d in zip(w, (A, B, C, E, fix)))
    return evaluate


def test_a_joystick_is_modelled_per_side_with_its_corrective_on_one_quadrant():
    evaluate = _joystick_rig()
    names, markers = ("c0", "c1", "c2"), tuple(f"m{i}" for i in range(6))
    model, report = probe_rig(evaluate, names, markers, np.zeros((6, 3)), rest=np.zeros(3),
                              lower=np.array([-1.0, 0.0, 0.0]), upper=np.ones(3), n_random=300)
    assert report.split == ("c0",)
    assert [tuple(p) for p in report.pairs] == [("c0-", "c1")]
    u = np.random.default_rng(1).uniform([-1, 0, 0], [1, 1, 1], size=(200, 3))
    size = np.abs(evaluate(u)).max()
    assert np.abs(model.deltas(u) - evaluate(u)).max() < 0.03 * size  # a cubic each side: smoothstep exact
    J = model.jacobian(u[:4])
    h = 1e-6
    for i in range(3):
        step = np.zeros((4, 3))
        step[:, i] = h
        fd = (model.deltas(u[:4] + step) - model.deltas(u[:4] - step)).reshape(4, -1) / (2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-8)
    np.testing.assert_allclose(model.jacobian_t_dot(u[:4], np.ones((4, 18))), J.sum(axis=1), atol=1e-12)
    up, down = model.along(0, [1.0])[0], model.along(0, [-1.0])[0]
    more = up if (up ** 2).sum() >= (down ** 2).sum() else -down  # the side that moves the points most
    np.testing.assert_allclose(model.secant()[0], more)


def test_a_rig_solve_that_does_not_settle_says_why(corrective_rig):
    model = corrective_rig
    weights = performance_weights(model.control_names, 200, seed=4)
    take = take_of(model, weights)
    settings = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 50))
    result = solve(SolveRequest(character=None, settings=settings, markers=take.markers,
                                rig=RigTarget("probed", model=model, max_iter=1)))
    info = result.info["rig"]
    assert not info["converged"] and info["last_step_drop"] > 1e-4
    assert any("stopped at their limit" in w for w in result.warnings), result.warnings


def test_a_library_version_of_a_rig_moves_its_nonlinear_model_too(corrective_rig):
    """A retune (or a chosen version) changes the columns the linear solve sees; the Gauss-Newton
    model takes the change as each control's first-order term, so the nonlinear solve keeps it."""
    target = RigTarget("probed", model=corrective_rig)
    basis = target.character
    k = basis.shape_names.index("jawOpen")
    deltas = basis.deltas.copy()
    deltas[k] *= 1.2
    tuned = target.with_columns(Basis(basis.shape_names, basis.marker_names, basis.neutral, deltas, basis.lower,
                                      basis.upper))
    np.testing.assert_allclose(tuned.character.deltas, deltas, atol=1e-12)
    assert target.with_columns(basis) is target


def test_a_curved_control_starts_on_its_own_curve_not_its_secant():
    """The Gauss-Newton start of a rig whose controls act far from proportionally (a smoothstep up, a
    clamp down, a sin slider): each frame solved on quarters of each control's range lands near the
    true offsets, where the secant columns alone put the joystick's down side and the slider wrong."""
    from facecap.solvers.rig.start import curved_start

    evaluate = _joystick_rig()
    model, _ = probe_rig(evaluate, ("c0", "c1", "c2"), tuple(f"m{i}" for i in range(6)), np.zeros((6, 3)),
                         rest=np.zeros(3), lower=np.array([-1.0, 0.0, 0.0]), upper=np.ones(3), n_random=300)
    u = np.random.default_rng(4).uniform([-0.8, 0.0, 0.0], [0.8, 0.8, 0.8], size=(60, 3))
    u[:, 1] = 0.0  # the corrective (c0 down x c1) is left to the Gauss-Newton steps: here none fires
    start = curved_start(model, evaluate(u), regularisation=1e-6, lower=model.lower, upper=model.upper)
    secant = solve_bounded(model.basis().matrix(), evaluate(u).reshape(60, -1), lower=model.lower, upper=model.upper,
                           regularisation=1e-6, relative=True).weights
    error = [np.sqrt(np.mean((w - u) ** 2, axis=0)) for w in (start, secant)]
    assert error[0][0] < 0.1 < error[1][0] and error[0].max() < 0.1, error  # measured 0.063 against 0.31
    held = curved_start(model, evaluate(u), regularisation=1e-6, lower=model.lower, upper=model.upper,
                        locks=np.array([np.nan, 0.25, np.nan]))
    np.testing.assert_array_equal(held[:, 1], 0.25)


def test_a_control_that_moves_nothing_stays_at_rest(corrective_rig):
    """Regression: the response of a control no marker sees was fitted noise, and the sparsity acting
    on it pushed the control off rest (tongueOut of the control rig sat at 0.3)."""
    model = corrective_rig
    k = model.control_names.index("tongueOut")
    rng = np.random.default_rng(9)
    noise = [rng.normal(size=model.linear[k].shape) * 1e-9 for _ in range(3)]
    linear, square, cube = model.linear.copy(), model.square.copy(), model.cube.copy()
    linear[k], square[k], cube[k] = noise[0], -noise[1] * 50, noise[2] * 30  # a wavy response of nothing
    noisy = RigModel(model.control_names, model.marker_names, model.neutral, linear, square, cube, model.pairs,
                     model.pair_deltas, model.rest, model.lower, model.upper)
    assert np.allclose(noisy._response[k], [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    weights = performance_weights(model.control_names, 200, seed=4)
    take = take_of(model, weights)
    settings = RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 50))
    result = solve(SolveRequest(character=None, settings=settings, markers=take.markers,
                                rig=RigTarget("probed", model=noisy)))
    assert np.nanmax(np.abs(result.weights[:, k])) < 0.01


def test_only_controls_at_rest_at_0_and_limited_to_0_1_read_as_shape_weights():
    """``RigTarget.weight_controls``: what a landmark take's blendshape scores and eye locks (weights 0-1) may be
    written into; a control of another range (two-sided, 0-2, at rest mid-range) is left to the landmarks."""
    model = random_model(C=5)
    model = replace(model, control_names=["eyeBlinkLeft", "jaw_side", "brow_0_2", "mid_rest", "jawOpen"],
                    rest=np.array([0.0, 0.0, 0.0, 0.5, 0.0]), lower=np.array([0.0, -1.0, 0.0, 0.0, 0.0]),
                    upper=np.array([1.0, 1.0, 2.0, 1.0, 1.0]))
    assert RigTarget("probed", model=model).weight_controls == ("eyeBlinkLeft", "jawOpen")


def test_a_landmark_take_onto_a_rig_says_which_controls_the_video_scores_reach():
    """Nothing said when every control reads as a shape weight; how many are solved from the landmarks alone when
    some do not; that none get the scores and eyes when none do (a bone rig)."""
    from facecap.facecap_addon.headless.take_request import rig_weights_note

    model = replace(random_model(C=5), control_names=["jawOpen", "jaw_side", "eyeBlinkLeft", "a", "b"],
                    rest=np.zeros(5), lower=np.array([0.0, -1.0, 0.0, 0.0, 0.0]), upper=np.ones(5))
    target = RigTarget("probed", model=model)
    assert rig_weights_note(target, target.weight_controls) == (
        "[rig] the video's blendshape scores and eyes reach the 4 control(s) that read as shape weights (at rest "
        "at 0, limits 0 and 1); the other 1 are solved from the landmarks alone",)
    assert rig_weights_note(target, ())[0].startswith("[rig] none of the rig's controls reads as a shape weight")
    whole = RigTarget("probed", model=replace(model, lower=np.zeros(5)))
    assert rig_weights_note(whole, whole.weight_controls) == ()
