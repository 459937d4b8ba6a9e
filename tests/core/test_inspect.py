"""`facecap inspect`: a summary for a good file, one line and a non-zero exit for a bad one."""

import re

import numpy as np

from facecap.solvers import MarkerSet
from facecap.solvers.tools.inspect import describe, main
from facecap.solvers.io import write_markers


def test_describe_lists_markers_gaps_and_segments():
    pos = np.zeros((10, 2, 3))
    pos[2:5, 1] = np.nan
    m = MarkerSet(("brow", "lip"), np.arange(1, 11), pos, fps=30, units="mm", source="t.csv",
                  segments={"posed_happy": [(3.0, 6.0)]})
    text = describe(m)
    assert "markers:  2 (3D)" in text and "frames:   10 (1..10), 30 fps" in text and "units:    mm" in text
    assert re.search(r"lip +3 +1 +3\n", text)
    assert "posed_happy: 3..6" in text


def test_main_ok_and_bad_file(tmp_path, capsys):
    m = MarkerSet(("a",), np.arange(1, 4), np.zeros((3, 1, 3)), fps=100, units="mm")
    write_markers(tmp_path / "t.c3d", m)
    assert main([str(tmp_path / "t.c3d")]) == 0
    assert "(c3d)" in capsys.readouterr().out
    (tmp_path / "bad.csv").write_text("frame,a_x,a_y,a_z\n1,0,zero,0\n")
    assert main([str(tmp_path / "bad.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("bad.csv, line 2, field 'a_y': expected a number, got 'zero'")
