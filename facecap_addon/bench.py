"""Blender-side benchmarks: bulk keying vs a keyframe_insert loop, and the whole CLI retarget.

Run through ``python -m facecap bench`` (with the solver cases). Times are medians; baselines
timed on a subset are scaled per key or per frame.
"""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..solvers.character.basis import Basis
from ..solvers.io.csv import write_markers_csv
from ..solvers.tools.bench import median_time

ROOT = Path(__file__).resolve().parents[1]


def _shape_key_mesh(n_shapes):
    import bpy  # bpy: Blender starts on first import

    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("BenchFace")
    mesh.vertices.add(4)
    obj = bpy.data.objects.new("BenchFace", mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    for k in range(n_shapes):
        obj.shape_key_add(name=f"shape{k:02d}", from_mix=False)
    return obj


def bench_keying(frames=36000, shapes=52, baseline_frames=300, repeat=3):
    """Bulk keying (keyframe_points.add + foreach_set) against keyframe_insert per key."""
    from . import anim  # loads bpy

    obj = _shape_key_mesh(shapes)
    key = obj.data.shape_keys
    names = [b.name for b in key.key_blocks[1:]]
    curves = [(f'key_blocks["{n}"].value', 0) for n in names]
    values = np.random.default_rng(0).uniform(0, 1, size=(frames, shapes))
    f = np.arange(1, frames + 1, dtype=np.float64)
    t = median_time(lambda: anim.new_action_with_curves(key, name="bench", curves=curves, frames=f, values=values), repeat)[0]

    def insert_loop():
        key.animation_data_clear()
        blocks = list(key.key_blocks[1:])
        for i in range(baseline_frames):
            for k, block in enumerate(blocks):
                block.value = values[i, k]
                block.keyframe_insert("value", frame=i + 1)  # the naive baseline being measured

    t_base = median_time(insert_loop, 1)[0] * frames / baseline_frames
    return dict(
        name=f"keying {shapes} F-curves x {frames} frames", seconds=t, baseline_seconds=t_base,
        ratio=t_base / t, goal=">= 50x and < 1 s",
        note=f"baseline: keyframe_insert loop over {baseline_frames} frames, scaled",
    )


def bench_cli_retarget(frames=36000, repeat=3):
    """``python -m facecap retarget`` on a long synthetic take of the sample character, process start to
    saved .blend; the median of ``repeat`` runs (one run varies by seconds on a shared machine)."""

    from ..solvers.tools.synth import (  # loads scipy
        performance_weights,
        synthesize_take,
    )

    samples = ROOT / "sample_blends"
    basis = Basis.load_npz(samples / "character_basis.npz")
    layout = json.loads((samples / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    weights = performance_weights(basis.shape_names, frames, seed=5)
    take = synthesize_take(basis, weights, stable=stable, seed=6)
    with tempfile.TemporaryDirectory(prefix="facecap-bench-") as tmp:
        tmp = Path(tmp)
        write_markers_csv(tmp / "long_take.csv", take.markers)
        config = tmp / "long_take.toml"
        config.write_text(
            f'[target]\nblend = "{samples / "character.blend"}"\nobject = "Face"\n'
            f'[source]\nmarkers = "long_take.csv"\nunits = "mm"\nfps = 60\n'
            f"[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 50]\n"
            f'[output]\nblend = "out.blend"\nweights = "out.csv"\nreport = "report.json"\n'
        )
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

        def once():
            proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config)],
                                  capture_output=True, text=True, env=env)
            if proc.returncode != 0:
                raise RuntimeError(proc.stderr.strip().splitlines()[-1])

        seconds = median_time(once, repeat)[0]
        stages = json.loads((tmp / "report.json").read_text())["timings_s"]  # the last run's
    detail = ", ".join(f"{k} {v:.2f} s" for k, v in stages.items() if k in ("read", "load_character", "stabilise", "solve", "key", "total"))
    return dict(
        name=f"CLI retarget {frames} frames x {basis.n_shapes} shapes x {basis.n_markers} markers (process start to saved .blend)",
        seconds=seconds, baseline_seconds=None, ratio=None, goal="< 15 s",
        note=f"median of {repeat} runs; stages of the last: {detail}",
    )
