"""``bench``: the whole command-line retarget of a long take against a plain per-frame loop, stage by stage.

The take: 36,000 frames of the sample character cut to 24 of its shapes and 53 of its
markers (a 48 MB CSV), solved with ``python -m facecap retarget`` from process start to saved .blend;
the baseline is the plain loop a user would write instead, one ``scipy.optimize.lsq_linear`` (BVLS)
per frame on the same take's deltas with the same ridge, timed in the same run. One line per stage
(from the take report's ``timings_s``), the whole run with its ratio against the loop.
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ...solvers.character.basis import Basis
from ...solvers.engine import basis_scale
from ...solvers.io.csv import write_markers_csv
from ...solvers.tools.bench.bench import bvls_loop

ROOT = Path(__file__).resolve().parents[2]

SHAPES = ("eyeBlinkLeft", "eyeBlinkRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight", "jawOpen",
          "jawLeft", "mouthClose", "mouthPressLeft", "mouthPressRight", "mouthStretchLeft", "mouthStretchRight",
          "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight", "mouthLowerDownLeft",
          "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp")
#: The sample character's markers left out (53 of 68 kept, the 8 stable ones among them).
LEFT_OUT = ("forehead_L", "forehead_R", "cheekbone_L", "cheekbone_R", "jaw_L", "jaw_R", "jaw_angle_L", "jaw_angle_R",
            "jaw_front_L", "jaw_front_R", "nose_side_L", "nose_side_R", "chin_L", "chin_R", "nose_tip_C")
#: The stages of the report's ``timings_s`` shown, in order.
STAGES = ("read", "load_character", "stabilise", "solve", "key", "total")


def cli_env():
    """The environment of a ``python -m facecap`` child: this one without PYTHONPATH."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def _character(folder, markers):
    """The sample character with only ``SHAPES`` and the vertex groups of ``markers``, saved in ``folder``."""
    import bpy  # bpy: Blender starts on first import

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "character.blend"))
    face = bpy.data.objects["Face"]
    for block in [b for b in face.data.shape_keys.key_blocks[1:] if b.name not in SHAPES]:
        face.shape_key_remove(block)
    for group in [g for g in face.vertex_groups if g.name in LEFT_OUT]:
        face.vertex_groups.remove(group)
    path = Path(folder) / "character24.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def write_take(folder, frames):
    """The take, its config and the baseline's data: (config path, basis matrix (P, K), deltas (F, P))."""
    from ...solvers.tools.synthetic.synth import performance_weights, synthesize_take  # loads scipy

    folder = Path(folder)
    full = Basis.load_npz(ROOT / "sample_blends" / "character_basis.npz")
    layout = json.loads((ROOT / "sample_blends" / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    markers = [n for n in full.marker_names if n not in LEFT_OUT]
    k = [full.shape_names.index(n) for n in SHAPES]
    m = [full.marker_names.index(n) for n in markers]
    basis = Basis(SHAPES, tuple(markers), full.neutral[m], full.deltas[k][:, m], full.lower[k], full.upper[k])
    weights = performance_weights(SHAPES, frames, seed=5)
    take = synthesize_take(basis, weights, stable=stable, seed=6)
    write_markers_csv(folder / "take.csv", take.markers)
    blend = _character(folder, markers)
    config = folder / "take.toml"
    config.write_text(f'[target]\nblend = "{blend}"\nobject = "Face"\n[source]\nmarkers = "take.csv"\nunits = "mm"\n'
                      f'fps = 60\n[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 50]\n'
                      '[output]\nblend = "out.blend"\nweights = "out.csv"\nreport = "report.json"\n')
    rng = np.random.default_rng(7)
    deltas = np.einsum("fk,kmd->fmd", weights, basis.deltas) + rng.normal(0.0, 3e-4, (frames,) + basis.deltas.shape[1:])
    deltas[np.isnan(take.markers.positions)] = np.nan  # the take's gaps
    return config, basis.matrix(), deltas.reshape(frames, -1)


def bench_cli_stages(frames=36000, repeat=3):
    """Rows for ``bench``: each stage of the CLI retarget (median over ``repeat`` runs), then the
    whole run against the plain per-frame ``lsq_linear`` loop over the same take."""
    with tempfile.TemporaryDirectory(prefix="facecap-bench-cli-") as tmp:
        config, A, D = write_take(tmp, frames)
        size = (Path(tmp) / "take.csv").stat().st_size
        t0, c0 = time.perf_counter(), time.process_time()
        bvls_loop(A, D, 1e-3 * basis_scale(A))
        baseline, baseline_cpu = time.perf_counter() - t0, time.process_time() - c0
        walls, cpus, stages = [], [], {s: [] for s in STAGES}
        for _ in range(repeat):
            t0, c0 = time.perf_counter(), os.times()
            proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config), "--replace"],
                                  capture_output=True, text=True, env=cli_env())
            walls.append(time.perf_counter() - t0)
            c1 = os.times()  # the retarget's process tree: on a busy machine its CPU is what it cost
            cpus.append(c1.children_user - c0.children_user + c1.children_system - c0.children_system)
            if proc.returncode != 0:
                raise RuntimeError((proc.stderr.strip().splitlines() or ["no output"])[-1])
            timings = json.loads((Path(tmp) / "report.json").read_text())["timings_s"]
            for s in STAGES:
                stages[s].append(timings.get(s, float("nan")))
    name = f"CLI retarget {frames} frames x {len(SHAPES)} shapes x {A.shape[0] // 3} markers ({size / 2**20:.0f} MB CSV)"
    rows = [dict(name=f"{name}: {s}", seconds=statistics.median(v), baseline_seconds=None, ratio=None, goal="",
                 note=f"median of {repeat}, from the report's timings_s") for s, v in stages.items()]
    whole, cpu = statistics.median(walls), statistics.median(cpus)
    rows.append(dict(name=f"{name}, process start to saved .blend", seconds=whole, baseline_seconds=baseline,
                     ratio=baseline / whole, goal=">= 3x the plain per-frame loop",
                     note=f"median of {repeat} ({', '.join(f'{w:.2f}' for w in walls)} s); CPU of its processes "
                          f"{cpu:.2f} s ({baseline_cpu / cpu:.2f}x the loop's); baseline: one lsq_linear (bvls) per "
                          f"frame over the same take, {baseline:.2f} s wall, {baseline_cpu:.2f} s CPU, timed once in "
                          f"this run; 1-min load {os.getloadavg()[0]:.1f}"))
    return rows
