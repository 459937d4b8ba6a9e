"""Blender-side benchmarks: bulk keying vs a keyframe_insert loop, the whole CLI retarget, and batch
throughput against sequential retarget runs (``bench --batch``).

Run through ``python -m facecap bench`` (with the solver cases). Times are medians; baselines
timed on a subset are scaled per key or per frame.
"""

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ...solvers.character.basis import Basis
from ...solvers.io.csv import write_markers_csv
from ...solvers.tools.bench.bench import median_time
from ...solvers.tools.bench.peak_memory import available, run_measured
from .cli_bench import bench_cli_stages, cli_env

ROOT = Path(__file__).resolve().parents[2]


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
    from ..scene import anim  # loads bpy

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


#: Frames per synthetic piece of a long take: longer takes are pieces like it, one after the other.
PIECE_FRAMES = 36000


def write_long_take(folder, frames):
    """A long synthetic take of the sample character in ``folder``: ``long_take.csv`` and the take
    config ``long_take.toml`` (outputs beside them). Takes longer than ``PIECE_FRAMES`` are pieces of
    that length with their own head motion, noise and gaps (seeds 6, 7, ...) on the same performance
    (it starts and ends at rest, so the pieces join smoothly; the head jumps back to rest between
    pieces). Written piece by piece: the bench's own memory stays that of one piece.
    Returns the config path."""
    from ...solvers.tools.synthetic.synth import performance_weights, synthesize_take  # loads scipy

    folder = Path(folder)
    samples = ROOT / "sample_blends"
    basis = Basis.load_npz(samples / "character_basis.npz")
    layout = json.loads((samples / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    weights = performance_weights(basis.shape_names, min(frames, PIECE_FRAMES), seed=5)
    csv = folder / "long_take.csv"
    piece_csv = folder / "piece.csv"
    with open(csv, "w", encoding="utf-8") as out:
        for i, first in enumerate(range(0, frames, PIECE_FRAMES)):
            n = min(PIECE_FRAMES, frames - first)
            take = synthesize_take(basis, weights[:n], stable=stable, seed=6 + i)
            write_markers_csv(piece_csv, dataclasses.replace(take.markers, frames=take.markers.frames + first))
            with open(piece_csv, encoding="utf-8") as fh:
                header = fh.readline()
                if i == 0:
                    out.write(header)
                for block in iter(lambda: fh.read(1 << 24), ""):
                    out.write(block)
    piece_csv.unlink()
    config = folder / "long_take.toml"
    config.write_text(
        f'[target]\nblend = "{samples / "character.blend"}"\nobject = "Face"\n'
        f'[source]\nmarkers = "long_take.csv"\nunits = "mm"\nfps = 60\n'
        f"[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 50]\n"
        f'[output]\nblend = "out.blend"\nweights = "out.csv"\nreport = "report.json"\n'
    )
    return config


def bench_cli_retarget(frames=36000, repeat=3):
    """Rows: ``python -m facecap retarget`` on a long synthetic take of the sample character, process start
    to saved .blend, the median of ``repeat`` runs (one run varies by seconds on a shared machine); then
    a smaller character's take stage by stage against the plain per-frame loop (``cli_bench``)."""
    basis = Basis.load_npz(ROOT / "sample_blends" / "character_basis.npz")
    with tempfile.TemporaryDirectory(prefix="facecap-bench-") as tmp:
        tmp = Path(tmp)
        config = write_long_take(tmp, frames)
        env = cli_env()

        def once():
            # --replace: every run the same work (without it, a run adds its solve to the last one's .blend)
            proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config), "--replace"],
                                  capture_output=True, text=True, env=env)
            if proc.returncode != 0:
                raise RuntimeError(proc.stderr.strip().splitlines()[-1])

        seconds = median_time(once, repeat)[0]
        stages = json.loads((tmp / "report.json").read_text())["timings_s"]  # the last run's
    detail = ", ".join(f"{k} {v:.2f} s" for k, v in stages.items() if k in ("read", "load_character", "stabilise", "solve", "key", "total"))
    return [dict(
        name=f"CLI retarget {frames} frames x {basis.n_shapes} shapes x {basis.n_markers} markers (process start to saved .blend)",
        seconds=seconds, baseline_seconds=None, ratio=None, goal="< 15 s",
        note=f"median of {repeat} runs; stages of the last: {detail}",
    )] + bench_cli_stages(frames, repeat)


def bench_batch(takes=20, frames=720, jobs=2, repeat=3):
    """``batch --jobs N`` on ``takes`` synthetic takes of ``frames`` frames against the same takes run by
    ``takes`` sequential ``python -m facecap retarget`` processes, process start to last saved .blend.
    Runs are interleaved (sequential, batch, batch --jobs 1, ...) so that a busy spell of a shared
    machine hits all of them; medians of ``repeat``. Also reports the CPU seconds used (children's)."""
    from ...solvers.tools.synthetic.synth import (  # loads scipy
        performance_weights,
        synthesize_take,
    )

    samples = ROOT / "sample_blends"
    basis = Basis.load_npz(samples / "character_basis.npz")
    layout = json.loads((samples / "marker_layout.json").read_text())
    stable = [m["name"] for m in layout["markers"] if m["stable"]]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    with tempfile.TemporaryDirectory(prefix="facecap-bench-batch-") as tmp:
        tmp = Path(tmp)
        for i in range(takes):
            weights = performance_weights(basis.shape_names, frames, seed=100 + i)
            take = synthesize_take(basis, weights, stable=stable, seed=200 + i)
            write_markers_csv(tmp / f"take{i:02d}.csv", take.markers)
            (tmp / f"take{i:02d}.toml").write_text(
                f'[target]\nblend = "{samples / "character.blend"}"\nobject = "Face"\n'
                f'[source]\nmarkers = "take{i:02d}.csv"\nunits = "mm"\nfps = 60\n'
                f"[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = [1, 50]\n"
                f'[output]\nblend = "out/take{i:02d}.blend"\nweights = "out/take{i:02d}.csv"\n'
                f'report = "out/take{i:02d}.json"\n')
        configs = sorted(tmp.glob("take*.toml"))

        def timed(commands):
            shutil.rmtree(tmp / "out", ignore_errors=True)  # every run writes new outputs (no adding)
            c0 = os.times()  # children's CPU: the retarget processes, the batch and its workers
            t0 = time.perf_counter()
            for command in commands:
                proc = subprocess.run([sys.executable, "-m", "facecap", *command], capture_output=True, text=True,
                                      env=env, cwd=tmp)
                if proc.returncode != 0:
                    raise RuntimeError((proc.stderr.strip().splitlines() or ["no output"])[-1])
            c1 = os.times()
            cpu = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
            return time.perf_counter() - t0, cpu

        cases = {"sequential": [["retarget", "--config", str(c)] for c in configs],
                 f"jobs{jobs}": [["batch", *map(str, configs), "--jobs", str(jobs), "--summary", "s.json"]],
                 "jobs1": [["batch", *map(str, configs), "--jobs", "1", "--summary", "s.json"]]}
        load = [os.getloadavg()[0]]
        runs = {name: [] for name in cases}
        for _ in range(repeat):
            for name, commands in cases.items():
                runs[name].append(timed(commands))
        load.append(os.getloadavg()[0])
    wall = {name: float(np.median([w for w, _ in r])) for name, r in runs.items()}
    cpu = {name: float(np.median([c for _, c in r])) for name, r in runs.items()}
    seq, par = wall["sequential"], wall[f"jobs{jobs}"]
    return dict(
        name=f"batch --jobs {jobs}: {takes} takes x {frames} frames (process start to last saved .blend)",
        seconds=par, baseline_seconds=seq, ratio=seq / par, goal=">= 3x vs sequential retarget runs",
        note=(f"{seq / par:.2f}x; median of {repeat} interleaved runs; sequential {seq:.1f} s, "
              f"--jobs 1 {wall['jobs1']:.1f} s ({seq / wall['jobs1']:.1f}x), --jobs {jobs} {par:.1f} s; "
              f"CPU s (children) sequential {cpu['sequential']:.1f}, "
              f"--jobs 1 {cpu['jobs1']:.1f}, --jobs {jobs} {cpu[f'jobs{jobs}']:.1f}; "
              f"{len(os.sched_getaffinity(0))} cores, 1-min load {load[0]:.1f} before, {load[1]:.1f} after"),
    )


#: Takes of the memory case (frames): 10 and 100 minutes at 60 fps.
MEMORY_FRAMES = (36000, 360000)
#: Goal for the process tree's peak PSS on the 360,000-frame take (bytes): "about 3 GB" (issue 18).
MEMORY_GOAL = 3_000_000_000


def bench_memory(frames=MEMORY_FRAMES):
    """Peak memory of ``python -m facecap retarget`` (the whole process tree) on long takes of the
    sample character, one run per length: the summed RSS and PSS of the tree (see
    ``solvers.tools.bench.peak_memory``), the main process's own peak, and the growth per frame between
    the shortest and longest take. Returns a list of rows (one per take, then the growth), each
    with a printable ``line``."""
    if not available():
        return [dict(line="memory: skipped (needs Linux /proc)")]
    shapes = Basis.load_npz(ROOT / "sample_blends" / "character_basis.npz").n_shapes
    rows, peaks = [], []
    for n in frames:
        with tempfile.TemporaryDirectory(prefix="facecap-bench-mem-") as tmp:
            config = write_long_take(tmp, n)
            size = (Path(tmp) / "long_take.csv").stat().st_size
            m = run_measured([sys.executable, "-m", "facecap", "retarget", "--config", str(config)], env=cli_env())
        if m["returncode"] != 0:
            raise RuntimeError(f"retarget of {n} frames failed: {m['stderr'][-1] if m['stderr'] else m['returncode']}")
        if m["killed"]:
            raise RuntimeError(f"retarget of {n} frames stopped: the machine ran short of memory")
        peaks.append((n, m))
        stages = ", ".join(f"{' '.join(k.split(' ')[:2])} {v['pss'] / 2**30:.2f}/{v['rss'] / 2**30:.2f}"
                           for k, v in m["stages"].items() if k != "start")
        rows.append(dict(
            frames=n, seconds=m["seconds"], tree_rss=m["tree_rss"], tree_pss=m["tree_pss"], main_rss=m["main_rss"],
            stages=m["stages"],
            line=(f"memory: CLI retarget {n} frames x {shapes} shapes ({size / 2**20:.0f} MB CSV), one run of "
                  f"{m['seconds']:.0f} s: peak of the process tree {m['tree_pss'] / 2**30:.2f} GiB PSS, "
                  f"{m['tree_rss'] / 2**30:.2f} GiB summed RSS ({m['procs']} process{'es' if m['procs'] > 1 else ''}); main process "
                  f"{m['main_rss'] / 2**30:.2f} GiB; per stage, PSS/RSS GiB: {stages}"),
        ))
    if len(peaks) > 1:
        (n0, a), (n1, b) = peaks[0], peaks[-1]
        per = {k: (b[k] - a[k]) / (n1 - n0) / 1024 for k in ("tree_pss", "tree_rss", "main_rss")}
        rows.append(dict(line=(f"memory growth {n0} -> {n1} frames: {per['tree_pss']:.2f} KiB a frame (tree PSS), "
                               f"{per['tree_rss']:.2f} (summed RSS), {per['main_rss']:.2f} (main process); goal: "
                               f"linear growth, and about {MEMORY_GOAL / 1e9:.0f} GB of tree PSS at 360000 frames "
                               f"({MEMORY_GOAL / 2**30:.2f} GiB); {n1} frames: {b['tree_pss'] / 1e9:.2f} GB")))
    return rows
