"""Library versions on disk (atomic, never overwritten) and the corrections CSV (issue 7)."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from facecap.solvers.character.basis import Basis
from facecap.solvers.errors import InputFileError
from facecap.solvers.tuning.store import list_versions, load_version, read_corrections_csv, save_version
from facecap.solvers.strategies.options import ExamplePairs
from facecap.solvers.tuning.take import LibraryVersion

SHAPES = ("jawOpen", "mouthSmileLeft", "eyeBlinkLeft")


def _version(name="calibrated-00000001+tune8f-abcdef12", parent="calibrated-00000001", scale=1.0, created="2026-01-01T00:00:00+00:00"):
    rng = np.random.default_rng(0)
    basis = Basis(SHAPES, ("m0", "m1", "m2", "m3"), rng.normal(size=(4, 3)), scale * rng.normal(size=(3, 4, 3)))
    return LibraryVersion(name, parent, "calibrated", "actor_basis", basis, created,
                          {"corrected_rmse_before": 0.1, "corrected_rmse_after": 0.02, "mu": None}, SHAPES)


def test_save_load_round_trip(tmp_path):
    v = _version()
    path = save_version(v, tmp_path / "lib")
    assert path == tmp_path / "lib" / "calibrated-00000001+tune8f-abcdef12.npz"
    back = load_version(path)
    assert (back.name, back.parent, back.strategy, back.kind, back.created, back.shapes) == \
        (v.name, v.parent, v.strategy, v.kind, v.created, v.shapes)
    assert_array_equal(back.payload.deltas, v.payload.deltas)
    assert back.summary == {"corrected_rmse_before": 0.1, "corrected_rmse_after": 0.02, "mu": None}
    ex = LibraryVersion("linear-1+tune2f-2", "linear-1", "linear", "examples",
                        ExamplePairs(np.array([5.0, 9.0]), np.eye(2, 3), SHAPES), "t", {}, SHAPES)
    back = load_version(save_version(ex, tmp_path))
    assert_array_equal(back.payload.frames, [5.0, 9.0]) and back.payload.names == SHAPES
    assert back.payload.markers is None


def test_never_overwrites_and_leaves_no_temporary(tmp_path):
    first = save_version(_version(scale=1.0), tmp_path)
    before = first.read_bytes()
    second = save_version(_version(scale=2.0), tmp_path)
    third = save_version(_version(scale=3.0), first)  # an explicit path that exists
    assert second.name == "calibrated-00000001+tune8f-abcdef12-2.npz"
    assert third.name == "calibrated-00000001+tune8f-abcdef12-3.npz"
    assert first.read_bytes() == before
    assert load_version(third).payload.deltas[0, 0, 0] == pytest.approx(3.0 * _version().payload.deltas[0, 0, 0])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([first.name, second.name, third.name])


def test_list_versions_oldest_first_skips_other_files(tmp_path):
    save_version(_version(name="b", created="2026-01-02T00:00:00+00:00"), tmp_path)
    save_version(_version(name="a", created="2026-01-03T00:00:00+00:00"), tmp_path)
    save_version(_version(name="c", parent="", created="2026-01-01T00:00:00+00:00"), tmp_path)
    np.savez(tmp_path / "not_a_version.npz", x=np.zeros(3))
    assert [v.name for _, v in list_versions(tmp_path)] == ["c", "b", "a"]
    with pytest.raises(InputFileError, match="library folder not found"):
        list_versions(tmp_path / "missing")


def test_load_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    with pytest.raises(InputFileError, match=r"bad\.npz: not a library version"):
        load_version(bad)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputFileError, match=r"other\.npz: library version: missing array 'format'"):
        load_version(tmp_path / "other.npz")
    with pytest.raises(InputFileError, match="library version file not found"):
        load_version(tmp_path / "nope.npz")


def test_corrections_csv(tmp_path):
    path = tmp_path / "corrections.csv"
    path.write_text("frame, JawOpen ,mouth_smile_L,eyeBlinkLeft\n"
                    "120,0.5,,0.25\n"
                    "\n"
                    "200,,0.75,\n"
                    "300,,,\n")
    got = read_corrections_csv(path, SHAPES)
    assert got == {120.0: {"jawOpen": 0.5, "eyeBlinkLeft": 0.25}, 200.0: {"mouthSmileLeft": 0.75}}
    raw = read_corrections_csv(path)  # without a character: the header's own names
    assert raw[120.0] == {"JawOpen": 0.5, "eyeBlinkLeft": 0.25}


@pytest.mark.parametrize("text, match", [
    ("", r"empty file"),
    ("time,jawOpen\n1,0.5\n", r"line 1, field 'column 1': the first column must be 'frame'"),
    ("frame,jawOpen,cheekPuff\n1,0.5,0.1\n", r"line 1, field 'column 3': shape 'cheekPuff' is not on the character"),
    ("frame,jawOpen,JAW_OPEN\n1,0.5,0.1\n", r"line 1, field 'column 3': 'JAW_OPEN' names the same shape as column 2"),
    ("frame,jawOpen\n1,0.5\n2,abc\n", r"line 3, field 'column 2': value of jawOpen must be a number; got 'abc'"),
    ("frame,jawOpen\n1,0.5\n1,0.6\n", r"line 3, field 'column 1': frame 1 appears twice"),
    ("frame,jawOpen\n1,0.5,0.2\n", r"line 2: 3 cells; the header has 2"),
    ("frame,jawOpen\n,0.5\n", r"line 2, field 'column 1': missing frame number"),
    ("frame,jawOpen\n1,nan\n", r"line 2, field 'column 2': value of jawOpen must be finite"),
    ("frame,jawOpen\n1,\n", r"no corrected value in any row"),
])
def test_corrections_csv_errors_name_line_and_column(tmp_path, text, match):
    path = tmp_path / "c.csv"
    path.write_text(text)
    with pytest.raises(InputFileError, match=match) as info:
        read_corrections_csv(path, SHAPES)
    assert str(path) in str(info.value)
