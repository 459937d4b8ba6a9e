"""The headless CLI as a TD runs it: subprocesses, real files, exit codes and one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers.io.csv import read_weights_csv

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"

pytestmark = pytest.mark.slow


def make_config(tmp_path, **overrides):
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    values = {
        "blend": SAMPLES / "character.blend",
        "markers": SAMPLES / "sample_take.csv",
        "out_blend": tmp_path / "out" / "retargeted.blend",
        "weights": tmp_path / "out" / "weights.csv",
        "report": tmp_path / "out" / "report.json",
    }
    values.update(overrides)
    text = f"""
[target]
blend = "{values['blend']}"
object = "Face"

[source]
markers = "{values['markers']}"
units = "mm"
fps = 60

[binding]
vertex_groups = true

[stabilise]
markers = {json.dumps(stable)}

[neutral]
frames = [1, 50]

[solve]
strategy = "geometric"

[output]
blend = "{values['out_blend']}"
weights = "{values['weights']}"
report = "{values['report']}"
"""
    path = tmp_path / "take.toml"
    path.write_text(text)
    return path, values


def run(*args, cwd=None):
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def check_outputs(values):
    frames, names, solved = read_weights_csv(values["weights"])
    _, truth_names, truth = read_weights_csv(SAMPLES / "sample_take_weights.csv")
    assert names == truth_names and frames.size == truth.shape[0]
    rmse = np.sqrt(np.nanmean((solved - truth) ** 2))
    assert rmse <= 0.03
    report = json.loads(Path(values["report"]).read_text())
    assert len(report["residual_rms_mm"]["per_frame"]) == frames.size
    assert set(report["markers_used"]) and report["timings_s"]["total"] > 0
    assert Path(values["out_blend"]).stat().st_size > 0
    return report


def test_python_m_facecap_retarget(tmp_path):
    config, values = make_config(tmp_path)
    before = (SAMPLES / "character.blend").stat().st_mtime_ns
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode == 0, proc.stderr
    assert "[5/5]" in proc.stderr  # progress goes to stderr
    check_outputs(values)
    assert (SAMPLES / "character.blend").stat().st_mtime_ns == before  # input untouched


def test_cli_script_entry_as_blender_runs_it(tmp_path):
    """``blender -b -P facecap_addon/cli.py -- retarget ...`` runs the file as a script; so do we."""
    config, values = make_config(tmp_path)
    proc = run(str(ROOT / "facecap_addon" / "cli.py"), "--", "retarget", "--config", str(config), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    check_outputs(values)


def test_output_blend_holds_the_new_action(tmp_path):
    config, values = make_config(tmp_path)
    assert run("-m", "facecap", "retarget", "--config", str(config)).returncode == 0
    code = (
        "import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]);"
        "k = bpy.data.objects['Face'].data.shape_keys;"
        "print(next(t for t in k.animation_data.nla_tracks if t.name == 'FaceCap Solve').strips[0].action.name)"
    )
    proc = run("-c", code, str(values["out_blend"]))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "sample_take"


@pytest.mark.parametrize(
    "override, message",
    [
        ({"markers": "/nonexistent/take.csv"}, r"/nonexistent/take\.csv: file not found"),
        ({"blend": "/nonexistent/character.blend"}, r"/nonexistent/character\.blend: file not found"),
    ],
)
def test_missing_input_gives_one_line_error(tmp_path, override, message):
    config, values = make_config(tmp_path, **override)
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    error_lines = [line for line in lines if "error" in line]
    assert len(error_lines) == 1 and "Traceback" not in proc.stderr
    import re

    assert re.search(message, error_lines[0])
    assert not Path(values["weights"]).exists()


def test_bad_config_names_the_key(tmp_path):
    config = tmp_path / "bad.toml"
    config.write_text('[source]\nmarkers = "x.csv"\nunits = "inch"\n[target]\nobject = "Face"\n[stabilise]\nmarkers=["a","b","c"]\n[neutral]\nframes=[1,2]\n')
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode == 1
    assert proc.stderr.strip() == f"facecap: error: {config}: [source.units] expected one of m, cm, mm, bu, px; got 'inch'"


def test_output_may_not_overwrite_input_blend(tmp_path):
    import shutil

    blend = tmp_path / "character.blend"
    shutil.copy(SAMPLES / "character.blend", blend)
    config, _ = make_config(tmp_path, blend=blend, out_blend=blend)
    before = blend.read_bytes()
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode == 1 and "output.blend" in proc.stderr
    assert blend.read_bytes() == before


def test_inspect_describes_a_file_and_refuses_a_bad_one(tmp_path):
    proc = run("-m", "facecap", "inspect", str(SAMPLES / "sample_take.csv"), "--units", "mm")
    assert proc.returncode == 0, proc.stderr
    assert "markers:  68" in proc.stdout and "frames:   720" in proc.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,a_x,a_y,a_z\n1,0,zero,0\n")
    proc = run("-m", "facecap", "inspect", str(bad))
    assert proc.returncode == 1
    assert proc.stderr.strip().count("\n") == 0 and "bad.csv, line 2" in proc.stderr


def test_clean_section_runs_and_is_reported(tmp_path):
    config, values = make_config(tmp_path)
    config.write_text(config.read_text() + "\n[clean]\nfill_spline = 8\n")
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode == 0, proc.stderr
    report = json.loads(Path(values["report"]).read_text())
    assert any("spline" in line for line in report["cleaning"])
    assert report["source"]["format"] == "csv"


def test_track_subcommand_writes_tracks(tmp_path):
    from facecap.solvers.video.synthetic import write_synthetic_clip

    clip = tmp_path / "clip.avi"
    write_synthetic_clip(clip, 12, 160, 120, seed=1)
    config = tmp_path / "track.toml"
    config.write_text('[source]\nvideo = "clip.avi"\n[tracking]\nregion = [30, 20, 100, 80]\nmethod = "lk"\n'
                      '[output]\nmarkers = "tracks.csv"\n')
    proc = run("-m", "facecap", "track", "--config", str(config))
    assert proc.returncode == 0, proc.stderr
    header = (tmp_path / "tracks.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "frame" and header[1].endswith("_x") and header[2].endswith("_y")
    proc = run("-m", "facecap", "track", "--config", str(tmp_path / "missing.toml"))
    assert proc.returncode == 1 and "missing.toml" in proc.stderr and "Traceback" not in proc.stderr


def test_retarget_2d_tracks_from_the_command_line(tmp_path):
    """Tracks as `facecap track` writes them (pixels) solve through the character's front view."""
    import sys as _sys

    _sys.path.insert(0, str(ROOT / "tests" / "core"))
    from test_pipeline_2d import tracks_2d

    from facecap.solvers import Basis
    from facecap.solvers.io.csv import write_markers_csv
    from facecap.solvers.tools.synthetic.synth import performance_weights

    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = tuple(m["name"] for m in layout["markers"] if m["stable"])
    weights = performance_weights(basis.shape_names, 240, seed=3)
    write_markers_csv(tmp_path / "tracks.csv", tracks_2d(basis, weights, stable))
    config, values = make_config(tmp_path, markers=tmp_path / "tracks.csv")
    config.write_text(config.read_text().replace('units = "mm"', 'units = "px"'))
    proc = run("-m", "facecap", "retarget", "--config", str(config))
    assert proc.returncode == 0, proc.stderr
    _, _, solved = read_weights_csv(values["weights"])
    assert np.sqrt(np.mean((solved - weights) ** 2)) <= 0.06
    report = json.loads(Path(values["report"]).read_text())
    assert any("front view" in w for w in report["warnings"])
