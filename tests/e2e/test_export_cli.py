"""[output] gltf / fbx from the command line: re-imported by Blender's own importers, the morph-target
weights (glTF) and shape-key curves (FBX) equal the weights CSV at every frame."""

import json
import os
import subprocess
import sys

import pytest
from batch_shoot import SAMPLES, STABLE

pytestmark = pytest.mark.slow

READ_BACK = """
import bpy, json, sys, numpy as np
from facecap.facecap_addon.scene import anim, layers
from facecap.solvers.io.csv import read_weights_csv
frames, names, weights = read_weights_csv(sys.argv[1])
out = {}
for path in sys.argv[2:]:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = 60
    if path.endswith(".glb"):
        bpy.ops.import_scene.gltf(filepath=path)
    else:
        bpy.ops.import_scene.fbx(filepath=path, anim_offset=0.0)
    face = bpy.data.objects["Face"]
    key = face.data.shape_keys
    curves = {fc.data_path: fc for fc in anim.action_fcurves(key.animation_data.action, key)}
    read = np.array([[curves[layers.shape_path(n)].evaluate(float(f)) for n in names] for f in frames])
    out[path] = {"max_error": float(np.abs(read - weights).max()), "shapes": len(key.key_blocks) - 1,
                 "objects": sorted(o.name for o in bpy.data.objects), "frames": len(frames)}
print("JSON" + json.dumps(out))
"""


def test_retarget_writes_gltf_and_fbx_that_read_back_as_the_weights_csv(tmp_path):
    config = tmp_path / "take.toml"
    config.write_text(
        f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
        f'[source]\nmarkers = "{SAMPLES / "sample_take.csv"}"\nunits = "mm"\nfps = 60\n'
        f"[stabilise]\nmarkers = {json.dumps(STABLE)}\n[neutral]\nframes = [1, 50]\n"
        '[output]\nweights = "out/weights.csv"\nreport = "out/report.json"\ngltf = "out/take.glb"\n'
        'fbx = "out/take.fbx"\n')
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)], capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "out"
    assert f"gltf: {out / 'take.glb'}" in proc.stdout and f"fbx: {out / 'take.fbx'}" in proc.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["outputs"]["gltf"] == str(out / "take.glb") and report["outputs"]["fbx"] == str(out / "take.fbx")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    read = subprocess.run([sys.executable, "-c", READ_BACK, str(out / "weights.csv"), str(out / "take.glb"),
                           str(out / "take.fbx")], capture_output=True, text=True, timeout=900, env=env)
    assert read.returncode == 0, read.stderr
    result = json.loads(next(line[4:] for line in read.stdout.splitlines() if line.startswith("JSON")))
    for path, r in result.items():
        print(f"{path}: max |re-imported - weights CSV| = {r['max_error']:.2e} over {r['frames']} frames")
        assert r["objects"] == ["Face"] and r["shapes"] == 52
        assert r["max_error"] <= 1e-3
