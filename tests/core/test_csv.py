"""Wide marker CSV: formats users write, and clear errors for what they get wrong."""

import numpy as np
import pytest

from facecap.solvers import FacecapError, InputFileError, MarkerSet, read_markers_csv, write_markers_csv
from facecap.solvers.io.csv import read_weights_csv, write_weights_csv


def write(tmp_path, text, name="take.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reads_comma_file_with_gaps(tmp_path):
    path = write(tmp_path, "frame,a_x,a_y,a_z,b_x,b_y,b_z\n1,1,2,3,4,5,6\n2,1.5,,3,NaN,5,6\n3,NA,NA,NA,4,5,6\n")
    m = read_markers_csv(path, units="mm", fps=30)
    assert m.names == ("a", "b")
    assert m.positions.shape == (3, 2, 3)
    np.testing.assert_array_equal(m.frames, [1, 2, 3])
    assert m.units == "mm" and m.fps == 30
    # A sample with any missing coordinate is a gap as a whole.
    assert m.visible.tolist() == [[True, True], [False, False], [False, True]]
    np.testing.assert_allclose(m.to_units("m").positions[0, 1], [0.004, 0.005, 0.006])


def test_reads_semicolon_file_and_ignores_text_columns_with_warning(tmp_path):
    path = write(tmp_path, "Frame;A7_x;A7_y;A7_z;Stimulustype\n1;0.1;0.2;0.3;posed_neutral\n2;0.1;0.2;0.4;\n")
    with pytest.warns(UserWarning, match="Stimulustype"):
        m = read_markers_csv(path)
    assert m.names == ("A7",)
    assert m.positions[1, 0, 2] == pytest.approx(0.4)


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(20, 4, 3))
    pos[3, 1] = np.nan
    m = MarkerSet(("p", "q", "r", "s"), np.arange(1, 21), pos, fps=60, units="mm")
    write_markers_csv(tmp_path / "rt.csv", m)
    back = read_markers_csv(tmp_path / "rt.csv", units="mm")
    assert back.names == m.names
    np.testing.assert_allclose(back.positions, m.positions, rtol=1e-8, equal_nan=True)


def test_weights_round_trip(tmp_path):
    w = np.array([[0.0, 1.0], [0.25, np.nan]])
    write_weights_csv(tmp_path / "w.csv", [1, 2], ["jawOpen", "eyeBlinkLeft"], w)
    frames, names, back = read_weights_csv(tmp_path / "w.csv")
    assert names == ("jawOpen", "eyeBlinkLeft")
    np.testing.assert_allclose(back, w, equal_nan=True)
    np.testing.assert_array_equal(frames, [1, 2])


@pytest.mark.parametrize(
    "text, match",
    [
        ("frame,a_x,a_y,a_z\n1,0,0,0\n2,0,x,0\n", r"take\.csv, line 3, field 'a_y': expected a number, got 'x'"),
        ("frame,a_x,a_y,a_z\n1,0,0,0\n2,0,0\n", r"take\.csv, line 3: 3 fields but the header has 4"),
        ("frame,a_x,a_y,a_z\n", r"take\.csv, line 1: no data rows"),
        ("", r"take\.csv, line 1: empty file"),
        ("time,a_x,a_y,a_z\n1,0,0,0\n", r"take\.csv, line 1: no frame column"),
        ("frame,a_x,a_y\n1,0,0\n", None),  # 2D is fine
        ("frame,a_x,a_y,a_z,b_x,b_y\n1,0,0,0,0,0\n", r"marker 'b' lacks column\(s\) \['b_z'\]"),
        ("frame,a_x,a_y,a_z,a_x\n1,0,0,0,0\n", r"line 1: duplicate columns \['a_x'\]"),
        ("frame,label\n1,hello\n", r"no marker columns"),
        ("frame,a_x,a_y,a_z\n2,0,0,0\n1,0,0,0\n", r"line 3, field 'frame': frame numbers must increase"),
        ("frame,a_x,a_y,a_z\n1,0,0,0\n,0,0,0\n", r"line 3, field 'frame': missing frame number"),
    ],
)
def test_bad_csv_names_file_line_and_field(tmp_path, text, match):
    path = write(tmp_path, text)
    if match is None:
        assert read_markers_csv(path).dim == 2
        return
    with pytest.raises(InputFileError, match=match):
        read_markers_csv(path)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(InputFileError, match="nope.csv: file not found"):
        read_markers_csv(tmp_path / "nope.csv")
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(InputFileError, match="bin.csv: not a text file"):
        read_markers_csv(tmp_path / "bin.csv")


def test_markerset_validation():
    with pytest.raises(FacecapError, match="duplicate marker names"):
        MarkerSet(("a", "a"), [1], np.zeros((1, 2, 3)))
    with pytest.raises(FacecapError, match="shape"):
        MarkerSet(("a",), [1], np.zeros((1, 3)))
    with pytest.raises(FacecapError, match="increase strictly"):
        MarkerSet(("a",), [2, 1], np.zeros((2, 1, 3)))
    with pytest.raises(FacecapError, match="unknown marker"):
        MarkerSet(("a",), [1], np.zeros((1, 1, 3)), source="t.csv").index(["b"])


def test_existing_output_is_replaced_atomically_only_on_success(tmp_path):
    target = tmp_path / "w.csv"
    target.write_text("precious")
    with pytest.raises(FacecapError, match="shape"):
        write_weights_csv(target, [1, 2], ["a"], np.zeros((1, 1)))
    bad = np.array([[0.5], ["x"]], dtype=object)  # fails on the second row, mid-write
    with pytest.raises(TypeError):
        write_weights_csv(target, [1, 2], ["a"], bad)
    assert target.read_text() == "precious"
    assert list(tmp_path.iterdir()) == [target]


def test_row_of_empty_cells_is_skipped_by_every_reader(tmp_path):
    # numpy's parser (taken for files with a text column) once read ",,,," as a row of gaps and
    # reported a missing frame number on the wrong line; the cell-by-cell reader skips it.
    path = write(tmp_path, "frame,a_x,a_y,a_z,label\n1,0,0,0,x\n,,,,\n2,0,1,0,y\n")
    with pytest.warns(UserWarning, match="label"):
        m = read_markers_csv(path)
    np.testing.assert_array_equal(m.frames, [1, 2])
    assert m.positions[1, 0, 1] == 1.0

