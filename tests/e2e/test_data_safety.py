"""A TD's files survive the CLI: a second retarget adds to the output .blend (the first solve, the
animator's keys and objects stay), --replace starts over explicitly, an interrupted run leaves no
temporary or half-written file, outputs get normal permissions and the output scene the take's timing."""

import hashlib
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from facecap.solvers.io.files import TMP_MARK, umask

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"

pytestmark = pytest.mark.slow


def config(folder, action, *, frames=None):
    folder.mkdir(parents=True, exist_ok=True)
    take = folder / "take.csv"
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    take.write_text("\n".join(lines if frames is None else lines[: frames + 1]) + "\n")
    path = folder / f"{action}.toml"
    path.write_text(
        f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
        '[source]\nmarkers = "take.csv"\nunits = "mm"\nfps = 60\n'
        '[stabilise]\nmarkers = ["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", '
        '"head_temple_R", "head_nose_bridge_C"]\n[neutral]\nframes = [1, 50]\n'
        f'[output]\nblend = "out/take.blend"\nweights = "out/weights.csv"\nreport = "out/report.json"\n'
        f'action = "{action}"\n')
    return path


def retarget(path, *extra):
    return subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(path), *extra],
                          capture_output=True, text=True, timeout=600)


def blend_contents(path, script=""):
    """Actions (name, fake user), the solve layer's action, objects and scene timing of a .blend."""
    code = (f"import bpy, json; bpy.ops.wm.open_mainfile(filepath={str(path)!r}); {script}"
            "k = bpy.data.objects['Face'].data.shape_keys; t = k.animation_data.nla_tracks['FaceCap Solve']; "
            "s = bpy.context.scene; print('JSON' + json.dumps({'actions': {a.name: a.use_fake_user for a in "
            "bpy.data.actions}, 'solve': t.strips[0].action.name, 'objects': sorted(o.name for o in bpy.data.objects), "
            "'fps': s.render.fps / s.render.fps_base, 'range': [s.frame_start, s.frame_end]}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(next(line[4:] for line in out.stdout.splitlines() if line.startswith("JSON")))


def digest(*paths):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


def test_a_second_retarget_adds_to_the_output_blend_and_replace_starts_over(tmp_path):
    a, b = config(tmp_path, "take_A", frames=240), config(tmp_path, "take_B", frames=240)
    inputs = digest(SAMPLES / "character.blend", tmp_path / "take.csv", a, b)
    assert retarget(a).returncode == 0
    out = tmp_path / "out" / "take.blend"
    # the animator adds an object and saves, as they would between two solves
    blend_contents(out, "bpy.context.scene.collection.objects.link(bpy.data.objects.new('AnimatorNote', None)); "
                   f"bpy.ops.wm.save_mainfile(filepath={str(out)!r}); ")
    proc = retarget(b)
    assert proc.returncode == 0, proc.stderr
    seen = blend_contents(out)
    assert seen["solve"] == "take_B" and seen["actions"]["take_A"] is True  # the first solve kept (fake user)
    assert "AnimatorNote" in seen["objects"]
    assert json.loads((tmp_path / "out" / "report.json").read_text())["output_blend"]["mode"] == "added"
    assert seen["fps"] == pytest.approx(60.0) and seen["range"] == [1, 240]
    proc = retarget(b, "--replace")
    assert proc.returncode == 0, proc.stderr
    seen = blend_contents(out)
    assert "take_A" not in seen["actions"] and "AnimatorNote" not in seen["objects"]
    assert json.loads((tmp_path / "out" / "report.json").read_text())["output_blend"]["mode"] == "replaced"
    assert digest(SAMPLES / "character.blend", tmp_path / "take.csv", a, b) == inputs
    mode = 0o666 & ~umask()
    for name in ("weights.csv", "report.json", "take.blend"):
        assert (tmp_path / "out" / name).stat().st_mode & 0o777 == mode


def test_an_output_that_is_an_input_exits_1_and_writes_nothing(tmp_path):
    path = config(tmp_path, "take_A", frames=120)
    path.write_text(path.read_text().replace('weights = "out/weights.csv"', 'weights = "take.csv"'))
    before = digest(tmp_path / "take.csv", path)
    proc = retarget(path)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "[output.weights] is the same file as [source.markers]" in proc.stderr.strip().splitlines()[-1]
    assert digest(tmp_path / "take.csv", path) == before and not (tmp_path / "out").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_run_leaves_no_temporary_or_half_file(tmp_path, sig):
    path = config(tmp_path, "take_A")
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config", str(path)],
                                stdout=subprocess.DEVNULL, stderr=err)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and "[3/5]" not in log.read_text():
            time.sleep(0.05)
        proc.send_signal(sig)
        proc.wait(timeout=120)
    text = log.read_text()
    assert proc.returncode == 130, text
    assert "interrupted" in text and "Traceback" not in text
    out = tmp_path / "out"
    left = [p.name for p in out.iterdir()] if out.exists() else []
    assert not [n for n in left if TMP_MARK in n]
    assert "weights.csv" not in left and "report.json" not in left  # stopped during the solve
