"""The batch summary a TD reads and --resume reads back, and the progress display."""

import csv
import io
import json
from pathlib import Path

import pytest

from facecap.facecap_addon.batch.batch_progress import Progress
from facecap.solvers.config.batch import BatchTake
from facecap.solvers.errors import FacecapError
from facecap.solvers.tools.batch_summary import CSV_COLUMNS, Summary, new_record, read_previous, table


def records():
    ok = new_record(BatchTake("take01", Path("/shoot/take01.toml")))
    ok.update(status="ok", frames=720, shapes=52, strategy="geometric", residual_mm=0.4731, warnings=2,
              seconds={"total": 2.5}, outputs={"weights": "/out/take01.csv", "blend": "/out/take01.blend"},
              digest={"combined": "abc"})
    bad = new_record(BatchTake("take02", Path("/shoot/take02.toml")))
    bad.update(status="failed", error="/shoot/take02.csv: file not found")
    return ok, bad


def test_summary_json_and_csv(tmp_path):
    ok, bad = records()
    summary = Summary(tmp_path / "s.json", {"jobs": 2}, {ok["config"]: ok, bad["config"]: bad})
    summary.write()
    data = json.loads((tmp_path / "s.json").read_text())
    assert data["facecap_batch"] == 1 and data["status"] == "failed" and data["jobs"] == 2
    assert data["counts"] == {"ok": 1, "failed": 1, "skipped": 0, "cancelled": 0}
    assert [t["take"] for t in data["takes"]] == ["take01", "take02"]
    rows = list(csv.DictReader(io.StringIO((tmp_path / "s.csv").read_text())))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert rows[0]["residual_mm"] == "0.4731" and rows[0]["seconds"] == "2.500" and rows[0]["frames"] == "720"
    assert rows[1]["status"] == "failed" and rows[1]["error"] == "/shoot/take02.csv: file not found"
    assert read_previous(tmp_path / "s.json")["/shoot/take01.toml"]["digest"] == {"combined": "abc"}
    assert read_previous(tmp_path / "missing.json") == {}
    (tmp_path / "other.json").write_text('{"takes": []}')
    with pytest.raises(FacecapError, match="other.json: --resume needs the batch's summary; this is not one"):
        read_previous(tmp_path / "other.json")  # resuming from it would run every take again over it


def test_while_running_the_summary_is_written_at_most_once_a_second(tmp_path):
    ok, bad = records()
    summary = Summary(tmp_path / "s.json", {}, {ok["config"]: ok})
    assert summary.write(force=False)
    summary.dirty = True
    assert not summary.write(force=False)  # written less than a second ago
    assert summary.write()


def test_the_printed_table_names_the_failure():
    text = table(list(records()))
    lines = text.splitlines()
    assert lines[0].split()[:3] == ["take", "status", "frames"]
    assert "take01" in lines[1] and "0.473" in lines[1] and "2.5" in lines[1]
    assert lines[2].startswith("take02") and lines[2].endswith("/shoot/take02.csv: file not found")
    assert lines[-1] == "1 ok, 1 failed of 2 takes"


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_draws_a_bar_on_a_terminal_and_lines_elsewhere():
    ok, bad = records()
    shown = Terminal()
    bar = Progress(2, shown)
    bar.finished(ok)
    bar.finished(bad)
    bar.close()
    drawn = shown.getvalue()
    assert bar.bar is not None and "2/2" in drawn and ("take/s" in drawn or "s/take" in drawn)
    assert "FAILED take02: /shoot/take02.csv: file not found" in shown.getvalue()
    plain = io.StringIO()
    lines = Progress(2, plain)
    lines.finished(ok)
    lines.finished(bad)
    out = plain.getvalue().splitlines()
    assert out[0].startswith("facecap: [1/2] ok take01 (720 frames, 0.473 mm, 2.5 s); elapsed 0:00, eta 0:00")
    assert out[1].startswith("facecap: [2/2] FAILED take02: /shoot/take02.csv: file not found; elapsed")
