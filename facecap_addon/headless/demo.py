"""``python -m facecap demo``: retarget the bundled sample take onto the bundled sample character
and print the accuracy against the sample's ground truth."""

import dataclasses
from pathlib import Path

import numpy as np

from ...solvers.config import load_take_config
from ...solvers.io.csv import read_weights_csv
from ...solvers.transforms import rotation_angle_deg
from . import console
from .headless import progress_line, run_take

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_CONFIG = ROOT / "sample_blends" / "sample_take.toml"
#: Warnings the sample take gives on purpose, and why: a first-time user should not think the demo went wrong.
EXPECTED = {"held at rest": "expected for the sample take (its markers sit on the skin, none on the eyes or "
                            "the tongue): "}


def _say(message):
    """The demo's progress and warning lines: a warning the sample gives on purpose says so."""
    if message.startswith("warning: "):
        why = next((note for words, note in EXPECTED.items() if words in message), "")
        message = "warning: " + why + message.removeprefix("warning: ")
    progress_line(message)


def run_demo(out):
    """Retarget the sample into ``out`` and print the figures; returns the exit status."""
    out = Path(out).resolve()
    config = load_take_config(SAMPLE_CONFIG)
    config = dataclasses.replace(
        config,
        output_blend=out / "sample_take_retargeted.blend",
        output_weights=out / "sample_take_weights_solved.csv",
        output_report=out / "sample_take_report.json",
        output_html=out / "sample_take_review.html",
        truth_path=ROOT / "sample_blends" / "sample_take_weights.csv",
    )
    result, outputs = run_take(config, say=_say)

    _, names, truth = read_weights_csv(ROOT / "sample_blends" / "sample_take_weights.csv")
    order = [names.index(n) for n in result.shape_names]
    err = result.weights - truth[:, order]
    rmse = float(np.sqrt(np.nanmean(err**2)))
    worst = np.nanmax(np.abs(err), axis=0)
    k = int(np.argmax(worst))

    from scipy.spatial.transform import Rotation  # scipy: loaded when the demo runs

    head = np.loadtxt(ROOT / "sample_blends" / "sample_take_head.csv", delimiter=",", skiprows=1)
    true_rot = Rotation.from_rotvec(head[:, 1:4], degrees=True).as_matrix()
    ok = ~result.stabilise.flagged
    rot_err = rotation_angle_deg(result.stabilise.head_rotations()[ok] @ true_rot[ok].transpose(0, 2, 1))

    out = console.stdout()
    print(f"facecap demo: sample take -> sample character (strategy: {result.strategy})", file=out)
    print(f"  frames {result.frames.size}, shapes {len(result.shape_names)}, markers {len(result.marker_names)}", file=out)
    print(f"  weights vs ground truth: RMSE {rmse:.4f}, max |error| {worst[k]:.4f} ({result.shape_names[k]})", file=out)
    print(f"  head rotation vs ground truth: median {np.median(rot_err):.3f} deg, max {rot_err.max():.3f} deg", file=out)
    if result.alignment is not None:
        print(f"  actor-to-character scale {result.alignment.scale:.4f}", file=out)
    print(f"  mean residual {np.nanmean(result.residual_rms) * 1e3:.3f} mm, solve {result.timings['solve']:.3f} s", file=out)
    for key, value in outputs.items():
        print(f"  {key}: {value}", file=out)
    return 0
