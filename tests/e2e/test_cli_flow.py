"""``python -m facecap retarget`` on a video take: no markers, flow-PCA features, posed footage frames.

The footage is a synthetic face written as a real mp4 file by the test (its six bumps are six
ARKit shapes of the sample character; weight = bump amplitude / AMP), with head motion and noise.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers.io.csv import read_weights_csv, write_weights_csv  # noqa: E402
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BLEND = ROOT / "sample_blends" / "character.blend"
W, H, N, AMP = 240, 180, 100, 4.0
SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "cheekPuff")
POSED = np.linspace(0, N - 1, 16).round().astype(int)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def footage(tmp_path_factory):
    d = tmp_path_factory.mktemp("cliflow")
    clip = write_synthetic_clip(d / "face.mp4", N, W, H, amplitude=AMP, noise=1.0, seed=11, period=24.0)
    write_weights_csv(d / "posed.csv", POSED + 1.0, SHAPES, clip.motion.amplitudes[POSED] / AMP)
    return d, clip.motion.amplitudes / AMP


def config(d, name, *, tracking='region = [24, 18, 192, 144]\nstable_region = [48, 9, 144, 18]',
           examples='weights = "posed.csv"', strategy="linear"):
    path = d / f"{name}.toml"
    path.write_text(f"""
[target]
blend = "{BLEND}"
object = "Face"
[source]
video = "face.mp4"
[tracking]
{tracking}
[flow]
components = 10
[solve]
strategy = "{strategy}"
[examples]
{examples}
[output]
blend = "{name}/take.blend"
weights = "{name}/weights.csv"
report = "{name}/report.json"
""")
    return path


def run(path):
    return subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=path.parent)


def test_the_review_page_of_a_video_take_shows_the_footage_beside_the_character(footage):
    """The contact sheet's source panel is the footage frame (grey, at the render's height) of each tile."""
    import base64

    from png_pixels import png_pixels

    d, _ = footage
    path = config(d, "review")
    done = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(path), "--html",
                           "review/page.html"], capture_output=True, text=True, timeout=300, cwd=d)
    assert done.returncode == 0, done.stderr
    html = (d / "review" / "page.html").read_text()
    tiles = re.findall(r'<figure class="tile[^"]*"><div class="pair"><img class="source" src="data:image/png;base64,'
                       r'([^"]+)" height="(\d+)"', html)
    assert len(tiles) >= 3, "every tile of a video take shows its footage frame"
    assert "the footage frame beside" in html
    png = d / "review" / "first.png"
    png.write_bytes(base64.b64decode(tiles[0][0]))
    pixels = png_pixels(png)
    assert pixels.shape[0] == int(tiles[0][1]) and abs(pixels.shape[1] / pixels.shape[0] - W / H) < 0.02
    assert np.ptp(pixels) > 50, "an image of the footage, not a blank"


def test_retarget_a_video_take_from_posed_frames(footage):
    d, truth = footage
    t0 = time.perf_counter()
    done = run(config(d, "linear"))
    seconds = time.perf_counter() - t0
    assert done.returncode == 0, done.stderr
    assert "retargeted 100 frames, 52 shapes (strategy: linear)" in done.stdout
    frames, names, solved = read_weights_csv(d / "linear" / "weights.csv")
    assert frames.tolist() == list(range(1, N + 1)) and len(names) == 52
    rest = np.setdiff1d(np.arange(N), POSED)
    cols = [names.index(s) for s in SHAPES]
    rmse = float(np.sqrt(np.mean((solved[rest][:, cols] - truth[rest]) ** 2)))
    others = np.delete(solved, cols, axis=1)
    report = json.loads((d / "linear" / "report.json").read_text())
    flow = report["flow"]
    print(f"CLI video take (linear): weights RMSE {rmse:.4f} on {rest.size} unposed frames; flow "
          f"{flow['flow_frames_per_s']:.0f} frames/s at {W}x{H}; {flow['components']} components explain "
          f"{flow['explained_variance']:.4f}; whole command {seconds:.1f} s")
    assert rmse <= 0.06 and np.abs(others).max() <= 1e-9  # shapes nobody posed stay at 0
    assert (d / "linear" / "take.blend").stat().st_size > 0
    assert flow["components"] == 10 and len(flow["explained_variance_ratio"]) == 10 and flow["frames"] == N
    assert flow["stabilised"] and flow["method"] == "dis" and flow["example_frames"] == 16
    assert "not defined" in flow["residual"] and report["residual_rms_mm"]["mean"] is None
    assert report["source"]["format"] == "video" and report["source"]["count"] == N
    assert {"flow", "features", "solve", "read", "key", "total"} <= set(report["timings_s"])
    assert report["outputs"]["action"] == "face" and report["strategy"] == "linear"


@pytest.mark.parametrize("name,edit,key", [
    ("noexamples", dict(examples=""), "examples.weights"),
    ("outside", dict(tracking="region = [200, 18, 100, 144]"), "tracking.region"),
])
def test_bad_video_config_is_one_line_naming_the_key(footage, name, edit, key):
    d, _ = footage
    done = run(config(d, name, **edit))
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert f"[{key}]" in lines[-1] and lines[-1].startswith("facecap: error: ") and "Traceback" not in done.stderr
    assert not (d / name).exists()


def test_ctrl_c_cancels_the_flow_with_nothing_written(footage):
    d, _ = footage
    path = config(d, "interrupted", tracking='region = [24, 18, 192, 144]\nmethod = "tvl1"')
    proc = subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config", str(path)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=d)
    seen, deadline = b"", time.monotonic() + 60
    while b"flow (tvl1): " not in seen and time.monotonic() < deadline:
        chunk = os.read(proc.stderr.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
    assert b"flow (tvl1): 1/100 frames" in seen, seen
    proc.send_signal(signal.SIGINT)
    rest = proc.communicate(timeout=60)[1]
    lines = [line for line in re.split(r"[\r\n]", (seen + rest).decode()) if line]
    assert proc.returncode == 130, lines
    assert re.fullmatch(r"facecap: cancelled at frame \d+ \(\d+ of 100 frames done\); nothing written",
                        lines[-1]), lines
    assert "Traceback" not in "\n".join(lines)
    assert not (d / "interrupted").exists()
