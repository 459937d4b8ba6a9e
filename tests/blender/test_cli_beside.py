"""The CLI's side jobs: the take read while Blender opens the character, the weights CSV written
while Blender keys and saves, each in a forked child. Same outputs as one after the other."""

import json
from pathlib import Path

import numpy as np
import pytest

from facecap.facecap_addon.headless import headless
from facecap.solvers.engine import split as engine_split
from facecap.solvers.config import load_take_config
from facecap.solvers.errors import InputFileError

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"

pytestmark = pytest.mark.skipif(not engine_split.fork_available(), reason="no fork on this platform")


def _config(tmp_path, markers, out):
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    path = tmp_path / f"{out}.toml"
    path.write_text(
        f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
        f'[source]\nmarkers = "{markers}"\nunits = "mm"\nfps = 60\n'
        f"[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 50]\n"
        f'[output]\nblend = "{out}/out.blend"\nweights = "{out}/weights.csv"\nreport = "{out}/report.json"\n'
    )
    return load_take_config(path)


def _run(monkeypatch, config, beside):
    """Retarget with the side jobs forced on (every file is 'big') or off; returns run_beside's call count."""
    calls = []
    real = engine_split.run_beside

    def spy(here, there, **kw):
        calls.append(kw)
        return real(here, there, **kw)

    monkeypatch.setattr(headless, "run_beside", spy)
    monkeypatch.setattr(headless, "PARALLEL_READ_BYTES", -1 if beside else 1 << 60)
    monkeypatch.setattr(headless, "PARALLEL_WRITE_VALUES", -1 if beside else 1 << 60)
    headless.run_take(config, quiet=True)
    return calls


def test_side_jobs_write_what_the_plain_run_writes(tmp_path, monkeypatch):
    plain = _config(tmp_path, SAMPLES / "sample_take.csv", "plain")
    beside = _config(tmp_path, SAMPLES / "sample_take.csv", "beside")
    assert _run(monkeypatch, plain, beside=False) == []
    calls = _run(monkeypatch, beside, beside=True)
    assert calls == [{}, {"let_finish": True}]  # the read, then the weights CSV
    a, b = tmp_path / "plain", tmp_path / "beside"
    assert (a / "weights.csv").read_bytes() == (b / "weights.csv").read_bytes()
    ra, rb = (json.loads((d / "report.json").read_text()) for d in (a, b))
    np.testing.assert_array_equal(ra["residual_rms_mm"]["per_frame"], rb["residual_rms_mm"]["per_frame"])
    assert ra["cleaning"] == rb["cleaning"] and ra["source"] == rb["source"]
    assert (b / "out.blend").stat().st_size > 0
    assert not [p.name for p in b.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_a_bad_take_read_beside_fails_with_its_own_message(tmp_path, monkeypatch):
    """The child's failure is not reported from the child: the file is read again here, so the
    error names the file and line as in a plain run."""
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    cells = lines[5].split(",")
    cells[3] = "oops"
    lines[5] = ",".join(cells)
    bad = tmp_path / "bad_take.csv"
    bad.write_text("\n".join(lines) + "\n")
    config = _config(tmp_path, bad, "bad")
    with pytest.raises(InputFileError) as plain:
        _run(monkeypatch, config, beside=False)
    with pytest.raises(InputFileError) as beside:
        _run(monkeypatch, config, beside=True)
    assert str(beside.value) == str(plain.value)
    assert "bad_take.csv" in str(beside.value) and "line 6" in str(beside.value)
    assert not (tmp_path / "bad").exists()  # nothing written
