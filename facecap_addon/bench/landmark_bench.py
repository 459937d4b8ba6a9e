"""``python -m facecap bench --landmarks``: face landmarks judged on rendered footage of a real face.

The ICT face (``shared/data/ict-facekit``) performs a real Live Link Face recording
(``shared/data/realdata/llf``) from a relaxed start: its ARKit weights, its head turns and its gaze,
filmed off-axis under a key light to one side and written as H.264 (``face_footage``). The footage alone
goes through a four-section take config (``[tracking] method = "landmarks"``) onto another ICT identity
and onto the sample character, and the solved weights are compared with the recording's, per region.
Speed: frames per second of the landmarks on the clip, decoding included, and their CPU time per frame.

The shared data folder is ``$FACECAP_SHARED``, else ``shared/`` beside the checkout.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ...solvers.character.face_model import load_ict
from ...solvers.config import load_take_config
from ...solvers.io.weights import read_weights
from ...solvers.video.landmarks import track_landmarks
from ..render.face_footage import Shot, render_face_clip
from ..headless.headless import run_take

#: Face regions and the ARKit shapes whose weights are judged in each.
REGIONS = {
    "brows": ("browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight"),
    "lids": ("eyeBlinkLeft", "eyeBlinkRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight"),
    "gaze": tuple(f"eyeLook{d}{s}" for s in ("Left", "Right") for d in ("Up", "Down", "In", "Out")),
    "cheeks_nose": ("cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight"),
    "jaw": ("jawForward", "jawLeft", "jawRight", "jawOpen"),
    "mouth": ("mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft",
              "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight",
              "mouthStretchLeft", "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
              "mouthShrugUpper", "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
              "mouthUpperUpLeft", "mouthUpperUpRight"),
}
#: Shapes a camera cannot see: the tongue, and a cheek puff (the face's outline barely changes from the front).
UNSEEN = ("tongueOut", "cheekPuff")


def shared_folder():
    env = os.environ.get("FACECAP_SHARED")
    return Path(env).expanduser() if env else Path(__file__).resolve().parents[3] / "shared"


def ict_arrays(path):
    """(neutral (V, 3), quads, ARKit shape names, deltas (K, V, 3), identity modes (I, V, 3)) of the ICT face file
    ``path``: metres, Z up, the face looking down -Y (``solvers.character.face_model``)."""
    m = load_ict(path)
    return m.neutral, m.polygons, m.shape_names, m.deltas, m.identity


def performance(path, names, *, start, frames, hold, fps=30.0):
    """A Live Link Face segment as (weights (F, K) on ``names``, head (F, 6), gaze (F, 2, 2)): ``hold``
    frames of a relaxed face easing into ``frames`` of the recording from its frame ``start``."""
    track = read_weights(path)
    step = max(1, int(round(track.fps / fps)))
    rows = np.r_[np.full(hold, start), start + step * np.arange(frames)]
    ease = np.clip(np.arange(len(rows)) / max(hold, 1) * 2.0 - 1.0, 0.0, 1.0)[:, None]
    weights = np.zeros((len(rows), len(names)))
    for k, name in enumerate(names):
        if name in track.names:
            weights[:, k] = np.nan_to_num(track.values[rows, track.names.index(name)])
    head = np.zeros((len(rows), 6))
    head[:, :3] = np.nan_to_num(track.head[rows]) * [1.0, -1.0, 1.0]  # yaw, pitch, roll as the renderer turns
    eyes = np.nan_to_num(track.eyes[rows])  # left yaw/pitch/roll, right yaw/pitch/roll
    gaze = np.stack([eyes[:, [3, 4]], eyes[:, [0, 1]]], axis=1) * [-1.0, 1.0]  # right, left; yaw to the left
    return weights * ease, head * ease, gaze * ease[..., None]


def region_table(solved_path, truth, names, *, skip=0):
    """{region: weights RMSE} over the shapes of :data:`REGIONS` the solve has, plus "visible" (every
    judged shape) and the eyeBlink peaks (solved, where the truth is above 0.7); frames from ``skip``."""
    solved = read_weights(solved_path)
    got = {n: solved.values[skip:, solved.names.index(n)] for n in names if n in solved.names}
    want = {n: truth[skip:, names.index(n)] for n in names}
    out, every = {}, []
    for region, shapes in REGIONS.items():
        errs = [np.nanmean((got[s] - want[s]) ** 2) for s in shapes if s in got and s in want]
        every += errs
        out[region] = float(np.sqrt(np.mean(errs))) if errs else float("nan")
    out["visible"] = float(np.sqrt(np.mean(every)))
    for side in ("Left", "Right"):
        closed = want[f"eyeBlink{side}"] > 0.7
        out[f"blink{side}_peak"] = float(np.nanmax(got[f"eyeBlink{side}"][closed])) if closed.any() else float("nan")
    return out


def run(out_dir, *, frames=300, start=1500, hold=45, recording="llf_alex_rom_3.csv", identity_seed=7, log=print):
    """Render, retarget onto another ICT identity and the sample character, print and return the tables."""
    shared = shared_folder() / "data"
    neutral, quads, names, deltas, identity = ict_arrays(shared / "ict-facekit" / "ict_face.npz")
    weights, head, gaze = performance(shared / "realdata" / "llf" / recording, names, start=start, frames=frames,
                                      hold=hold)
    out = Path(out_dir)
    clip = out / "ict.mp4"
    t = time.perf_counter()
    render_face_clip(clip, neutral, quads, deltas, weights, head=head, gaze=gaze, shot=Shot(distance=0.5))
    log(f"rendered {len(weights)} frames in {time.perf_counter() - t:.0f} s: {clip}")
    log(speed_line(clip))
    person = ict_character(out / "person.blend", neutral, quads, names, deltas, identity, identity_seed)
    sample = Path(__file__).resolve().parents[2] / "sample_blends" / "character.blend"
    tables = {}
    for label, blend, obj in (("ICT identity", person, "ICT"), ("sample character", sample, "Face")):
        config = out / f"{label.split()[0].lower()}.toml"
        solved = config.with_suffix(".csv")
        config.write_text(f'[target]\nblend = "{blend}"\nobject = "{obj}"\n[source]\nvideo = "{clip.name}"\n'
                          f'[tracking]\nmethod = "landmarks"\n[output]\nweights = "{solved.name}"\n', encoding="utf-8")
        c0, t0 = time.process_time(), time.perf_counter()
        run_take(load_take_config(config), quiet=True)
        tables[label] = region_table(solved, weights, names, skip=hold)
        log(f"{label}: " + ", ".join(f"{k} {v:.3f}" for k, v in tables[label].items())
            + f" ({time.perf_counter() - t0:.0f} s, CPU {time.process_time() - c0:.0f} s)")
    return tables


def speed_line(clip):
    """Landmarks of ``clip`` timed: frames/s (decoding included) and CPU ms per frame of the process."""
    c0, t0 = time.process_time(), time.perf_counter()
    found = track_landmarks(clip, smoothing=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = len(found.found)
    return (f"landmarks: {n / wall:.0f} frames/s ({n} frames, decoding included), {1000 * cpu / n:.1f} ms of CPU "
            f"per frame over all threads, {os.cpu_count()} cores")


def ict_character(path, neutral, quads, names, deltas, identity, seed, modes=20, name="ICT"):
    """Save the ICT identity drawn from ``seed`` (``modes`` coefficients) as a .blend with one object
    ``name`` and a shape key per expression (Blender starts afresh); returns the path."""
    import bpy  # bpy: Blender starts on first import

    person = neutral + np.einsum("i,ivd->vd", np.random.default_rng(seed).normal(size=modes), identity[:modes])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(person.tolist(), [], quads.tolist())
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.shape_key_add(name="Basis")
    for name, delta in zip(names, deltas):
        obj.shape_key_add(name=name).data.foreach_set("co", (person + delta).astype(np.float32).ravel())
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def main(argv=None):
    parser = argparse.ArgumentParser(prog="facecap bench --landmarks")
    parser.add_argument("--frames", type=int, default=300, help="frames of the recording (default 300, at 30 fps)")
    parser.add_argument("--start", type=int, default=1500, help="its first frame (default 1500)")
    parser.add_argument("--out", default=None, help="keep the clip, configs and solves here")
    args = parser.parse_args(argv)
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        run(args.out, frames=args.frames, start=args.start)
    else:
        with tempfile.TemporaryDirectory() as d:
            run(d, frames=args.frames, start=args.start)
    return 0
