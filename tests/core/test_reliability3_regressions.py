"""Regression tests named after the defects of the third reliability campaign (``shared/bugs/reliability-3``) that
need no Blender: the template command's outputs, archives and downloads (01-06) and CSV cells a spreadsheet would
run (09). (Signals, Blender's temporary folder and rigs whose drivers cannot run: ``tests/e2e/test_reliability3_cli.py``.)"""

import csv
from types import SimpleNamespace

import numpy as np

from facecap.solvers.io import import_markers, read_weights, write_markers
from facecap.solvers.io.csv import read_weights_csv
from facecap.solvers.io.csv_write import formula_safe, text_of_cell, write_weights_csv
from facecap.solvers.markers import MarkerSet
from facecap.solvers.tools.batch_summary import new_record, to_csv
from facecap.solvers.tuning.store import read_corrections_csv

FORMULAS = ('=HYPERLINK("http://example.invalid","click")', "+1+1", "@SUM(1)", "-1+1", "\tx", "'=quoted", "''",
            "'plain", "plain", "a=b")


def formulas(path_or_rows):
    """The cells a spreadsheet would run: text (not a number) starting with = + - @ or a tab."""
    if not isinstance(path_or_rows, list):
        with open(path_or_rows, newline="", encoding="utf-8") as fh:
            path_or_rows = list(csv.reader(fh))
    out = []
    for cell in (c for row in path_or_rows for c in row if c[:1] and c[:1] in "=+-@\t"):
        try:
            float(cell)
        except ValueError:
            out.append(cell)
    return out


def test_09_formula_like_names_are_text_in_every_csv_and_read_back_as_written(tmp_path):
    """A spreadsheet runs a cell that starts with = + - @ (or a tab): facecap writes it after a ', as OWASP
    advises, and its own readers give back the original name (weights, markers, corrections)."""
    for name in FORMULAS:
        assert text_of_cell(formula_safe(name)) == name
    rng = np.random.default_rng(9)
    names = list(FORMULAS)
    write_weights_csv(tmp_path / "w.csv", np.arange(1, 4), names, rng.random((3, len(names))))
    assert not formulas(tmp_path / "w.csv")
    assert read_weights_csv(tmp_path / "w.csv")[1] == tuple(names)
    assert tuple(read_weights(tmp_path / "w.csv").names) == tuple(names)
    corrections = read_corrections_csv(tmp_path / "w.csv")
    assert set(corrections[1.0]) == set(names)
    markers = [n for n in names if n.strip() == n]
    m = MarkerSet(tuple(markers), np.arange(1, 4), rng.normal(size=(3, len(markers), 3)), fps=60, units="mm",
                  segments={"=cmd|' /C calc'!A0": [(1.0, 2.0)]})
    write_markers(tmp_path / "m.csv", m)
    assert not formulas(tmp_path / "m.csv")
    back = import_markers(tmp_path / "m.csv").markers
    assert back.names == m.names and list(back.segments) == list(m.segments)
    np.testing.assert_allclose(back.positions, m.positions, rtol=1e-6)


def test_09_the_batch_summary_csv_holds_no_formula(tmp_path):
    take = SimpleNamespace(name="=1+1", path=tmp_path / "=1+1.toml", listed_by=None)
    record = new_record(take, status="failed", error="-bad: @it")
    text = to_csv([record])
    row = next(csv.reader(text.splitlines()[1:]))
    assert row[0] == "'=1+1" and row[2] == "'-bad: @it" and not formulas([row])
