"""retarget() with every strategy: dispatch, shared stabilisation, inputs, errors, report; the strategy config sections."""

import json
from dataclasses import replace

import numpy as np
import pytest

from facecap.solvers import ConfigError, load_take_config
from facecap.solvers.tools.compare import STABLE, build_scenario
from facecap.solvers.errors import FacecapError
from facecap.solvers.io.weights import WeightTrack
from facecap.solvers.pipeline import RetargetSettings, retarget
from facecap.solvers.strategies.base import Target
from facecap.solvers.strategies.options import CalibrationSettings, ExamplePairs, MappingSettings, StrategyInputs
from facecap.solvers.strategies.pca import farthest_frames
from facecap.solvers.config.strategies import load_strategy_inputs


@pytest.fixture(scope="module")
def sc():
    return build_scenario(frames=360, n_examples=40)


@pytest.fixture(scope="module")
def settings(sc):
    poses = tuple((k, (tuple(v),)) for k, v in sc.poses.items())
    cal = CalibrationSettings(poses=poses, neutral_frames=tuple(sc.calibration_neutral))
    return RetargetSettings(stable_markers=STABLE, neutral_frames=(1, 60), calibration=cal)


def rmse(result, truth):
    return float(np.sqrt(np.mean(np.nan_to_num(result.weights - truth, nan=1.0) ** 2)))


def test_calibrated_gets_actor_space_deltas_and_matches_the_strategy(sc, settings):
    r = retarget(sc.test.markers, sc.character, replace(settings, strategy="calibrated"),
                 inputs=StrategyInputs(calibration=sc.calibration))
    assert r.strategy == "calibrated" and r.alignment is None and r.residual_space == "actor"
    assert r.shape_names == sc.character.shape_names and r.weights.shape == sc.test.weights.shape
    # the same numbers as the strategy fed by hand (compare's pipeline-free path), up to head smoothing
    from facecap.solvers.strategies import make_strategy

    direct = make_strategy("calibrated").fit(sc.character, calibration=sc.calibration, poses=sc.poses,
                                             neutral=sc.calibration_neutral, stable_markers=STABLE)
    d = direct.solve(sc.test.deltas, names=sc.test.names, neutral=sc.test.neutral)
    assert abs(rmse(r, sc.test.weights) - rmse(d, sc.test.weights)) < 0.005
    assert rmse(r, sc.test.weights) < 0.06
    json.dumps(r.report())
    assert np.nanmean(r.residual_rms) < 0.002  # metres, actor space


def test_geometric_is_unchanged_and_needs_a_basis(sc, settings):
    settings = replace(settings, strategy="geometric")
    g = retarget(sc.test.markers, sc.character, settings)
    assert g.strategy == "geometric" and g.alignment is not None
    with pytest.raises(FacecapError, match="geometric' needs the character's shapes at the bound points"):
        retarget(sc.test.markers, Target(sc.character.shape_names, sc.character.lower, sc.character.upper), settings)


@pytest.mark.parametrize("strategy, needs", [
    ("calibrated", r"strategy 'calibrated' needs \[calibration\] markers and poses"),
    ("refine", r"strategy 'refine' needs \[calibration\] markers and poses"),
    ("linear", r"strategy 'linear' needs \[examples\] weights"),
    ("rbf", r"strategy 'rbf' needs \[examples\] weights"),
    ("pca", r"strategy 'pca' needs \[examples\] weights"),
    ("parallel", r"strategy 'parallel' needs \[source\] weights"),
])
def test_missing_inputs_are_named(sc, settings, strategy, needs):
    with pytest.raises(FacecapError, match=needs):
        retarget(sc.test.markers, sc.character, replace(settings, strategy=strategy))


def test_stored_actor_basis_replaces_the_calibration_take(sc, settings):
    s = replace(settings, strategy="calibrated")
    first = retarget(sc.test.markers, sc.character, s, inputs=StrategyInputs(calibration=sc.calibration))
    again = retarget(sc.test.markers, sc.character.shape_names, s,
                     inputs=StrategyInputs(actor_basis=first.fitted.actor_basis))
    np.testing.assert_allclose(again.weights, first.weights, atol=1e-12)


def test_locks_bounds_and_mapping_table_apply_to_calibrated(sc, settings):
    table = (("jawOpen", "jawOpen", 0.5), ("jawOpen", "mouthClose", 0.2))
    s = replace(settings, strategy="calibrated", bounds=(("mouthSmile*", 0.0, 0.3),), locks=(("eyeBlinkLeft", 0.25),),
                mapping=MappingSettings(table=table))
    r = retarget(sc.test.markers, sc.character, s, inputs=StrategyInputs(calibration=sc.calibration))
    k = sc.character.shape_names.index
    assert np.all(r.weights[:, k("eyeBlinkLeft")] == 0.25)
    assert np.nanmax(r.weights[:, k("mouthSmileLeft")]) <= 0.3 + 1e-12
    jaw = r.source_weights[:, r.source_names.index("jawOpen")]
    np.testing.assert_allclose(r.weights[:, k("jawOpen")], np.clip(0.5 * jaw, 0, 1), atol=1e-9)


@pytest.mark.parametrize("strategy", ["linear", "rbf", "pca"])
def test_example_strategies_from_frames_of_the_take_or_another_take(sc, settings, strategy):
    te, tr = sc.test, sc.training
    ex = farthest_frames(te.deltas, 40)
    own = ExamplePairs(te.markers.frames[ex], te.weights[ex], sc.character.shape_names)
    other = ExamplePairs(tr.markers.frames[sc.example_frames], tr.weights[sc.example_frames],
                         sc.character.shape_names, markers=tr.markers)
    for pairs in (own, other):
        r = retarget(te.markers, sc.character, replace(settings, strategy=strategy), inputs=StrategyInputs(examples=pairs))
        assert rmse(r, te.weights) < 0.16
        json.dumps(r.report())  # rbf: per-frame distances become a list


def test_examples_name_unknown_shapes_and_frames(sc, settings):
    te = sc.test
    bad = ExamplePairs(te.markers.frames[:3], np.zeros((3, 1)), ("noSuchShape",))
    with pytest.raises(FacecapError, match=r"character does not have: \['noSuchShape'\]"):
        retarget(te.markers, sc.character, replace(settings, strategy="linear"), inputs=StrategyInputs(examples=bad))
    bad = ExamplePairs(np.array([99999.0]), np.zeros((1, 1)), ("jawOpen",))
    with pytest.raises(FacecapError, match=r"frame\(s\) \[99999.0\] are not in the example take"):
        retarget(te.markers, sc.character, replace(settings, strategy="linear"), inputs=StrategyInputs(examples=bad))


def test_refine_keeps_the_original_library(sc, settings):
    r = retarget(sc.test.markers, sc.character, replace(settings, strategy="refine"),
                 inputs=StrategyInputs(calibration=sc.calibration))
    s = r.fitted
    assert s.original_basis is not s.refined_basis and r.info["version"] == len(r.info["history"]) - 1
    assert all(b <= a for a, b in zip(r.info["history"], r.info["history"][1:]))


def test_parallel_needs_no_markers(settings):
    names = ("JawOpen", "MouthSmileLeft", "EyeBlinkRight")
    values = np.array([[0.1, 0.0, 0.2], [0.1, 0.0, 0.2], [0.6, 0.5, 1.0], [np.nan, 0.4, 0.3]])
    track = WeightTrack(frames=np.arange(1.0, 5.0), fps=60.0, names=names, values=values)
    target = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "eyeBlinkRight")
    s = replace(settings, strategy="parallel", mapping=MappingSettings(gain=(("jawOpen", 2.0),), neutral_frames=(1, 2)))
    r = retarget(None, target, s, inputs=StrategyInputs(weights=track))
    assert r.strategy == "parallel" and r.stabilise is None and r.marker_names == ()
    np.testing.assert_allclose(r.weights[2], [1.0, 0.5, 0.0, 0.8])  # (0.6 - 0.1) * 2, clipped; neutral offsets
    assert np.isnan(r.weights[3, 0]) and r.weights[3, 1] == pytest.approx(0.4)
    report = r.report()
    json.dumps(report)
    assert report["stabilise"] is None and report["residual_rms_mm"]["mean"] is None


# -- config ---------------------------------------------------------------------------------------

BASE = """
[target]
object = "Face"
[source]
markers = "take.csv"
units = "mm"
[stabilise]
markers = ["a", "b", "c"]
[neutral]
frames = [1, 30]
"""


def write(tmp_path, text):
    path = tmp_path / "take.toml"
    path.write_text(text)
    return path


def test_calibration_mapping_sections_are_read(tmp_path):
    text = BASE + """[solve]
strategy = "calibrated"
[calibration]
markers = "cal/calib.csv"
neutral = [1, 20]
poses = { jawOpen = [120, 135], AU12 = [[200, 215], [400, 410]], mouthSmile = [50, 60] }
split = ["mouthSmile"]
align = "similarity"
[mapping]
keyed_by = "target"
table = { mouthClose = { jawOpen = 0.3 }, cheekPuff = "AU12" }
[output]
actor_basis = "out/actor.npz"
"""
    cfg = load_take_config(write(tmp_path, text))
    s = cfg.settings
    assert cfg.calibration_path == (tmp_path / "cal" / "calib.csv").resolve()
    assert cfg.output_actor_basis == (tmp_path / "out" / "actor.npz").resolve()
    assert s.calibration.pose_table() == {"jawOpen": [[120, 135]], "AU12": [[200, 215], [400, 410]], "mouthSmile": [[50, 60]]}
    assert s.calibration.neutral_frames == (1, 20) and s.calibration.split == ("mouthSmile",)
    assert s.calibration.align == "similarity"
    assert s.mapping.table_dict() == {"jawOpen": {"mouthClose": 0.3}, "AU12": {"cheekPuff": 1.0}}


def test_parallel_config_reads_weights_without_markers(tmp_path):
    text = """[target]
object = "Face"
[source]
weights = "llf.csv"
[solve]
strategy = "parallel"
[mapping]
gain = { jawOpen = 1.2, "*" = 0.9 }
clamp = [0.0, 0.8]
curve = "gamma:0.8"
mirror = true
neutral = [1, 30]
"""
    cfg = load_take_config(write(tmp_path, text))
    assert cfg.markers_path is None and cfg.weights_path == (tmp_path / "llf.csv").resolve()
    assert cfg.action_name == "llf"
    m = cfg.settings.mapping
    assert m.gain == (("jawOpen", 1.2), ("*", 0.9)) and m.clamp == (0.0, 0.8) and m.curve == "gamma:0.8"
    assert m.mirror and m.neutral_frames == (1, 30)


def test_examples_pca_refine_sections_are_read(tmp_path):
    text = BASE + """[solve]
strategy = "rbf"
[examples]
weights = "posed.csv"
markers = "other.csv"
frames = [10, 20]
kernel = "cubic"
rbf_smoothing = 0.1
degree = 0
n_components = 6
far = 3.0
[pca]
mode = "posed"
ica = true
[refine]
training = "train.csv"
max_iterations = 4
"""
    cfg = load_take_config(write(tmp_path, text))
    e = cfg.settings.examples
    assert cfg.examples_weights_path == (tmp_path / "posed.csv").resolve()
    assert cfg.examples_markers_path == (tmp_path / "other.csv").resolve()
    assert cfg.training_path == (tmp_path / "train.csv").resolve()
    assert (e.frames, e.kernel, e.rbf_smoothing, e.degree, e.n_components, e.far) == ((10.0, 20.0), "cubic", 0.1, 0, 6, 3.0)
    assert cfg.settings.pca.mode == "posed" and cfg.settings.pca.ica and cfg.settings.refine.max_iterations == 4


@pytest.mark.parametrize("extra, message", [
    ('[solve]\nstrategy = "calibrated"\n', r"\[calibration.markers\] strategy 'calibrated' needs \[calibration\] markers and poses"),
    ('[solve]\nstrategy = "refine"\n[calibration]\nmarkers = "c.csv"\n', r"\[calibration.poses\] strategy 'refine' needs"),
    ('[solve]\nstrategy = "calibrated"\n[calibration]\nbasis = "a.npz"\nmarkers = "c.csv"\n', r"\[calibration.basis\] give either"),
    ('[solve]\nstrategy = "linear"\n', r"\[examples.weights\] strategy 'linear' needs \[examples\] weights"),
    ('[solve]\nstrategy = "parallel"\n', r"\[source.weights\] strategy 'parallel' needs \[source\] weights"),
    ('[calibration]\nposes = { jawOpen = [135, 120] }\n', r"\[calibration.poses.jawOpen\] expected \[first, last\]"),
    ('[calibration]\nposes = { jawOpen = [1, 2] }\nsplit = ["smile"]\n', r"\[calibration.split\] names pose\(s\) not in"),
    ('[calibration]\nalign = "affine"\n', r"\[calibration.align\] expected one of"),
    ('[calibration]\nunits = "inch"\n', r"\[calibration.units\] expected one of m, cm, mm, px; got 'inch'"),
    ('[mapping]\nkeyed_by = "shape"\n', r"\[mapping.keyed_by\] expected one of source, target; got 'shape'"),
    ('[mapping]\ntable = { jawOpen = { jawOpen = "x" } }\n', r"\[mapping.table.jawOpen\] gain for 'jawOpen' must be a number"),
    ('[mapping]\ncurve = "wiggle"\n', r"\[mapping.curve\] invalid value 'wiggle'"),
    ('[mapping]\nclamp = [1, 0]\n', r"\[mapping.clamp\] invalid value"),
    ('[mapping]\nneutral = [5]\n', r"\[mapping.neutral\] expected \[first, last\]"),
    ('[examples]\nkernel = "sinc"\n', r"\[examples.kernel\] expected one of thin_plate_spline, .*; got 'sinc'"),
    ('[examples]\ndegree = 3\n', r"\[examples.degree\] expected an integer >= -1 and <= 2; got 3"),
    ('[examples]\nridge = -1\n', r"\[examples.ridge\] expected a number >= 0 and <= 1e\+06; got -1"),
    ('[pca]\nmode = "magic"\n', r"\[pca.mode\] expected one of"),
    ('[pca]\nvariance = 1.5\n', r"\[pca.variance\] expected a number > 0 and <= 1; got 1.5"),
    ('[refine]\nstiffness = -1\n', r"\[refine.stiffness\] expected a number >= 0 and <= 1e\+06; got -1"),
    ('[refine]\nsteps = 3\n', r"\[refine.steps\] unknown key"),
])
def test_strategy_section_errors_name_the_key(tmp_path, extra, message):
    with pytest.raises(ConfigError, match=message):
        load_take_config(write(tmp_path, BASE + extra))


def test_weights_source_belongs_to_parallel(tmp_path):
    with pytest.raises(ConfigError, match=r"\[source.weights\] \[source\] weights is only read by strategy 'parallel'"):
        load_take_config(write(tmp_path, BASE.replace('units = "mm"', 'weights = "w.csv"')))


def test_load_strategy_inputs_reads_the_named_files(tmp_path, sc):
    from facecap.solvers.io.csv import write_markers_csv, write_weights_csv

    write_markers_csv(tmp_path / "calib.csv", sc.calibration)
    poses = ", ".join(f"{k} = {v}" for k, v in list(sc.poses.items())[:3])
    text = BASE + f'[solve]\nstrategy = "calibrated"\n[calibration]\nmarkers = "calib.csv"\nposes = {{ {poses} }}\n'
    inputs = load_strategy_inputs(load_take_config(write(tmp_path, text)))
    assert inputs.calibration.names == sc.calibration.names and inputs.calibration.units == "mm"
    write_weights_csv(tmp_path / "posed.csv", np.array([5.0, 9.0]), ("jawOpen",), np.array([[0.2], [0.7]]))
    inputs = load_strategy_inputs(load_take_config(write(tmp_path, BASE + '[solve]\nstrategy = "pca"\n[examples]\nweights = "posed.csv"\n')))
    assert inputs.examples.names == ("jawOpen",) and inputs.examples.frames.tolist() == [5.0, 9.0]
    with pytest.raises(FacecapError, match=r"nope.csv: file not found \(config \[examples\] weights\)"):
        load_strategy_inputs(load_take_config(write(tmp_path, BASE + '[solve]\nstrategy = "pca"\n[examples]\nweights = "nope.csv"\n')))
