"""``python -m facecap tune`` end to end (issue 7): corrections CSV -> new library version + re-solved take.

Written to tmp_path by the test itself: an actor's calibration session with 4 of the 52 poses held at
40% strength, a 300-frame performance (head motion, noise, gaps), and the animator's corrections on 8
frames taken from the ground truth. The character is the sample character .blend.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import SAMPLE_BASIS, STABLE, actor_take, calibration_weights, make_actor
from facecap.solvers.io.csv import read_weights_csv, write_markers_csv, write_weights_csv
from facecap.solvers.tuning.store import load_version
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take
from facecap.solvers.tuning.retune import spread_frames

ROOT = Path(__file__).resolve().parents[2]
BLEND = ROOT / "sample_blends" / "character.blend"
WEAK = ("jawOpen", "mouthSmileLeft", "browInnerUp", "eyeBlinkLeft")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune")
    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    Wc, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    for name in WEAK:
        Wc[:, actor.shape_names.index(name)] *= 0.4
    calib = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, gap_fraction=0.0,
                            max_deg=10.0, seed=5)
    write_markers_csv(out / "calib.csv", calib.markers)
    truth = performance_weights(character.shape_names, 300, seed=0)
    t = actor_take(actor, truth, gaps=0.05, seed=2)
    write_markers_csv(out / "take.csv", t.markers)
    # the frames where the weak poses are most active (what an animator would fix)
    idx = spread_frames(truth[:, [character.shape_names.index(n) for n in WEAK]].sum(axis=1), 8)
    write_weights_csv(out / "corrections.csv", t.markers.frames[idx], character.shape_names, truth[idx])
    return {"dir": out, "poses": poses, "neutral": neutral, "truth": truth, "idx": idx,
            "names": character.shape_names}


def write_config(folder, take, extra=""):
    d = take["dir"]
    poses = ", ".join(f"{k} = {v}" for k, v in take["poses"].items())
    text = f"""
[target]
blend = "{BLEND}"
object = "Face"
[source]
markers = "{d / "take.csv"}"
units = "mm"
fps = 60
[stabilise]
markers = {json.dumps(list(STABLE))}
[neutral]
frames = [1, 60]
[solve]
strategy = "calibrated"
[calibration]
markers = "{d / "calib.csv"}"
units = "mm"
neutral = {take["neutral"]}
poses = {{ {poses} }}
[output]
weights = "out/weights.csv"
report = "out/report.json"
{extra}
"""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "take.toml"
    path.write_text(text)
    return path


def run(command, config):
    return subprocess.run([sys.executable, "-m", "facecap", command, "--config", str(config)],
                          capture_output=True, text=True, timeout=600)


def _rmse(a):
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))


@pytest.fixture(scope="module")
def tuned(take, tmp_path_factory):
    folder = tmp_path_factory.mktemp("tuned")
    config = write_config(folder, take, f'[tuning]\ncorrections = "{take["dir"] / "corrections.csv"}"\nout = "lib"\n')
    proc = run("tune", config)
    return folder, proc


def test_tune_writes_version_outputs_and_figures(take, tuned):
    folder, proc = tuned
    assert proc.returncode == 0, proc.stderr
    print("\n" + proc.stdout)
    assert "corrected RMSE" in proc.stdout and "other frames moved" in proc.stdout
    report = json.loads((folder / "out" / "report.json").read_text())
    t = report["tuning"]
    assert t["changed"] and t["kind"] == "actor_basis" and t["strategy"] == "calibrated"
    assert t["corrected_rmse_after"] <= 0.05 and t["corrected_rmse_after"] < 0.5 * t["corrected_rmse_before"]
    version = load_version(t["files"]["version"])
    original = load_version(t["files"]["original"])
    assert Path(t["files"]["version"]).parent == folder / "lib"
    assert version.name == t["version"] and version.parent == original.name and original.parent == ""
    # the re-solved take: better on the corrected frames and on the others
    _, names, solved = read_weights_csv(folder / "out" / "weights.csv")
    truth, idx = take["truth"], take["idx"]
    other = np.setdiff1d(np.arange(len(truth)), idx)
    assert names == take["names"]
    assert _rmse(np.nan_to_num(solved[idx] - truth[idx], nan=1.0)) <= 0.05
    print(f"held-out RMSE after tune: {_rmse(np.nan_to_num(solved[other] - truth[other], nan=1.0)):.4f}")


def test_a_second_tune_never_overwrites(take, tuned):
    folder, _ = tuned
    before = {p.name: p.read_bytes() for p in (folder / "lib").iterdir()}
    proc = run("tune", folder / "take.toml")
    assert proc.returncode == 0, proc.stderr
    after = {p.name: p.read_bytes() for p in (folder / "lib").iterdir()}
    assert all(after[name] == data for name, data in before.items())  # every earlier file is intact
    assert len(after) == len(before) + 1  # the same version again, stored beside it (-2); the original once


def test_retarget_with_the_stored_version_reproduces_the_tune(take, tuned, tmp_path):
    folder, _ = tuned
    report = json.loads((folder / "out" / "report.json").read_text())
    plain = run("retarget", write_config(tmp_path / "plain", take))
    assert plain.returncode == 0, plain.stderr
    config = write_config(tmp_path / "again", take, f'[tuning]\nlibrary = "{report["tuning"]["files"]["version"]}"\n')
    proc = run("retarget", config)
    assert proc.returncode == 0, proc.stderr
    _, _, tuned_w = read_weights_csv(folder / "out" / "weights.csv")
    _, _, again = read_weights_csv(tmp_path / "again" / "out" / "weights.csv")
    _, _, before = read_weights_csv(tmp_path / "plain" / "out" / "weights.csv")
    np.testing.assert_allclose(again, tuned_w, atol=1e-8)
    assert np.nanmax(np.abs(before - tuned_w)) > 0.1  # and it is not the untuned solve
    assert json.loads((tmp_path / "again" / "out" / "report.json").read_text())["library"]["version"] == \
        report["tuning"]["version"]


def test_retarget_applies_controls(take, tmp_path):
    plain = run("retarget", write_config(tmp_path / "plain", take))
    assert plain.returncode == 0, plain.stderr
    controls = ('[controls]\njawOpen = { gain = 1.5, clamp = [0, 0.6] }\n"eyeBlink*" = { mute = true }\n'
                'browInnerUp = { lock = 0.25 }\n')
    proc = run("retarget", write_config(tmp_path / "ctl", take, controls))
    assert proc.returncode == 0, proc.stderr
    names = take["names"]
    _, _, base = read_weights_csv(tmp_path / "plain" / "out" / "weights.csv")
    _, _, ctl = read_weights_csv(tmp_path / "ctl" / "out" / "weights.csv")
    j = names.index("jawOpen")
    np.testing.assert_allclose(ctl[:, j], np.clip(1.5 * base[:, j], 0.0, 0.6), atol=1e-8)
    for n in ("eyeBlinkLeft", "eyeBlinkRight"):
        np.testing.assert_array_equal(ctl[:, names.index(n)], 0.0)
    np.testing.assert_allclose(ctl[:, names.index("browInnerUp")], 0.25, atol=1e-12)
    k = names.index("mouthFunnel")
    np.testing.assert_allclose(ctl[:, k], base[:, k], atol=1e-8)


def test_bad_tuning_config_is_one_line(take, tmp_path):
    proc = run("tune", write_config(tmp_path / "a", take))
    assert proc.returncode == 1 and "[tuning.corrections]" in proc.stderr and "Traceback" not in proc.stderr
    proc = run("retarget", write_config(tmp_path / "b", take, '[controls]\njawOpen = { gian = 2 }\n'))
    assert proc.returncode == 1 and "[controls.jawOpen] unknown control(s) ['gian']" in proc.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,jawOpen\n10,oops\n")
    proc = run("tune", write_config(tmp_path / "c", take, f'[tuning]\ncorrections = "{bad}"\n'))
    assert proc.returncode == 1 and "bad.csv, line 2, field 'column 2'" in proc.stderr
