"""The CLI with every strategy: a synthetic ACTOR (own proportions and expressions) drives the sample CHARACTER.

Data are written to tmp_path by the tests themselves (no downloads, nothing stored): the actor's
calibration session and a performance as marker CSVs (mm, head motion, noise, gaps), the ground-truth
weights, a Live Link Face CSV of the same performance for ``parallel``, and posed example weights.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers.character.basis import Basis
from facecap.solvers.tools.compare import SAMPLE_BASIS, STABLE, _phone_weights, actor_take, calibration_weights, make_actor
from facecap.solvers.io.csv import read_weights_csv, write_markers_csv, write_weights_csv
from facecap.solvers.strategies.pca import farthest_frames
from facecap.solvers.tools.synthetic.synth import performance_weights, synthesize_take

ROOT = Path(__file__).resolve().parents[2]
BLEND = ROOT / "sample_blends" / "character.blend"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Calibration take, performance take (+ truth), LLF CSV and posed examples, written to disk."""
    out = tmp_path_factory.mktemp("actor")
    character = Basis.load_npz(SAMPLE_BASIS)
    actor = make_actor(character, seed=0)
    Wc, poses, neutral = calibration_weights(actor.shape_names, hold=30)
    calib = synthesize_take(actor, Wc, rest=30, stable=STABLE, units="mm", actor_scale=1.0, gap_fraction=0.0,
                            max_deg=10.0, seed=5)
    write_markers_csv(out / "calib.csv", calib.markers)
    truth = performance_weights(character.shape_names, 600, seed=0)
    take = actor_take(actor, truth, gaps=0.05, seed=2)
    write_markers_csv(out / "take.csv", take.markers)
    write_weights_csv(out / "truth.csv", take.markers.frames, character.shape_names, truth)
    phone, phone_names = _phone_weights(truth, character.shape_names)
    rows = [",".join(["Timecode", "BlendShapeCount", *phone_names])]
    for f, values in enumerate(phone):  # 60 fps timecodes (HH:MM:SS:FF), as the phone app writes them
        tc = f"00:00:{f // 60:02d}:{f % 60:02d}.000"
        rows.append(",".join([tc, str(len(phone_names)), *(f"{v:.6f}" for v in values)]))
    (out / "llf.csv").write_text("\n".join(rows) + "\n")
    ex = farthest_frames(take.deltas, 60)
    write_weights_csv(out / "examples.csv", take.markers.frames[ex], character.shape_names, truth[ex])
    return {"dir": out, "poses": poses, "neutral": neutral, "truth": truth}


def write_config(tmp_path, pair, strategy, body):
    d = pair["dir"]
    source = f'weights = "{d / "llf.csv"}"' if strategy == "parallel" else f'markers = "{d / "take.csv"}"\nunits = "mm"'
    head = "" if strategy == "parallel" else f"[stabilise]\nmarkers = {json.dumps(list(STABLE))}\n[neutral]\nframes = [1, 60]\n"
    text = f"""
[target]
blend = "{BLEND}"
object = "Face"
[source]
{source}
fps = 60
{head}
[solve]
strategy = "{strategy}"
{body}
[output]
weights = "out/weights.csv"
report = "out/report.json"
"""
    path = tmp_path / "take.toml"
    path.write_text(text)
    return path


def run(config):
    return subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)],
                          capture_output=True, text=True, timeout=600)


def rmse(tmp_path, pair):
    frames, names, solved = read_weights_csv(tmp_path / "out" / "weights.csv")
    _, truth_names, _ = read_weights_csv(pair["dir"] / "truth.csv")
    assert names == truth_names and solved.shape == pair["truth"].shape
    return float(np.sqrt(np.mean(np.nan_to_num(solved - pair["truth"], nan=1.0) ** 2)))


def calibration_body(pair, *, relative_to=None):
    poses = ", ".join(f"{k} = {v}" for k, v in pair["poses"].items())
    markers = pair["dir"] / "calib.csv"
    return (f'[calibration]\nmarkers = "{markers}"\nunits = "mm"\nneutral = {pair["neutral"]}\n'
            f"poses = {{ {poses} }}\n")


def test_calibrated_cross_retarget_through_the_cli(tmp_path, pair):
    config = write_config(tmp_path, pair, "calibrated", calibration_body(pair) + '[output]\n')
    text = config.read_text().replace("[output]\n\n[output]", "[output]").replace(
        '[output]\nweights', '[output]\nactor_basis = "out/actor.npz"\nweights')
    config.write_text(text)
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    assert "strategy: calibrated" in proc.stdout
    error = rmse(tmp_path, pair)
    print(f"calibrated via CLI: RMSE {error:.4f}")
    assert error <= 0.04
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["strategy"] == "calibrated" and report["residual_space"] == "actor"
    assert report["alignment"] is None and len(report["source_channels"]) == 52
    actor = Basis.load_npz(tmp_path / "out" / "actor.npz")
    assert actor.shape_names == tuple(pair["poses"])


def test_calibrated_is_far_better_than_geometric_on_this_pair(tmp_path, pair):
    config = write_config(tmp_path, pair, "geometric", "")
    assert run(config).returncode == 0
    assert rmse(tmp_path, pair) > 0.06  # the character's own shapes do not explain the actor's markers


def test_parallel_from_a_live_link_face_csv(tmp_path, pair):
    config = write_config(tmp_path, pair, "parallel", "[mapping]\nneutral = [1, 50]\n")
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    error = rmse(tmp_path, pair)
    print(f"parallel via CLI: RMSE {error:.4f}")
    assert error <= 0.04  # phone noise 0.02 and a 0-0.08 neutral bias, removed by the neutral offset
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["strategy"] == "parallel" and report["weights_file"].endswith("llf.csv")
    assert report["source"]["format"] == "livelinkface" and report["stabilise"] is None


def test_a_live_link_face_review_page_shows_the_phones_head(tmp_path, pair):
    """The page of a phone take said "No head motion" although the file has head angles: they are kept
    (WeightTrack.head, radians) and drawn, in degrees, on the result's frames."""
    import re

    from facecap.solvers.tools.report.blob import unpack

    lines = (pair["dir"] / "llf.csv").read_text().splitlines()
    n = len(lines) - 1
    yaw = 0.3 * np.sin(np.arange(n) / 40.0)  # radians, as the app writes them
    head = ["HeadYaw,HeadPitch,HeadRoll"] + [f"{y:.6f},{0.5 * y:.6f},{-0.25 * y:.6f}" for y in yaw]
    (tmp_path / "llf.csv").write_text("\n".join(f"{a},{b}" for a, b in zip(lines, head)) + "\n")
    config = write_config(tmp_path, pair, "parallel", "[mapping]\nneutral = [1, 50]\n")
    config.write_text(config.read_text().replace(str(pair["dir"] / "llf.csv"), str(tmp_path / "llf.csv")))
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config), "--html",
                           str(tmp_path / "out" / "review.html")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "out" / "review.html").read_text()
    assert "No head motion" not in html and "as the phone tracked it" in html
    meta = json.loads(re.search(r'id="facecap-meta">(.*?)</script>', html, re.S).group(1).replace("<\\/", "</"))
    arrays = unpack(re.search(r'id="facecap-blob">(.*?)</script>', html, re.S).group(1), meta["arrays"])
    assert "head_rotation" in [f["id"] for f in meta["figures"]]
    np.testing.assert_allclose(arrays["head_rotation"][0], np.degrees(yaw), atol=1e-3)
    np.testing.assert_allclose(arrays["head_rotation"][2], np.degrees(-0.25 * yaw), atol=1e-3)


@pytest.mark.parametrize("strategy, bound", [("linear", 0.15), ("rbf", 0.15), ("pca", 0.15)])
def test_example_strategies_through_the_cli(tmp_path, pair, strategy, bound):
    config = write_config(tmp_path, pair, strategy, f'[examples]\nweights = "{pair["dir"] / "examples.csv"}"\n')
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    error = rmse(tmp_path, pair)
    print(f"{strategy} via CLI: RMSE {error:.4f}")
    assert error <= bound
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    json.dumps(report)  # rbf's per-frame distances are JSON-ready
    assert report["strategy"] == strategy


def test_refine_through_the_cli(tmp_path, pair):
    config = write_config(tmp_path, pair, "refine", calibration_body(pair) + "[refine]\nmax_iterations = 3\n")
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    history = report["strategy_info"]["history"]
    assert all(b <= a for a, b in zip(history, history[1:]))
    assert rmse(tmp_path, pair) <= 0.08


def test_missing_strategy_inputs_name_the_key(tmp_path, pair):
    config = write_config(tmp_path, pair, "calibrated", "")
    proc = run(config)
    assert proc.returncode == 1
    assert proc.stderr.strip() == (f"facecap: error: {config}: [calibration.markers] strategy 'calibrated' needs "
                                   "[calibration] markers and poses (or a stored [calibration] basis)")


def test_compare_subcommand_prints_the_table():
    proc = subprocess.run([sys.executable, "-m", "facecap", "compare", "--frames", "240", "--examples", "20",
                           "--strategy", "calibrated", "--strategy", "parallel"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "| calibrated |" in proc.stdout and "| parallel |" in proc.stdout


def test_semantic_calibration_writes_a_profile_that_later_takes_reuse(tmp_path, pair):
    """The default strategy with a calibration session: the actor's own shapes; ``[output] profile`` stores them and
    a later take of the same performer reads them with ``[actor] profile`` (no calibration session)."""
    first = tmp_path / "first"
    first.mkdir()
    config = write_config(first, pair, "semantic", calibration_body(pair))
    config.write_text(config.read_text().replace("[output]\n", '[output]\nprofile = "../performers/actor.npz"\n'))
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    assert "actor: solved against the actor's own calibration poses" in proc.stderr
    calibrated = rmse(first, pair)
    assert calibrated <= 0.04, calibrated
    report = json.loads((first / "out" / "report.json").read_text())
    assert report["actor"]["tier"] == "calibration" and report["outputs"]["profile"].endswith("actor.npz")
    later = tmp_path / "later"
    later.mkdir()
    config = write_config(later, pair, "semantic", f'[actor]\nprofile = "{tmp_path / "performers" / "actor.npz"}"\n')
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    assert "actor: solved against the stored profile of this performer" in proc.stderr
    assert json.loads((later / "out" / "report.json").read_text())["actor"]["tier"] == "profile"
    assert abs(rmse(later, pair) - calibrated) < 0.005  # the same shapes, read back


def test_semantic_without_calibration_says_what_it_knows_and_refuses_to_write_a_profile(tmp_path, pair):
    config = write_config(tmp_path, pair, "semantic", "")
    proc = run(config)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["actor"]["tier"] == "character" and "actor: nothing is known about the actor's face" in proc.stderr
    assert rmse(tmp_path, pair) <= 0.07  # measured 0.05: this actor is close to the character (geometric 0.06)
    config.write_text(config.read_text().replace("[output]\n", '[output]\nprofile = "actor.npz"\n'))
    proc = run(config)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1
    assert "output.profile" in proc.stderr and "[calibration] sequence" in proc.stderr and "poses" in proc.stderr
    assert not (tmp_path / "actor.npz").exists()
