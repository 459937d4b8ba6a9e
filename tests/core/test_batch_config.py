"""The takes of a batch: batch files with [defaults], folders, checks across takes, and what --resume hashes."""

import json
import os
from pathlib import Path

import pytest

from facecap.solvers.config import load_take_config
from facecap.solvers.config.batch import InputDigests, collect_takes, config_digest, take_names
from facecap.solvers.config.paths import check_across_takes
from facecap.solvers.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
STABLE = ["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R"]


def write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def take_text(markers="take.csv", extra=""):
    return f'[source]\nmarkers = "{markers}"\n' + extra


BATCH = f"""
[batch]
takes = ["takes/"]

[defaults.target]
blend = "rig/character.blend"
object = "Face"

[defaults.source]
units = "mm"
fps = 60

[defaults.stabilise]
markers = {json.dumps(STABLE)}

[defaults.neutral]
frames = [1, 50]

[defaults.solve]
regularisation = 0.002

[defaults.output]
weights = "out/{{take}}.csv"
report = "out/{{take}}/report.json"
"""


@pytest.fixture
def shoot(tmp_path):
    write(tmp_path / "batch.toml", BATCH)
    write(tmp_path / "takes" / "take01.toml", take_text())
    own = "[solve]\nregularisation = 0.01\n[neutral]\nframes = [5, 20]\n"
    write(tmp_path / "takes" / "take02.toml", take_text(extra=own))
    return tmp_path


def test_a_batch_file_merges_its_defaults_under_each_take(shoot):
    takes = collect_takes([shoot / "batch.toml"])
    assert [t.name for t in takes] == ["take01", "take02"]
    assert all(t.error is None and t.listed_by == shoot / "batch.toml" for t in takes)
    first, second = (load_take_config(t.path, t.data) for t in takes)
    # defaults' paths resolve against the batch file, the take's own against the take
    assert first.target_blend == shoot / "rig" / "character.blend"
    assert first.markers_path == shoot / "takes" / "take.csv"
    # {take} in the defaults' [output] values
    assert first.output_weights == shoot / "out" / "take01.csv"
    assert second.output_report == shoot / "out" / "take02" / "report.json"
    # the take's own keys win, key by key inside a section; the rest of the section stays
    assert first.settings.regularisation == pytest.approx(0.002)
    assert second.settings.regularisation == pytest.approx(0.01)
    assert second.settings.neutral_frames == (5, 20)
    assert second.units == "mm" and second.fps == 60.0 and second.target_object == "Face"


def test_a_folder_with_a_batch_file_means_the_batch_file(shoot):
    write(shoot / "takes" / "batch.toml", '[batch]\ntakes = ["take01.toml"]\n[defaults.target]\nobject = "Other"\n')
    takes = collect_takes([shoot / "takes"])
    assert [t.name for t in takes] == ["take01"]
    assert takes[0].data["target"] == {"object": "Other"}


def test_a_folder_without_one_is_every_toml_in_it(shoot):
    takes = collect_takes([shoot / "takes"])
    assert [t.path.name for t in takes] == ["take01.toml", "take02.toml"]
    assert all(t.listed_by is None and "target" not in t.data for t in takes)


def test_a_folder_of_take_folders_is_every_toml_one_level_down(tmp_path):
    """``batch shoot/`` with shoot/take51/take51.toml: the take folders are looked into (it said only
    "no take configs found" before)."""
    for name in ("take51", "take52"):
        write(tmp_path / "shoot" / name / f"{name}.toml", '[source]\nmarkers = "take.csv"\n')
    (tmp_path / "shoot" / "notes").mkdir()
    takes = collect_takes([tmp_path / "shoot"])
    assert [t.name for t in takes] == ["take51", "take52"]
    assert collect_takes([tmp_path / "shoot" / "notes"]) == []


def test_a_missing_or_unreadable_take_is_that_takes_error_not_the_batch(shoot):
    write(shoot / "takes" / "take03.toml", "[source\nmarkers = 1\n")
    takes = collect_takes([shoot / "takes" / "take01.toml", shoot / "missing.toml", shoot / "takes" / "take03.toml"])
    assert [t.error is None for t in takes] == [True, False, False]
    assert "config file not found" in takes[1].error
    assert "not valid TOML" in takes[2].error


@pytest.mark.parametrize("text, key, message", [
    ('[batch]\ntakes = ["takes/"]\n[defaults.solve]\nregularisaton = 1.0\n', "defaults.solve.regularisaton",
     "unknown key (did you mean 'regularisation'?); known keys: strategy, regularisation"),
    ('[batch]\ntakes = ["takes/"]\n[defaults.source]\nunits = "inch"\n', "defaults.source.units",
     "expected one of m, cm, mm, bu, px; got 'inch'"),
    ('[batch]\ntakes = ["takes/"]\n[defaults.source]\nmarkers = "{take}.csv"\n', "defaults.source.markers",
     "{take} is only filled in [defaults.output]"),
    ('[batch]\ntakes = []\n', "batch.takes", "expected a list of take configs"),
    ('[batch]\ntakes = ["takes/"]\njobs = 2\n', "batch.jobs", "unknown key; known keys: takes"),
    ('[batch]\ntakes = ["nothing/*.toml"]\n', "batch.takes", "'nothing/*.toml' matches no .toml file"),
])
def test_a_bad_batch_file_names_its_key(shoot, text, key, message):
    write(shoot / "batch.toml", text)
    with pytest.raises(ConfigError) as err:
        collect_takes([shoot / "batch.toml"])
    assert f"[{key}]" in str(err.value) and message in str(err.value) and str(shoot / "batch.toml") in str(err.value)


def test_a_take_reached_twice_or_nested_batch_files_are_refused(shoot):
    with pytest.raises(ConfigError, match="listed twice"):
        collect_takes([shoot / "batch.toml", shoot / "takes" / "take01.toml"])
    write(shoot / "more" / "batch.toml", '[batch]\ntakes = ["../batch.toml"]\n')
    with pytest.raises(ConfigError, match="batch files do not nest"):
        collect_takes([shoot / "more" / "batch.toml"])
    with pytest.raises(ConfigError, match="no such take config, folder or batch file"):
        collect_takes([shoot / "nowhere"])


def test_take_names_are_unique():
    paths = [Path("/s/day1/take01.toml"), Path("/s/day2/take01.toml"), Path("/s/day2/take02.toml")]
    assert take_names(paths) == ["day1/take01", "day2/take01", "take02"]


def full_take(folder, name, weights, markers="take.csv", extra=""):
    return write(folder / f"{name}.toml", f"""
[target]
blend = "{SAMPLES / 'character.blend'}"
object = "Face"
[source]
markers = "{markers}"
[stabilise]
markers = {json.dumps(STABLE)}
[neutral]
frames = [1, 50]
[output]
weights = "{weights}"
{extra}""")


def test_two_takes_writing_one_file_are_refused_naming_both(tmp_path):
    a = load_take_config(full_take(tmp_path, "a", "out/w.csv"))
    b = load_take_config(full_take(tmp_path / "sub", "b", "../out/./w.csv"))
    c = load_take_config(full_take(tmp_path, "c", "out/c.csv"))
    check_across_takes([a, c])
    with pytest.raises(ConfigError) as err:
        check_across_takes([a, c, b], names=["a", "c", "b"])
    assert "takes 'a' [output.weights] and 'b' [output.weights] write the same file" in str(err.value)


def test_a_take_reading_what_another_writes_is_refused(tmp_path):
    a = load_take_config(full_take(tmp_path, "a", "out/a.csv", extra='blend = "out/a.blend"\n'))
    b = load_take_config(full_take(tmp_path, "b", "out/b.csv", markers="out/a.csv"))
    with pytest.raises(ConfigError, match=r"take 'b' reads \[source.markers\] .* which take 'a' writes as "
                                          r"\[output.weights\]"):
        check_across_takes([a, b], names=["a", "b"])


def test_an_existing_output_is_compared_by_identity(tmp_path):
    (tmp_path / "out").mkdir()
    write(tmp_path / "out" / "a.csv", "x")
    os.link(tmp_path / "out" / "a.csv", tmp_path / "out" / "hard.csv")
    a = load_take_config(full_take(tmp_path, "a", "out/a.csv"))
    b = load_take_config(full_take(tmp_path, "b", "out/hard.csv"))
    with pytest.raises(ConfigError, match="write the same file"):
        check_across_takes([a, b], names=["a", "b"])


@pytest.mark.parametrize("key, name", [("gltf", "take.gltf"), ("fbx", "take.obj")])
def test_export_outputs_must_have_their_formats_suffix(tmp_path, key, name):
    with pytest.raises(ConfigError, match=rf"\[output.{key}\] expected a file name ending in"):
        load_take_config(full_take(tmp_path, "a", "out/a.csv", extra=f'{key} = "{name}"\n'))


def test_export_outputs_are_checked_against_the_other_outputs(tmp_path):
    from facecap.solvers.config.paths import check_outputs

    config = load_take_config(full_take(tmp_path, "a", "out/a.csv", extra='gltf = "out/a.glb"\nfbx = "out/a.fbx"\n'))
    assert config.output_gltf == tmp_path / "out" / "a.glb" and config.output_fbx == tmp_path / "out" / "a.fbx"
    check_outputs(config)
    clash = load_take_config(full_take(tmp_path, "b", "out/b.glb", extra='gltf = "out/b.glb"\n'))
    with pytest.raises(ConfigError, match=r"\[output.weights\] and \[output.gltf\] are the same file"):
        check_outputs(clash)


def test_digests_follow_the_inputs_and_the_effective_config(shoot):
    write(shoot / "takes" / "take.csv", "frame,a_x\n1,0\n")
    write(shoot / "rig" / "character.blend", "not really a blend")
    takes = collect_takes([shoot / "batch.toml"])
    configs = [load_take_config(t.path, t.data) for t in takes]
    first = InputDigests().of_config(configs[0])
    assert set(first) == {"[source.markers]", "[target.blend]"}
    assert InputDigests().of_config(configs[0]) == first
    digest = config_digest(takes[0])
    assert config_digest(collect_takes([shoot / "batch.toml"])[0]) == digest
    # a change to an input, or to the defaults, changes the digest
    write(shoot / "takes" / "take.csv", "frame,a_x\n1,1\n")
    assert InputDigests().of_config(configs[0])["[source.markers]"] != first["[source.markers]"]
    write(shoot / "batch.toml", BATCH.replace("0.002", "0.003"))
    assert config_digest(collect_takes([shoot / "batch.toml"])[0]) != digest
