"""Take configs: relative paths, defaults, and errors that name the key."""

import pytest

from facecap.solvers import ConfigError, load_take_config

BASE = """
[target]
blend = "char.blend"
object = "Face"
[source]
markers = "takes/t1.csv"
units = "mm"
fps = 120
[stabilise]
markers = ["a", "b", "c"]
[neutral]
frames = [1, 30]
"""


def write(tmp_path, text):
    path = tmp_path / "take.toml"
    path.write_text(text)
    return path


def test_paths_resolve_against_the_config_folder(tmp_path):
    cfg = load_take_config(write(tmp_path, BASE + '[output]\nweights = "out/w.csv"\n'))
    assert cfg.markers_path == (tmp_path / "takes" / "t1.csv").resolve()
    assert cfg.target_blend == (tmp_path / "char.blend").resolve()
    assert cfg.output_weights == (tmp_path / "out" / "w.csv").resolve()
    assert cfg.output_blend is None
    assert cfg.fps == 120 and cfg.units == "mm" and cfg.action_name == "t1"
    assert cfg.settings.stable_markers == ("a", "b", "c") and cfg.settings.neutral_frames == (1, 30)


def test_solve_options_are_read(tmp_path):
    text = BASE + "[solve]\nregularisation = 0.01\nsparsity = 0\nsymmetry = 0.5\nsmoothing = [0.0, 0.2]\n"
    text += "[output]\n"
    s = load_take_config(write(tmp_path, text.replace("[neutral]", "[neutral]"))).settings
    assert (s.regularisation, s.sparsity, s.symmetry, s.smoothing) == (0.01, 0, 0.5, (0.0, 0.2))


@pytest.mark.parametrize(
    "extra, message",
    [
        ("[solve]\nstrategy = \"magic\"\n", r"\[solve.strategy\] expected one of semantic, geometric, calibrated, .*; got 'magic'"),
        ("[solve]\nregularisation = -1\n", r"\[solve.regularisation\] expected a number >= 0 and <= 100; got -1"),
        ("[solve]\nsmoothing = [1]\n", r"\[solve.smoothing\] expected a list of 2 numbers"),
        ("[solve]\nregularistion = 1\n", r"\[solve.regularistion\] unknown key"),
        ("[sovle]\n", r"unknown section \[sovle\]"),
        ("[output]\nblend = 3\n", r"\[output.blend\] expected a file name; got 3"),
    ],
)
def test_errors_name_the_key(tmp_path, extra, message):
    with pytest.raises(ConfigError, match=message):
        load_take_config(write(tmp_path, BASE + extra))


def test_missing_required_key_and_file(tmp_path):
    with pytest.raises(ConfigError, match=r"\[neutral.frames\] missing required key"):
        load_take_config(write(tmp_path, BASE.replace("[neutral]\nframes = [1, 30]\n", "")))
    with pytest.raises(ConfigError, match="config file not found"):
        load_take_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_take_config(write(tmp_path, "[target\n"))


def test_bounds_locks_regions(tmp_path):
    text = BASE + """
[solve]
bounds = { "mouth*" = [0.0, 0.8], jawOpen = [0, 0.5] }
locks = { tongueOut = 0.0 }
[solve.regions.upper]
shapes = ["brow*", "eye*"]
markers = ["brow*", "eye*", "head_*"]
[solve.regions.lower]
shapes = ["*"]
markers = ["*"]
"""
    s = load_take_config(write(tmp_path, text)).settings
    assert s.bounds == (("mouth*", 0.0, 0.8), ("jawOpen", 0.0, 0.5))
    assert s.locks == (("tongueOut", 0.0),)
    assert [r.name for r in s.regions] == ["upper", "lower"]
    assert s.regions[0].markers == ("brow*", "eye*", "head_*")


@pytest.mark.parametrize(
    "extra, message",
    [
        ('[solve]\nbounds = { jawOpen = [1, 0] }\n', r"\[solve.bounds.jawOpen\] expected \[lower, upper\]"),
        ('[solve]\nlocks = { jawOpen = "x" }\n', r"\[solve.locks.jawOpen\] expected a number"),
        ('[solve.regions.upper]\nshapes = ["brow*"]\n', r"\[solve.regions.upper\] expected a table"),
    ],
)
def test_shape_option_errors(tmp_path, extra, message):
    with pytest.raises(ConfigError, match=message):
        load_take_config(write(tmp_path, BASE + extra))


def test_source_and_clean_sections(tmp_path):
    text = BASE.replace('units = "mm"', 'units = "bu"\nunit_scale = 0.046\nup_axis = "Y"') + "[clean]\nfill_spline = 6\none_euro = [1.0, 0.01, 1.0]\n"
    cfg = load_take_config(write(tmp_path, text))
    assert cfg.units == "bu" and cfg.read_options == {"unit_scale": 0.046, "up_axis": "Y"}
    assert cfg.clean.fill_spline == 6 and cfg.clean.one_euro == (1.0, 0.01, 1.0)
    with pytest.raises(ConfigError, match=r"\[source.unit_scale\] Blender units need unit_scale"):
        load_take_config(write(tmp_path, BASE.replace('units = "mm"', 'units = "bu"')))
    with pytest.raises(ConfigError, match=r"\[clean.one_euro\] expected"):
        load_take_config(write(tmp_path, BASE + "[clean]\none_euro = [1]\n"))
    with pytest.raises(ConfigError, match=r"\[clean.lowpass_hz\] expected a number > 0 and <= 5000; got -3"):
        load_take_config(write(tmp_path, BASE + "[clean]\nlowpass_hz = -3\n"))
    with pytest.raises(ConfigError, match=r"\[clean\] choose one filter"):
        load_take_config(write(tmp_path, BASE + "[clean]\nlowpass_hz = 12\none_euro = [1.0, 0.01, 1.0]\n"))
