"""docs/rom.md shows the built-in ROM sheets as they are: a table per sheet, a row per pose in the order performed
(its number, label, what the performer does and the shapes it asks), and the picture ``docs-images`` renders."""

from pathlib import Path

import pytest

from facecap.solvers.rom import SHEETS

PAGE = Path(__file__).resolve().parents[2] / "docs" / "rom.md"
HEADER = "| # | pose | what the performer does | the shapes it asks (weight) |\n|---|---|---|---|\n"


def sheet_table(poses):
    """The page's table of ``poses``."""
    asks = (", ".join(f"{shape} {weight:g}" for shape, weight in p.weights) for p in poses)
    return HEADER + "".join(f"| {i} | {p.label} | {p.how} | {a} |\n" for i, (p, a) in enumerate(zip(poses, asks), 1))


@pytest.mark.parametrize("sheet", sorted(SHEETS))
def test_the_page_has_each_sheet_as_the_code_has_it(sheet):
    text = PAGE.read_text(encoding="utf-8")
    assert sheet_table(SHEETS[sheet]) in text, f"docs/rom.md: the table of {sheet} differs from solvers/rom/sheets.py"
    assert f"](images/rom_{sheet}.png)" in text


def test_the_table_says_what_each_pose_asks():
    rows = sheet_table(SHEETS["facecap-24"]).splitlines()
    assert rows[3] == ("| 2 | smile | a broad smile, cheeks lifting | mouthSmileLeft 1, mouthSmileRight 1, "
                       "cheekSquintLeft 0.4, cheekSquintRight 0.4 |")
