"""Nothing a take reads is ever written over, two outputs never share a path, and a write problem is one
line before any work (``preflight``); temporary files of a killed run are cleaned up; bad configs are
one line, not a traceback."""

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from facecap.facecap_addon.headless.headless import preflight
from facecap.solvers.config import load_take_config
from facecap.solvers.errors import ConfigError
from facecap.solvers.io.files import (STALE_AGE, TMP_MARK, machine_tag, remove_stale_temporaries, umask,
                                     write_text_atomic)

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


def write_config(folder, output, extra=""):
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(SAMPLES / "sample_take.csv", folder / "take.csv")
    text = (f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
            '[source]\nmarkers = "take.csv"\nunits = "mm"\nfps = 60\n'
            '[stabilise]\nmarkers = ["head_forehead_C", "head_forehead_L", "head_forehead_R"]\n'
            f'[neutral]\nframes = [1, 50]\n{extra}[output]\n{output}\n')
    path = folder / "take.toml"
    path.write_text(text)
    return path


def refused(path, match):
    with pytest.raises(ConfigError, match=match) as info:
        preflight(load_take_config(path))
    assert "\n" not in str(info.value)
    return str(info.value)


@pytest.mark.parametrize("output, clash", [
    ('weights = "take.csv"', r"\[output.weights\] is the same file as \[source.markers\]"),
    ('report = "take.toml"', r"\[output.report\] is the same file as the config itself"),
    ('report = "./sub/../take.toml"', r"\[output.report\] is the same file as the config itself"),
    (f'blend = "{SAMPLES / "character.blend"}"', r"\[output.blend\] is the same file as \[target.blend\]"),
    ('weights = "out/same.csv"\nreport = "out/same.csv"', r"\[output.weights\] and \[output.report\] are the same file"),
])
def test_an_output_that_is_an_input_or_another_output_is_refused(tmp_path, output, clash):
    path = write_config(tmp_path, output)
    before = {p: p.read_bytes() for p in (path, tmp_path / "take.csv")}
    refused(path, clash)
    assert all(p.read_bytes() == data for p, data in before.items())
    assert not (tmp_path / "out").exists()


def test_links_and_home_are_resolved_before_comparing(tmp_path, monkeypatch):
    (tmp_path / "link.csv").symlink_to(tmp_path / "take.csv")
    refused(write_config(tmp_path, 'weights = "link.csv"'), r"\[output.weights\] is the same file as \[source.markers\]")
    os.link(tmp_path / "take.csv", tmp_path / "hard.csv")
    refused(write_config(tmp_path, 'weights = "hard.csv"'), r"is the same file as \[source.markers\]")
    monkeypatch.setenv("HOME", str(tmp_path))
    refused(write_config(tmp_path, 'weights = "~/take.csv"'), r"is the same file as \[source.markers\]")


def test_calibration_and_corrections_inputs_are_protected_too(tmp_path):
    (tmp_path / "lib.npz").write_bytes(b"stored")
    extra = '[solve]\nstrategy = "calibrated"\n[calibration]\nbasis = "lib.npz"\n'
    refused(write_config(tmp_path, 'actor_basis = "lib.npz"', extra),
            r"\[output.actor_basis\] is the same file as \[calibration.basis\]")
    assert (tmp_path / "lib.npz").read_bytes() == b"stored"


@pytest.mark.parametrize("setup, output, message", [
    (lambda d: (d / "existing_dir").mkdir(), 'weights = "existing_dir"', "is a folder; a file name is needed"),
    (lambda d: (d / "afile").write_text("x"), 'weights = "afile/w.csv"', "afile is a file, not a folder"),
    (lambda d: None, 'blend = "out/' + "x" * 300 + '.blend"', "this file system allows"),
])
def test_write_locations_are_checked_before_any_work(tmp_path, setup, output, message):
    setup(tmp_path)
    refused(write_config(tmp_path, output), message)


@pytest.fixture
def read_only_folder(tmp_path):
    """A folder nobody may write into: mode 0555, and for root (who ignores modes, as CI runs) also
    immutable (``chattr +i``), which root cannot write into either."""
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    immutable = os.geteuid() == 0
    if immutable:
        chattr = shutil.which("chattr")
        if chattr is None or subprocess.run([chattr, "+i", str(folder)], capture_output=True).returncode != 0:
            pytest.skip("running as root where chattr +i is not possible: no folder root cannot write into")
    yield folder
    if immutable:
        subprocess.run([shutil.which("chattr"), "-i", str(folder)], check=True)


def test_a_read_only_folder_is_refused(tmp_path, read_only_folder):
    refused(write_config(tmp_path, 'weights = "ro/w.csv"'), "read-only")


def test_a_config_that_writes_nothing_is_refused(tmp_path):
    refused(write_config(tmp_path, ""), r"\[output\] nothing would be written")


def test_stale_temporaries_of_dead_runs_are_removed_live_ones_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    tag = machine_tag()
    dead = out / f".w.csv{TMP_MARK}{tag}.999999999.abc.csv"
    live = out / f".w.csv{TMP_MARK}{tag}.{os.getpid()}.abc.csv"
    saving = out / f".x.blend{TMP_MARK}{tag}.999999999.abc.blend@"  # Blender's own file beside a dead save
    other = out / ".w.csv.tmp"  # not of our naming: never touched
    for p in (dead, live, saving, other):
        p.write_text("partial")
    preflight(load_take_config(write_config(tmp_path, 'weights = "out/w.csv"')))
    assert not dead.exists() and not saving.exists() and live.exists() and other.exists()
    assert remove_stale_temporaries(tmp_path / "missing") == []


def test_a_temporary_of_another_machine_or_container_is_judged_by_its_age_not_its_pid(tmp_path):
    """Regression (reliability-2 #05): a run on another farm node or in another PID namespace deleted a
    live writer's temporary file because that pid was not alive *here*."""
    other_tag = "0" * 12 if machine_tag() != "0" * 12 else "1" * 12
    elsewhere = tmp_path / f".a.blend{TMP_MARK}{other_tag}.999999999.abc.blend"
    legacy = tmp_path / f".a.blend{TMP_MARK}999999999.abc.blend"  # an older facecap's untagged name
    for p in (elsewhere, legacy):
        p.write_text("being written on another node")
    assert remove_stale_temporaries(tmp_path) == []
    assert elsewhere.exists() and legacy.exists()
    later = time.time() + STALE_AGE + 60
    assert sorted(remove_stale_temporaries(tmp_path, now=later)) == sorted([elsewhere, legacy])


def test_outputs_get_the_permissions_of_new_files(tmp_path):
    write_text_atomic(tmp_path / "report.json", "{}")
    assert (tmp_path / "report.json").stat().st_mode & 0o777 == 0o666 & ~umask()
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]


@pytest.mark.parametrize("text, message", [
    ("", None),  # (the whole config after a UTF-8 BOM: fine)
    ("[clean]\none_euro = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
    ("[calibration]\nfps = " + "9" * 5000 + "\n", "not valid TOML: Exceeds the limit"),
    ("[calibration]\nfps = 99999999999999999999\n", r"\[calibration.fps\] expected a number > 0 and <= 10000"),
    ("[refine]\ntraining = \"a\\u0000b.csv\"\n", r"\[refine.training\] must not contain NUL"),
    ("[solve]\nlocks = { \"*\" = 1e308 }\n", r"\[solve.locks.\*\] expected a number between -10 and 10"),
    ("[solve]\nbounds = { jawOpen = [0, inf] }\n", r"\[solve.bounds.jawOpen\] expected \[lower, upper\]"),
])
def test_hostile_values_are_one_line(tmp_path, text, message):
    path = write_config(tmp_path, 'weights = "out/w.csv"', text)
    if message is None:
        path.write_text("\ufeff" + path.read_text(), encoding="utf-8")
        assert load_take_config(path).target_object == "Face"
        return
    with pytest.raises(ConfigError, match=message) as info:
        load_take_config(path)
    assert "\n" not in str(info.value)
