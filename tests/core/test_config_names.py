"""Every name a take config gives is checked against what exists with the config file, the key and a "did you
mean" (issue 40: `head_sid_R` was reported against the take file, not `[stabilise] markers`, after the .blend was
opened, with all 68 markers and no suggestion; `object = "face"` did not suggest `Face`)."""

import dataclasses

import numpy as np
import pytest

from facecap.solvers.character.shape_controls import ShapeControl
from facecap.solvers.config import load_take_config
from facecap.solvers.config.names import check_input_files, check_scene_names, check_take_names
from facecap.solvers.errors import ConfigError, ConfigProblems
from facecap.solvers.markers import MarkerSet

STABLE = ["head_forehead_C", "head_temple_L", "head_temple_R", "head_side_L", "head_side_R"]


def config(tmp_path, extra="", stable=STABLE, markers="take.csv"):
    path = tmp_path / "take.toml"
    path.write_text(f'[target]\nobject = "Face"\n[source]\nmarkers = "{markers}"\n[stabilise]\nmarkers = {stable!r}\n'
                    f'[neutral]\nframes = [1, 5]\n[output]\nweights = "out/w.csv"\n{extra}'.replace("'", '"'))
    return load_take_config(path)


def take(names):
    return MarkerSet(names=tuple(names), frames=np.arange(1, 11, dtype=float), fps=60.0,
                     positions=np.zeros((10, len(names), 3)), source="/shoot/take.csv")


def test_a_misspelt_input_file_names_the_key_and_the_file_it_meant(tmp_path):
    (tmp_path / "sample_take.csv").write_text("frame\n")
    cfg = config(tmp_path, markers="sample_tak.csv")
    with pytest.raises(ConfigError) as exc:
        check_input_files(cfg)
    assert str(exc.value) == (f"{tmp_path / 'take.toml'}: [source.markers] {tmp_path / 'sample_tak.csv'}: file not "
                              "found (did you mean 'sample_take.csv'?)")


def test_every_missing_input_file_is_named_at_once(tmp_path):
    cfg = config(tmp_path, extra='[examples]\nweights = "nowhere/posed.csv"\nframes = [1, 2]\n', markers="take.csv")
    cfg = dataclasses.replace(cfg, target_blend=tmp_path / "character.blend")
    with pytest.raises(ConfigProblems) as exc:
        check_input_files(cfg)
    lines = str(exc.value).splitlines()
    assert [line.split("] ")[0].split("[")[-1] for line in lines] == ["target.blend", "source.markers",
                                                                       "examples.weights"]
    assert lines[2].endswith(f"file not found (no folder {tmp_path / 'nowhere'})")


def test_an_unknown_stable_marker_names_the_key_and_suggests_the_marker(tmp_path):
    cfg = config(tmp_path, stable=STABLE[:-1] + ["head_sid_R"])
    names = STABLE + [f"m{i:02d}" for i in range(63)]
    with pytest.raises(ConfigError) as exc:
        check_take_names(cfg, take(names))
    message = str(exc.value)
    assert message.startswith(f"{tmp_path / 'take.toml'}: [stabilise.markers] no marker 'head_sid_R' (did you mean "
                              "'head_side_R'?) in take.csv (68 markers; `python -m facecap inspect /shoot/take.csv`")
    assert "m05" not in message  # not every marker listed
    check_take_names(config(tmp_path), take(names))  # all there: no error


def test_marker_patterns_that_match_nothing_are_named_with_their_key(tmp_path):
    cfg = config(tmp_path, extra='[solve]\nregions = { upper = { shapes = ["brow*"], markers = ["brw*"] } }\n')
    with pytest.raises(ConfigError, match=r"\[solve\.regions\.upper\] 'brw\*' matches no marker of the take"):
        check_take_names(cfg, take(STABLE + ["brow_L"]))


def test_an_object_in_the_wrong_case_is_suggested_and_the_meshes_listed(tmp_path):
    cfg = dataclasses.replace(config(tmp_path), target_object="face")
    with pytest.raises(ConfigError) as exc:
        check_scene_names(cfg, {"Face": "MESH", "Camera": "CAMERA", "Armature": "ARMATURE"}, where="character.blend")
    assert str(exc.value) == (f"{tmp_path / 'take.toml'}: [target.object] no object named 'face' in character.blend "
                              "(did you mean 'Face'?); its meshes: Face")


def test_shape_keys_bones_and_cameras_a_config_names_are_checked_once_the_character_is_open(tmp_path):
    path = tmp_path / "take.toml"
    path.write_text('[target]\nobject = "Face"\n[source]\nmarkers = "take.csv"\n[stabilise]\nmarkers = ["a", "b", "c"]\n'
                    '[neutral]\nframes = [1, 5]\n[solve]\nlocks = { tongueOt = 0.0 }\nprojection = "camera"\n'
                    'camera = "Cam"\n[output]\nweights = "out/w.csv"\nhead = "Armature:haed"\n'
                    '[controls]\njawOpn = { gain = 1.1 }\n')
    cfg = load_take_config(path)
    objects = {"Face": "MESH", "Camera": "CAMERA", "Armature": "ARMATURE"}
    with pytest.raises(ConfigProblems) as exc:
        check_scene_names(cfg, objects, ["jawOpen", "tongueOut", "browDownLeft"], lambda name: ["head", "neck"])
    lines = str(exc.value).splitlines()
    assert any("[output.head] 'Armature' has no bone 'haed' (did you mean 'head'?)" in line for line in lines)
    assert any("[solve.camera] no camera named 'Cam' in the .blend (did you mean 'Camera'?)" in line for line in lines)
    assert any("[solve.locks.tongueOt] 'tongueOt' matches no shape key of the character (did you mean 'tongueOut'?)"
               in line for line in lines)
    assert any("[controls.jawOpn] 'jawOpn' matches no shape key of the character (did you mean 'jawOpen'?)" in line
               for line in lines)
    assert len(lines) == 4


def test_controls_by_alias_or_glob_that_match_a_shape_pass(tmp_path):
    cfg = dataclasses.replace(config(tmp_path), controls={"JawOpen": ShapeControl(gain=1.1),
                                                          "brow*": ShapeControl(gain=0.9)})
    check_scene_names(cfg, {"Face": "MESH"}, ["jawOpen", "browDownLeft"])
