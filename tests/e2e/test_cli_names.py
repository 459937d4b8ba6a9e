"""A misspelt name in a take config stops ``retarget`` at the earliest moment it can be known, in one line naming
the config file, the key and the name it meant (issue 40): a file and a stable marker before Blender opens the
character (no ``[2/5] opening`` line, nothing written), an object and a shape key before anything is solved."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_blends" / "sample_take.toml"

pytestmark = pytest.mark.slow


def retarget(tmp_path, old, new):
    text = SAMPLE.read_text(encoding="utf-8")
    assert old in text
    text = text.replace(old, new)
    for name in ("character.blend", "sample_take.csv", "sample_tak.csv"):  # the sample's files, where they are
        text = text.replace(f'"{name}"', f'"{(ROOT / "sample_blends" / name).as_posix()}"')
    config = tmp_path / "take.toml"
    config.write_text(text.replace('"out/', f'"{tmp_path.as_posix()}/out/'))
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)], capture_output=True,
                          text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()
    return config, proc.stderr.splitlines()


@pytest.mark.parametrize("old, new, key, said, opened", [
    ('"head_side_R"]', '"head_sid_R"]', "stabilise.markers", "no marker 'head_sid_R' (did you mean 'head_side_R'?) in "
                                                              "sample_take.csv", False),
    ('markers = "sample_take.csv"', 'markers = "sample_tak.csv"', "source.markers",
     "sample_tak.csv: file not found (did you mean 'sample_take.csv'?)", False),
    ('object = "Face"', 'object = "face"', "target.object", "no object named 'face' in character.blend (did you mean "
                                                            "'Face'?); its meshes: Face", True),
    ("regularisation = 0.001", "regularisation = 0.001\nlocks = { tongueOt = 0.0 }", "solve.locks.tongueOt",
     "'tongueOt' matches no shape key of the character (did you mean 'tongueOut'?)", True),
])
def test_a_misspelt_name_stops_the_run_as_early_as_it_can_be_known(tmp_path, old, new, key, said, opened):
    """A file or a marker: before Blender opens the character; an object or a shape key: after, before the solve."""
    config, err = retarget(tmp_path, old, new)
    assert any("[2/5] opening" in line for line in err) == opened and not any("[3/5]" in line for line in err), err
    (error,) = [line for line in err if line.startswith("facecap: error: ")]
    if opened:
        assert error == f"facecap: error: {config}: [{key}] {said}", error
    else:
        assert error.startswith(f"facecap: error: {config}: [{key}] ") and said in error, error


def test_what_reading_found_is_said_before_blender_opens_the_character(tmp_path):
    """Issue 40: the guessed units and the assumed frame rate were said after [5/5], when it was too late to stop."""
    text = SAMPLE.read_text(encoding="utf-8").replace('units = "mm"\n', "").replace("fps = 60\n", "")
    for name in ("character.blend", "sample_take.csv"):
        text = text.replace(f'"{name}"', f'"{(ROOT / "sample_blends" / name).as_posix()}"')
    config = tmp_path / "take.toml"
    config.write_text(text.replace('"out/', f'"{tmp_path.as_posix()}/out/'))
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)], capture_output=True,
                          text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    err = proc.stderr.splitlines()
    units = next(i for i, line in enumerate(err) if line.startswith("facecap: warning: units not given: guessed mm"))
    rate = next(i for i, line in enumerate(err) if line.startswith("facecap: warning: frame rate assumed: 60 fps"))
    opening = next(i for i, line in enumerate(err) if "[2/5] opening" in line)
    assert max(units, rate) < opening, err
    assert sum("units not given" in line for line in err) == 1  # said once, not again at the end
