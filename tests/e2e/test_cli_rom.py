"""A performer's range of motion from the command line, as a TD runs it: the ROM take with its sheet
(``[calibration] sequence``) turned into a performer profile by one ``retarget`` (``[output] profile``), then a
later take of the same performer solved with that profile (``[actor] profile``) onto the sample character.

The performer is the realism benchmark's Face Cap actor (a human not of the template's family) performing the
facecap-24 sheet imperfectly; the files are written to tmp_path by the test (shared data beside the checkout)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shared_data import SHARED, require

from facecap.solvers.character.face_model import load_ict
from facecap.solvers.io.csv import read_weights_csv, write_markers_csv
from facecap.solvers.tools.synthetic.realism.families import load_family
from facecap.solvers.tools.synthetic.realism.layouts import DENSE_HEAD
from facecap.solvers.tools.synthetic.realism.metrics import compare
from facecap.solvers.tools.synthetic.realism.scenario import make_draw
from facecap.solvers.tools.synthetic.realism.takes import REST, load_performances

ROOT = Path(__file__).resolve().parents[2]
BLEND = ROOT / "sample_blends" / "character.blend"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def performer(tmp_path_factory):
    require(SHARED / "data" / "facecap-head")
    out = tmp_path_factory.mktemp("performer")
    model = load_ict(require(SHARED / "data" / "ict-facekit"))
    family = load_family("facecap", SHARED, model)
    draw = make_draw(family, load_performances(SHARED / "data" / "realdata" / "llf", family.model.shape_names), 7,
                     frames=900)
    write_markers_csv(out / "rom.csv", draw.roms["facecap-24"].markers)
    write_markers_csv(out / "take.csv", draw.markers)
    return out, draw


def _config(folder, name, body):
    text = (f'[target]\nblend = "{BLEND}"\nobject = "Face"\n[source]\nunits = "mm"\n{body["source"]}\n'
            f"[stabilise]\nmarkers = {json.dumps(list(DENSE_HEAD))}\n{body.get('neutral', '')}"
            f"{body.get('more', '')}[output]\n{body['output']}\n")
    (folder / name).write_text(text)
    return folder / name


def _run(config):
    return subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)], cwd=config.parent,
                          capture_output=True, text=True, timeout=600)


def test_a_rom_take_becomes_a_profile_that_solves_the_performers_later_takes(performer):
    folder, draw = performer
    rom = _config(folder, "rom.toml", {"source": 'markers = "rom.csv"', "neutral": "[neutral]\ndetect = true\n",
                                      "more": '[calibration]\nsequence = "facecap-24"\n',
                                      "output": 'profile = "alex.npz"\nreport = "rom_report.json"'})
    done = _run(rom)
    assert done.returncode == 0, done.stderr[-3000:]
    # the take itself is the ROM: its holds found and named, the neutral found between them
    assert "ROM: 24 of 24 poses found" in done.stderr, done.stderr[-3000:]
    report = json.loads((folder / "rom_report.json").read_text())
    assert report["strategy_info"]["rom"]["poses_found"] == 24
    assert (folder / "alex.npz").is_file()

    def solve(name, more):
        config = _config(folder, name, {"source": 'markers = "take.csv"', "neutral": f"[neutral]\nframes = [1, {REST}]\n",
                                        "more": more, "output": f'weights = "{name}.csv"\nreport = "{name}.json"'})
        result = _run(config)
        assert result.returncode == 0, result.stderr[-3000:]
        _, names, weights = read_weights_csv(folder / f"{name}.csv")
        return result, compare(weights, names, draw.truth, draw.shape_names, frames=draw.performance_frames)

    known, with_profile = solve("profile", '[actor]\nprofile = "alex.npz"\ntemplate = "none"\n')
    nothing, without = solve("nothing", '[actor]\ntemplate = "none"\n')
    # measured (seed 7, 900 frames): 0.115 with the profile against 0.185 knowing nothing (the same ROM as the
    # take's [calibration] markers: 0.116); mean per-shape r 0.78 against 0.52
    assert with_profile["all"]["rmse"] < 0.7 * without["all"]["rmse"] and with_profile["all"]["rmse"] < 0.13
    assert with_profile["all"]["r"] > max(0.7, without["all"]["r"] + 0.15)
    assert "stored profile of this performer" in known.stderr
    assert "not this actor's" not in known.stderr and "not this actor's" in nothing.stderr


def test_a_sequence_the_config_gets_wrong_is_named_by_its_key(performer, tmp_path):
    folder, _ = performer
    bad = _config(folder, "bad.toml", {"source": 'markers = "rom.csv"', "neutral": "[neutral]\ndetect = true\n",
                                       "more": '[calibration]\nsequence = ["jawOpen", { jawOpen = 2 }]\n',
                                       "output": 'weights = "bad.csv"'})
    done = _run(bad)
    assert done.returncode == 1
    assert "[calibration.sequence]" in done.stderr and "item 2" in done.stderr and "(0, 1]" in done.stderr
    assert not (folder / "bad.csv").exists()
    holds = _config(folder, "holds.toml", {"source": 'markers = "rom.csv"', "neutral": "[neutral]\ndetect = true\n",
                                           "more": '[calibration]\nsequence = "facecap-24"\nholds = { "jaw opn" = 120 }\n',
                                           "output": 'weights = "holds.csv"'})
    done = _run(holds)
    assert done.returncode == 1 and "[calibration.holds]" in done.stderr and "'jaw opn'" in done.stderr
    assert np.all([line.startswith("facecap") for line in done.stderr.strip().splitlines()])
