"""Per-shape everyday controls (issue 7): each control, their order, globs and aliases, presets."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from facecap.solvers.errors import FacecapError, InputFileError
from facecap.solvers.character.shape_controls import (ShapeControl, apply_controls, controls_from_gain_offset, curve_function,
                                            load_preset, locks_from_controls, save_preset)
from facecap.solvers.tuning.retune import apply_gain_offset, fit_gain_offset

NAMES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browInnerUp")


@pytest.fixture
def weights():
    rng = np.random.default_rng(0)
    return rng.uniform(0.0, 1.0, size=(50, len(NAMES)))


def test_defaults_change_nothing(weights):
    out = apply_controls(weights, NAMES, {"jawOpen": ShapeControl()}, fps=60)
    assert_array_equal(out, weights)
    assert out is not weights


def test_gain_offset_clamp_mute(weights):
    W0 = weights.copy()
    out = apply_controls(weights, NAMES, {
        "jawOpen": ShapeControl(gain=1.5, offset=-0.1),
        "mouthSmileLeft": ShapeControl(clamp=(0.2, 0.6)),
        "browInnerUp": ShapeControl(mute=True, gain=3.0),
    }, fps=60)
    assert_allclose(out[:, 0], 1.5 * W0[:, 0] - 0.1, atol=1e-15)
    assert_allclose(out[:, 1], np.clip(W0[:, 1], 0.2, 0.6), atol=1e-15)
    assert_array_equal(out[:, 2], W0[:, 2])
    assert_array_equal(out[:, 3], 0.0)
    assert_array_equal(weights, W0)  # input untouched


def test_curves(weights):
    x = np.array([[-0.5, 0.0, 0.25, 0.5, 1.0, 1.5]]).T
    smooth = apply_controls(x, ("a",), {"a": ShapeControl(curve="smoothstep")}, fps=60)[:, 0]
    assert_allclose(smooth, [0.0, 0.0, 0.15625, 0.5, 1.0, 1.0], atol=1e-15)
    gamma = apply_controls(x, ("a",), {"a": ShapeControl(curve="gamma:0.5")}, fps=60)[:, 0]
    assert_allclose(gamma, [-np.sqrt(0.5), 0.0, 0.5, np.sqrt(0.5), 1.0, np.sqrt(1.5)], atol=1e-15)
    with pytest.raises(FacecapError, match="unknown curve 'cubic'"):
        ShapeControl(curve="cubic")
    with pytest.raises(FacecapError, match="positive exponent"):
        ShapeControl(curve="gamma:-1")


def test_smoothing_is_zero_phase_and_keeps_nan():
    fps = 60.0
    t = np.arange(240) / fps
    clean = 0.5 + 0.3 * np.sin(2 * np.pi * 0.5 * t)
    noisy = clean + 0.05 * np.random.default_rng(1).normal(size=t.size)
    noisy[100:104] = np.nan
    out = apply_controls(noisy[:, None], ("jawOpen",), {"jawOpen": ShapeControl(smoothing=0.1)}, fps=fps)[:, 0]
    ok = np.isfinite(noisy)
    err_in = np.sqrt(np.mean((noisy[ok] - clean[ok]) ** 2))
    err_out = np.sqrt(np.mean((out[ok] - clean[ok]) ** 2))
    print(f"\nsmoothing 0.1 s: noise RMS {err_in:.4f} -> {err_out:.4f}")
    assert err_out < 0.4 * err_in
    assert np.isnan(out[100:104]).all() and np.isfinite(out[ok]).all()
    # zero phase: a symmetric pulse stays centred
    pulse = np.exp(-0.5 * ((np.arange(121) - 60) / 6.0) ** 2)[:, None]
    sm = apply_controls(pulse, ("a",), {"a": ShapeControl(smoothing=0.05)}, fps=fps)[:, 0]
    assert int(np.argmax(sm)) == 60
    assert_allclose(sm, sm[::-1], atol=1e-12)


def test_order_curve_gain_offset_smoothing_clamp_mute():
    w = np.array([[0.5], [0.8], [1.0]])
    c = ShapeControl(curve="gamma:2", gain=2.0, offset=-0.2, clamp=(0.0, 1.0))
    out = apply_controls(w, ("a",), {"a": c}, fps=30)[:, 0]
    # curve first (0.25, 0.64, 1), then gain and offset (0.3, 1.08, 1.8), then clamp
    assert_allclose(out, [0.3, 1.0, 1.0], atol=1e-15)
    # a clamp before the gain would give 2 * 1 - 0.2 = 1.8 on the last frame: the clamp is last
    muted = apply_controls(w, ("a",), {"a": ShapeControl(gain=2.0, offset=0.5, mute=True)}, fps=30)[:, 0]
    assert_array_equal(muted, 0.0)


def test_globs_aliases_and_precedence(weights):
    controls = {"mouthSmile*": ShapeControl(gain=2.0), "MouthSmile_L": ShapeControl(gain=0.5)}
    out = apply_controls(weights, NAMES, controls, fps=60)
    assert_allclose(out[:, 1], 0.5 * weights[:, 1])  # exact (alias, case-insensitive) beats the glob
    assert_allclose(out[:, 2], 2.0 * weights[:, 2])
    assert_array_equal(out[:, [0, 3]], weights[:, [0, 3]])
    with pytest.raises(FacecapError, match=r"key\(s\) \['cheek\*'\] match no shape"):
        apply_controls(weights, NAMES, {"cheek*": ShapeControl(gain=2.0)}, fps=60)
    with pytest.raises(FacecapError, match="must have shape"):
        apply_controls(weights[:, :2], NAMES, {}, fps=60)


def test_lock_passes_through_and_becomes_a_solver_lock(weights):
    controls = {"jawOpen": ShapeControl(lock=0.3, gain=5.0), "brow*": ShapeControl(gain=2.0)}
    out = apply_controls(weights, NAMES, controls, fps=60)
    assert_array_equal(out[:, 0], weights[:, 0])  # the solve holds it; controls leave it alone
    assert locks_from_controls(controls) == (("jawOpen", 0.3),)
    # resolved against the character: alias keys and globs name the shapes exactly
    resolved = locks_from_controls({"Jaw_Open": ShapeControl(lock=0.3), "mouthSmile*": ShapeControl(lock=0.0)}, NAMES)
    assert resolved == (("jawOpen", 0.3), ("mouthSmileLeft", 0.0), ("mouthSmileRight", 0.0))


def test_bad_controls_name_the_field():
    with pytest.raises(FacecapError, match="`clamp` must be"):
        ShapeControl(clamp=(1.0, 0.0))
    with pytest.raises(FacecapError, match="`smoothing` must be a number from 0 to 60 seconds"):
        ShapeControl(smoothing=-0.1)
    with pytest.raises(FacecapError, match="`gain` must be a number from -1000 to 1000"):
        ShapeControl(gain=float("nan"))
    with pytest.raises(FacecapError, match="`mute` must be true or false"):
        ShapeControl(mute="yes")


def test_controls_from_gain_offset_matches_apply_gain_offset(weights):
    truth = weights.copy()
    truth[:, 0] = 0.8 * weights[:, 0] + 0.1
    corrections = {t: np.where(np.arange(4) == 0, truth[t], np.nan) for t in (3, 10, 20, 33)}
    gain, offset = fit_gain_offset(weights, corrections)
    controls = controls_from_gain_offset(NAMES, gain, offset)
    assert list(controls) == ["jawOpen"]
    assert controls["jawOpen"].gain == pytest.approx(0.8, abs=1e-12)
    assert controls["jawOpen"].offset == pytest.approx(0.1, abs=1e-12)
    assert_allclose(apply_controls(weights, NAMES, controls, fps=60), apply_gain_offset(weights, gain, offset),
                    atol=1e-15)


def test_preset_round_trip(tmp_path, weights):
    controls = {"jawOpen": ShapeControl(gain=1.2, clamp=(0.0, 1.0), curve="smoothstep", smoothing=0.05),
                "mouth*": ShapeControl(offset=-0.05, mute=False, lock=None),
                "browInnerUp": ShapeControl(mute=True, lock=0.25)}
    path = tmp_path / "controls.json"
    save_preset(path, controls)
    assert not list(tmp_path.glob(".*tmp"))  # no temporary left behind
    loaded = load_preset(path)
    assert loaded == controls
    assert_array_equal(apply_controls(weights, NAMES, loaded, fps=60), apply_controls(weights, NAMES, controls, fps=60))
    data = json.loads(path.read_text())
    assert data["shapes"]["mouth*"] == {"offset": -0.05}  # only what differs from the defaults


@pytest.mark.parametrize("text, match", [
    ("{", r"line 1: not valid JSON"),
    ('{"format": "other"}', r"field 'format': not a shape-controls preset"),
    ('{"format": "facecap-shape-controls", "shapes": []}', r"field 'shapes': expected a table"),
    ('{"format": "facecap-shape-controls", "shapes": {"jawOpen": {"gian": 2}}}',
     r"field 'shapes.jawOpen': unknown control\(s\) \['gian'\]"),
    ('{"format": "facecap-shape-controls", "shapes": {"jawOpen": {"clamp": [1, 0]}}}',
     r"field 'shapes.jawOpen': `clamp` must be"),
    ('{"format": "facecap-shape-controls", "shapes": {"jawOpen": {"curve": "wavy"}}}',
     r"field 'shapes.jawOpen': .*unknown curve 'wavy'"),
])
def test_bad_presets_name_file_and_field(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputFileError, match=match) as info:
        load_preset(path)
    assert str(path) in str(info.value)
    with pytest.raises(InputFileError, match="preset file not found"):
        load_preset(tmp_path / "missing.json")


def test_curve_function_is_shared_with_parallel():
    from facecap.solvers.strategies import parallel

    x = np.linspace(-0.2, 1.2, 8)
    assert_allclose(parallel.parallel_curve("smoothstep")(x), curve_function("smoothstep")(x))
    with pytest.raises(FacecapError, match="parallel: unknown curve"):
        parallel.parallel_curve("nope")


def _config(tmp_path, text):
    from facecap.solvers import load_take_config
    from test_config import BASE

    path = tmp_path / "take.toml"
    path.write_text(BASE + text)
    return load_take_config(path)


def test_tuning_and_controls_sections_of_a_take_config(tmp_path):
    save_preset(tmp_path / "p.json", {"jawOpen": ShapeControl(gain=3.0), "brow*": ShapeControl(mute=True)})
    cfg = _config(tmp_path, '[tuning]\ncorrections = "c.csv"\nmu = 3\nlibrary = "lib/v.npz"\nout = "lib"\n'
                            '[controls]\npreset = "p.json"\njawOpen = { gain = 1.2, clamp = [0, 1], curve = "smoothstep", '
                            'smoothing = 0.05, mute = false, lock = 0.3 }\n"mouth*" = { offset = -0.1 }\n')
    t = cfg.tuning
    assert (t.corrections, t.mu, t.library, t.out) == (tmp_path / "c.csv", 3.0, tmp_path / "lib" / "v.npz",
                                                       tmp_path / "lib")
    assert cfg.controls["jawOpen"] == ShapeControl(gain=1.2, clamp=(0.0, 1.0), curve="smoothstep", smoothing=0.05,
                                                   lock=0.3)  # the table wins over the preset
    assert cfg.controls["brow*"] == ShapeControl(mute=True) and cfg.controls["mouth*"] == ShapeControl(offset=-0.1)
    plain = _config(tmp_path, "")
    assert plain.tuning.corrections is None and plain.tuning.mu is None and plain.controls == {}


@pytest.mark.parametrize("text, match", [
    ("[tuning]\nmu = 0\n", r"\[tuning.mu\] expected a number > 0 and <= 1e\+12; got 0"),
    ("[tuning]\nmu = \"auto\"\n", r"\[tuning.mu\] expected a number; got 'auto'"),
    ("[tuning]\nlibary = \"v.npz\"\n", r"\[tuning.libary\] unknown key"),
    ("[controls]\njawOpen = { gain = \"x\" }\n", r"\[controls.jawOpen\] `gain` must be a number from -1000 to 1000"),
    ("[controls]\njawOpen = 1.2\n", r"\[controls.jawOpen\] expected a table; got 1.2"),
    ("[controls]\npreset = \"missing.json\"\n", r"\[controls.preset\] file not found"),
])
def test_bad_tuning_and_controls_keys_are_named(tmp_path, text, match):
    from facecap.solvers import ConfigError

    with pytest.raises(ConfigError, match=match) as info:
        _config(tmp_path, text)
    assert "take.toml" in str(info.value)
