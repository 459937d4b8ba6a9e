"""A batch's index page after ``--resume``: takes that were up to date count as done (not "0 solved, 3
not" with every row red), their notes are informational, not error-red; failures stay red."""

import re

from facecap.solvers.tools.report import TakeSummary, write_batch_index


def rows(html):
    return re.findall(r'<tr class="(\w+)">(.*?)</tr>', html, re.S)


def test_up_to_date_takes_count_as_done_and_their_notes_are_not_errors(tmp_path):
    note = "up to date: inputs, config and outputs unchanged since 2026-11-01T10:00:00Z"
    records = [TakeSummary(take=f"take{i}", status="skipped", frames=720, residual_mm=[0.4] * 720, message=note,
                           strategy="geometric") for i in range(3)]
    html = write_batch_index(tmp_path / "index.html", records)["path"].read_text()
    summary = re.search(r'<p class="summary">(.*?)</p>', html).group(1)
    assert summary == "3 take(s): 0 solved, 3 up to date (solved before, unchanged); 2,160 frames with weights."
    found = rows(html)
    assert [kind for kind, _ in found] == ["current"] * 3
    for _, cells in found:
        assert '<span class="current">up to date</span>' in cells
        assert f'<span class="info">{note}</span>' in cells and "bad" not in cells


def test_failures_stay_red_beside_solved_and_current_takes(tmp_path):
    records = [TakeSummary(take="a", status="ok", frames=100, warnings=2),
               TakeSummary(take="b", status="skipped", frames=50, message="up to date"),
               TakeSummary(take="c", status="failed", message="c.csv, line 7: expected a number")]
    html = write_batch_index(tmp_path / "index.html", records)["path"].read_text()
    assert [kind for kind, _ in rows(html)] == ["ok", "current", "bad"]
    assert '<span class="bad">c.csv, line 7: expected a number</span>' in html
    assert '<span class="info">2 warning(s)</span>' in html
    assert "1 solved, 1 up to date (solved before, unchanged), 1 not solved; 150 frames" in html
