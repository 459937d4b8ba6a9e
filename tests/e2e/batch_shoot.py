"""A shoot folder for the batch tests: takes cut from the sample take with different settings, a batch
file with shared [defaults], broken takes, and the same takes as standalone configs for single runs."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
STABLE = ["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
          "head_nose_bridge_C", "head_side_L", "head_side_R"]

#: name -> (frames of the sample take, markers dropped, [solve] extra)
GOOD = {
    "take_a": (400, (), ""),
    "take_b": (720, (), "regularisation = 0.01\nlocks = { jawForward = 0.0 }\n"),
    "take_c": (600, ("cheek_L", "cheek_R", "mouth_corner_L"), ""),
    "take_d": (500, (), "smoothing = [0.1, 0.5]\nsparsity = 0.01\n"),
}


def cut_take(path, frames, drop=(), tile=1):
    """The first ``frames`` frames of the sample take without the markers ``drop``, repeated ``tile`` times."""
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if not any(h.startswith(d + "_") and len(h) == len(d) + 2 for d in drop)]
    rows = [line.split(",") for line in lines[1: frames + 1]]
    out = [",".join(header[i] for i in keep)]
    for t in range(tile):
        for k, row in enumerate(rows):
            row = [str(t * frames + k + 1)] + row[1:]
            out.append(",".join(row[i] for i in keep))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n")
    return path


def batch_file(folder, takes="takes/", outputs=None):
    outputs = outputs or {"blend": "out/{take}.blend", "weights": "out/{take}.csv", "report": "out/{take}.json"}
    text = (f'[batch]\ntakes = ["{takes}"]\n\n[defaults.target]\nblend = "{SAMPLES / "character.blend"}"\n'
            f'object = "Face"\n\n[defaults.source]\nunits = "mm"\nfps = 60\n\n'
            f"[defaults.stabilise]\nmarkers = {json.dumps(STABLE)}\n\n[defaults.neutral]\nframes = [1, 50]\n\n"
            "[defaults.output]\n" + "".join(f'{k} = "{v}"\n' for k, v in outputs.items()))
    path = folder / "batch.toml"
    path.write_text(text)
    return path


def shoot(folder, good=GOOD, broken=True):
    """Write the shoot: folder/batch.toml, folder/takes/*.toml, folder/captures/*.csv; with ``broken``, a take
    whose markers file is missing and one with a bad value. Returns the batch file."""
    for name, (frames, drop, solve) in good.items():
        cut_take(folder / "captures" / f"{name}.csv", frames, drop)
        take(folder / "takes" / f"{name}.toml", f"../captures/{name}.csv", solve)
    if broken:
        take(folder / "takes" / "take_missing.toml", "../captures/not_there.csv")
        take(folder / "takes" / "take_badvalue.toml", "../captures/take_a.csv", "regularisation = -1.0\n")
    return batch_file(folder)


def take(path, markers, solve=""):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'[source]\nmarkers = "{markers}"\n' + (f"[solve]\n{solve}" if solve else ""))
    return path


def standalone(folder, name, out, good=GOOD):
    """The take ``name`` as one config with the defaults written out and outputs in ``out``."""
    frames, drop, solve = good[name]
    path = folder / "single" / f"{name}.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
        f'[source]\nmarkers = "{folder / "captures" / f"{name}.csv"}"\nunits = "mm"\nfps = 60\n'
        f"[stabilise]\nmarkers = {json.dumps(STABLE)}\n[neutral]\nframes = [1, 50]\n"
        + (f"[solve]\n{solve}" if solve else "")
        + f'[output]\nblend = "{out / f"{name}.blend"}"\nweights = "{out / f"{name}.csv"}"\n'
          f'report = "{out / f"{name}.json"}"\n')
    return path


def facecap(*args, cwd=None, **kw):
    return subprocess.run([sys.executable, "-m", "facecap", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=900, **kw)


def summary(path):
    data = json.loads(Path(path).read_text())
    return data, {t["take"]: t for t in data["takes"]}


SOLVE_CURVES = """
import bpy, sys, numpy as np
from facecap.facecap_addon.scene import anim, layers
out = {}
for i, path in enumerate(sys.argv[2:]):
    bpy.ops.wm.open_mainfile(filepath=path)
    key = bpy.data.objects["Face"].data.shape_keys
    action = layers.solved_action(key)
    out[f"name{i}"] = np.array(action.name)
    for fc in anim.action_fcurves(action, key):
        points = fc.keyframe_points if len(fc.keyframe_points) else fc.sampled_points
        co = np.empty(2 * len(points), dtype=np.float32)
        points.foreach_get("co", co)
        out[f"{i}:{fc.data_path}"] = co
np.savez(sys.argv[1], **out)
"""


def solve_curves(blends, tmp):
    """{blend: {data path: keys (2 n,) float32}} and the solve action's name, of each .blend's solve layer."""
    target = Path(tmp) / "curves.npz"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", SOLVE_CURVES, str(target), *map(str, blends)], capture_output=True,
                          text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr
    data = np.load(target)
    out = []
    for i in range(len(blends)):
        curves = {k.split(":", 1)[1]: data[k] for k in data.files if k.startswith(f"{i}:")}
        out.append((str(data[f"name{i}"]), curves))
    return out
