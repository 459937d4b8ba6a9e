"""Ctrl-C or SIGTERM at 20 seeded random moments of a whole retarget (Blender's start-up, reading, the
solve, keying, writing): each run ends with exit status 130 or finishes (0), without a traceback, and
leaves no temporary file, no lock and no half-written output: every output there is whole (the .blend's
structure complete, the CSV with every frame, the report JSON that parses)."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from facecap.solvers.io.blend_file import check_blend_structure
from facecap.solvers.io.csv import read_weights_csv
from facecap.solvers.io.files import TMP_MARK
from facecap.solvers.io.locks import LOCK_SUFFIX

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
SEED = 29
MOMENTS = 20
FRAMES = 240

pytestmark = pytest.mark.slow


def config(folder):
    folder.mkdir(parents=True)
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    (folder / "take.csv").write_text("\n".join(lines[: FRAMES + 1]) + "\n")
    path = folder / "take.toml"
    path.write_text(f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
                    '[source]\nmarkers = "take.csv"\nunits = "mm"\nfps = 60\n[stabilise]\nmarkers = "auto"\n'
                    '[neutral]\nframes = [1, 30]\n[output]\nblend = "o/take.blend"\nweights = "o/w.csv"\n'
                    'report = "o/r.json"\n')
    return path


def run(path, delay=None, sig=signal.SIGINT):
    proc = subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    if delay is not None:
        time.sleep(delay)
        if proc.poll() is None:
            os.killpg(proc.pid, sig)  # as Ctrl-C in a terminal: the whole process group
    _, err = proc.communicate(timeout=600)
    return proc.returncode, err


def whole_outputs(out):
    """The outputs in ``out`` are whole; returns their names."""
    names = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    assert not [n for n in names if TMP_MARK in n or n.endswith(LOCK_SUFFIX)], names
    if "take.blend" in names:
        check_blend_structure(out / "take.blend")
    if "w.csv" in names:
        frames, _, weights = read_weights_csv(out / "w.csv")
        assert frames.size == FRAMES and weights.shape[0] == FRAMES
    if "r.json" in names:
        assert json.loads((out / "r.json").read_text())["facecap_report"] == 1
    return names


def test_a_signal_at_any_moment_ends_in_130_or_a_finished_run_never_a_half_written_file(tmp_path):
    path = config(tmp_path / "whole")
    start = time.monotonic()
    rc, err = run(path)
    whole = time.monotonic() - start
    assert rc == 0, err
    assert whole_outputs(tmp_path / "whole" / "o") == ["r.json", "take.blend", "w.csv"]
    rng = random.Random(SEED)
    outcomes = []
    for i in range(MOMENTS):
        # a fresh take folder for half the moments, the finished one (being added to) for the rest
        folder = tmp_path / f"m{i}"
        path = config(folder) if i % 2 == 0 else tmp_path / "whole" / "take.toml"
        delay, sig = rng.uniform(0.0, 1.1 * whole), rng.choice([signal.SIGINT, signal.SIGTERM])
        rc, err = run(path, delay, sig)
        assert rc in (0, 130), (i, delay, sig, rc, err[-800:])
        assert "Traceback" not in err and "internal error" not in err, (i, delay, err[-800:])
        names = whole_outputs(path.parent / "o")
        if rc == 0:
            assert names == ["r.json", "take.blend", "w.csv"]
        outcomes.append((round(delay, 2), sig.name, rc))
    print(f"\nsignals: a whole run takes {whole:.1f} s; (delay, signal, exit): {outcomes}")
    assert any(rc == 130 for _, _, rc in outcomes)
