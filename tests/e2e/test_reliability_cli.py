"""Regression tests of the reliability-2 defects that need the whole command line: damaged .blend files,
two runs adding to one .blend at once, a re-run take and ``batch --resume`` after a kill, a changed
character, Ctrl-C while Blender starts (``shared/bugs/reliability-2``: 03, 04, 07, 12, 15c)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from matrix_env import missing_prerequisite
from shared_data import BUGS

from facecap.facecap_addon.batch.batch import done_name

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
STABLE = '["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R"]'

pytestmark = pytest.mark.slow


def take_config(folder, name="take", *, blend=None, output='weights = "o/w.csv"', frames=120):
    folder.mkdir(parents=True, exist_ok=True)
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    (folder / "take.csv").write_text("\n".join(lines[: frames + 1]) + "\n")
    path = folder / f"{name}.toml"
    path.write_text(f'[target]\nblend = "{blend or SAMPLES / "character.blend"}"\nobject = "Face"\n'
                    f'[source]\nmarkers = "take.csv"\nunits = "mm"\nfps = 60\n[stabilise]\nmarkers = {STABLE}\n'
                    f'[neutral]\nframes = [1, 30]\n[output]\n{output}\n')
    return path


def facecap(*args, cwd=None, timeout=600):
    return subprocess.run([sys.executable, "-m", "facecap", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def one_line_error(proc):
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
    return [line for line in proc.stderr.splitlines() if line.startswith("facecap: error:")][-1]


def actions(blend):
    code = (f"import bpy, json; bpy.ops.wm.open_mainfile(filepath={str(blend)!r}); "
            "print('JSON' + json.dumps(sorted(a.name for a in bpy.data.actions)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(next(line[4:] for line in out.stdout.splitlines() if line.startswith("JSON")))


def test_03_damaged_blend_files_are_one_line_never_a_traceback_or_a_crash(tmp_path):
    data = (SAMPLES / "character.blend").read_bytes()
    (tmp_path / "trunc.blend").write_bytes(data[: len(data) // 3])
    (tmp_path / "text.blend").write_text("BLENDER this is just text\n")
    damaged = ["trunc.blend", "text.blend"]
    segv = BUGS / "reliability-2" / "03_corrupt_blend_traceback" / "segv.blend"
    if segv.is_file():
        shutil.copy(segv, tmp_path / "segv.blend")  # makes Blender 5.0 crash (SIGSEGV) when it opens it
        damaged.append("segv.blend")
    for name in damaged:
        line = one_line_error(facecap("retarget", "--config", take_config(tmp_path, blend=tmp_path / name)))
        assert name in line and "Blender can" in line, line
    out = take_config(tmp_path / "added", output='blend = "o/out.blend"')
    assert facecap("retarget", "--config", out).returncode == 0
    blend = tmp_path / "added" / "o" / "out.blend"
    os.truncate(blend, blend.stat().st_size // 2)  # disk trouble after the first run
    line = one_line_error(facecap("retarget", "--config", out))
    assert "out.blend" in line and "the existing [output] blend" in line
    if not segv.is_file():
        missing_prerequisite(f"the crashing .blend of the campaign is not at {segv}")


def test_04_two_runs_adding_to_one_blend_at_once_keep_both_actions(tmp_path):
    configs = {a: take_config(tmp_path, a, output=f'blend = "o/out.blend"\naction = "{a}"') for a in "ABC"}
    assert facecap("retarget", "--config", configs["A"]).returncode == 0
    procs = [subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config", str(configs[a])],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for a in "BC"]
    results = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [r[1][-500:] for r in results]
    assert {"A", "B", "C"} <= set(actions(tmp_path / "o" / "out.blend"))
    assert not list((tmp_path / "o").glob(".*facecap-lock"))


def test_12_a_rerun_take_replaces_its_own_action_and_resume_trusts_the_workers_record(tmp_path):
    shoot = tmp_path / "shoot"
    take_config(shoot, "take_a", output='blend = "out/take_a.blend"\nweights = "out/take_a.csv"')
    (shoot / "batch.toml").write_text('[batch]\ntakes = ["take_a.toml"]\n')
    summary = tmp_path / "s.json"
    proc = facecap("batch", shoot / "batch.toml", "--jobs", "1", "--summary", summary)
    assert proc.returncode == 0, proc.stderr
    done = tmp_path / "s-logs" / "done" / done_name((shoot / "take_a.toml").resolve())
    assert json.loads(done.read_text())["status"] == "ok"
    # a kill right after the take finished: the summary still says running, the worker's record says done
    document = json.loads(summary.read_text())
    document["takes"][0]["status"] = "running"
    summary.write_text(json.dumps(document))
    proc = facecap("batch", shoot / "batch.toml", "--jobs", "1", "--summary", summary, "--resume")
    assert proc.returncode == 0 and "1 up to date" in proc.stderr, proc.stderr
    # and when it does run again (its record lost too), it replaces its own action instead of adding .001
    shutil.rmtree(tmp_path / "s-logs")
    summary.unlink()
    assert facecap("batch", shoot / "batch.toml", "--jobs", "1", "--summary", summary).returncode == 0
    assert [a for a in actions(shoot / "out" / "take_a.blend") if a.startswith("take")] == ["take"]  # take.csv


def test_15c_a_character_changed_since_the_output_blend_was_made_is_told(tmp_path):
    character = tmp_path / "character.blend"
    shutil.copy(SAMPLES / "character.blend", character)
    config = take_config(tmp_path, blend=character, output='blend = "o/out.blend"')
    assert facecap("retarget", "--config", config).returncode == 0
    code = (f"import bpy; bpy.ops.wm.open_mainfile(filepath={str(character)!r}); "
            "bpy.data.objects['Face'].location.x += 1; bpy.ops.wm.save_mainfile()")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=300).returncode == 0
    proc = facecap("retarget", "--config", config)
    assert proc.returncode == 0 and "has changed since the output .blend was made" in proc.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_07_a_signal_while_blender_starts_is_exit_130_without_a_traceback(tmp_path, sig):
    config = take_config(tmp_path, frames=60)
    start = time.monotonic()
    subprocess.run([sys.executable, "-c", "import bpy"], capture_output=True, timeout=300)
    boot = time.monotonic() - start
    for fraction in (0.3, 0.6, 0.9, 1.2):
        proc = subprocess.Popen([sys.executable, "-m", "facecap", "retarget", "--config", str(config)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        time.sleep(boot * fraction)
        if proc.poll() is None:
            os.killpg(proc.pid, sig)  # as Ctrl-C does: the whole process group
        _, err = proc.communicate(timeout=300)
        assert proc.returncode in (0, 130), (fraction, proc.returncode, err[-800:])
        assert "Traceback" not in err and "internal error" not in err, (fraction, err[-800:])
