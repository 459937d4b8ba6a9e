"""``python -m facecap rig-bench``: the test rigs' figures, and the Rigify picture of docs/rigs.md.

* the control-rig sample: controls RMSE against solving the same take to the plain shape keys, and
  with correctives firing, the nonlinear solve against a linear one;
* the Rigify face: a real capture (c3dorg_29_Facial-Sing, bound by position) solved onto the Rigify
  face and onto the shape keys (mean marker residual of each), and a long take of known control
  curves: the time of the whole solve, probing included (wall and CPU, the median of ``repeat``
  runs), its controls RMSE and mean marker residual, and the ratios against the before-state
  (``BEFORE``: the same take solved by the code before the fast path) and, with ``reference``,
  against the slow reference path run here on the same take;
* ``--docs DIR``: frames of the Rigify face animated from the capture, rendered (Workbench) to
  ``DIR/rigify_face.png``.
Every take goes through a take config and ``headless.run_take``, as on the command line.
"""

import json
import statistics
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

from ...solvers.config import load_take_config
from ...solvers.io import write_markers
from ...solvers.io.images import read_tga, write_png
from ...solvers.tools.synthetic.realism.real_captures import FACIAL_SING_LANDMARKS, landmarks_toml
from ...solvers.tools.synthetic.synth import performance_weights, synthesize_points
from . import rig_samples, rig_samples_rigs
from ..rig import rig_target
from ..render.docs_images import compose
from ..headless.headless import run_take
from ..render.render_state import mark_rendered
from ..rig import rig_solve
from ..rig.rig_eval import RigEvaluator

ROOT = Path(__file__).resolve().parents[2]
CHARACTER = ROOT / "sample_blends" / "character.blend"
STABLE = ["head_forehead_C", "head_forehead_L", "head_forehead_R", "head_temple_L", "head_temple_R",
          "head_nose_bridge_C", "head_side_L", "head_side_R"]
FACIAL_SING_STABLE = ["root-1", "root-2", "root-3", "root-4", "root-5", "root-6"]
#: Facial-Sing bound by position with six landmarks (docs/binding.md): the Rigify face has no shape keys
#: for the automatic binding's motion test to judge its poses by, and the fit alone is ambiguous there.
FACIAL_SING_BINDING = '[binding]\nmode = "nearest"\n' + landmarks_toml(FACIAL_SING_LANDMARKS)
#: The 3,600-frame Rigify take (``control_curves(seed=3)``) solved by the code before the fast path
#: (commit eb369c7): medians of 3 runs (181.5 / 194.5 / 314.8 s wall) on the 2-core development
#: machine, shared with other test runs. Machine-dependent: ``--reference`` measures here instead.
BEFORE = {"frames": 3600, "seconds": 194.5, "cpu_seconds": 171.3, "controls_rmse": 0.0004272,
          "mean_residual_mm": 0.47925}


def open_character():
    bpy.ops.wm.open_mainfile(filepath=str(CHARACTER))
    return bpy.data.objects["Face"]


def control_curves(controls, n_frames, *, seed=0, rest=60):
    """Known control curves: smooth bumps within 60 % of each control's range, at rest at both ends."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)
    out = np.zeros((n_frames, len(controls)))
    bumps = max(2, n_frames // 200)
    for j, c in enumerate(controls):
        for _ in range(bumps):
            centre, width = rng.uniform(rest + 30, n_frames - rest - 30), rng.uniform(30, 80)
            side = c.upper if rng.uniform() < 0.5 or c.lower == c.rest else c.lower
            out[:, j] += 0.6 * rng.uniform(0.3, 1.0) * (side - c.rest) * np.exp(-0.5 * ((t - centre) / (width / 4)) ** 2)
    lo, hi = np.array([c.lower for c in controls]), np.array([c.upper for c in controls])
    return np.clip(out + np.array([c.rest for c in controls]), lo, hi)


def write_take(folder, mesh, controls, values, *, seed=5):
    """The marker take of the rig on ``mesh`` performing ``values`` (F, C) -> (evaluator, bound points)."""
    evaluator = RigEvaluator(mesh, controls, [g.name for g in mesh.vertex_groups])
    points = evaluator.evaluate(values)
    evaluator.close()
    take = synthesize_points(evaluator.marker_names, points, values, stable=STABLE, seed=seed)
    write_markers(Path(folder) / "take.csv", take.markers)
    return evaluator, points


def take_config(folder, name, obj, *, markers="take.csv", source='units = "mm"\nfps = 60\n', stable=STABLE,
                neutral=(1, 50), rig="", extra="", outputs="", blend="rig.blend"):
    """A take config in ``folder`` solving ``markers`` onto ``obj`` of ``folder/<blend>``."""
    path = Path(folder) / f"{name}.toml"
    path.write_text(f'[target]\nblend = "{blend}"\nobject = "{obj}"\n[source]\nmarkers = "{markers}"\n{source}'
                    f'[stabilise]\nmarkers = {json.dumps(stable)}\n[neutral]\nframes = {list(neutral)}\n{extra}{rig}'
                    f'[output]\nweights = "{name}.csv"\n{outputs}')
    return load_take_config(path)


def columns(result, names):
    return result.weights[:, [result.shape_names.index(n) for n in names]]


def rmse(a, b):
    return float(np.sqrt(np.nanmean((np.asarray(a) - np.asarray(b)) ** 2)))


def control_rig_figures(folder, frames, say):
    """Controls RMSE of the control-rig sample against the plain keys; correctives, nonlinear vs linear."""
    out = {}
    for correctives in (False, True):
        sub = Path(folder) / f"control_rig_{int(correctives)}"
        sub.mkdir()
        mesh = open_character()
        ctrl = rig_samples.build_control_rig(mesh, correctives=correctives)
        controls = rig_target.preset_controls("arkit_sliders", mesh, ctrl)
        names = [c.name for c in controls]
        weights = performance_weights(names, frames, seed=4)
        sliders = rig_samples.sliders_for_weights(names, weights)
        write_take(sub, mesh, controls, sliders)
        bpy.ops.wm.save_as_mainfile(filepath=str(sub / "rig.blend"))
        mesh.data.shape_keys.animation_data_clear()  # the same face's plain keys: no driver sets them
        bpy.ops.wm.save_as_mainfile(filepath=str(sub / "plain.blend"))
        rig = '[rig]\npreset = "arkit_sliders"\nobject = "FaceControls"\n'
        if not correctives:
            t0 = time.perf_counter()
            solved = run_take(take_config(sub, "rig", "Face", rig=rig), quiet=True)[0]
            seconds = time.perf_counter() - t0
            plain = run_take(take_config(sub, "plain", "Face", blend="plain.blend"), quiet=True)[0]
            out["control_rig"] = {"controls_rmse": rmse(columns(solved, names), sliders),
                                  "shape_keys_rmse": rmse(columns(plain, names), weights), "seconds": seconds}
            say(f"control rig: controls RMSE {out['control_rig']['controls_rmse']:.4f}, plain shape keys "
                f"{out['control_rig']['shape_keys_rmse']:.4f}")
            continue
        index = {n: i for i, n in enumerate(names)}
        firing = np.zeros(frames, dtype=bool)
        for _, (a, b), _ in rig_samples.CORRECTIVES:
            firing |= sliders[:, index[a]] * sliders[:, index[b]] > 0.05
        errors = {}
        for nonlinear in (False, True):
            result = run_take(take_config(sub, f"nl{int(nonlinear)}", "Face",
                                          rig=rig + f"nonlinear = {str(nonlinear).lower()}\n"), quiet=True)[0]
            errors[nonlinear] = rmse(columns(result, names)[firing], sliders[firing])
        out["correctives"] = {"linear_rmse": errors[False], "nonlinear_rmse": errors[True],
                              "frames_firing": int(firing.sum())}
        say(f"correctives firing ({int(firing.sum())} frames): linear {errors[False]:.4f}, nonlinear {errors[True]:.4f}")
    return out


def _timed_solves(folder, face_name, rig_section, controls, truth, repeat, name="long"):
    """The long take solved ``repeat`` times: median wall and CPU seconds, accuracy of the last."""
    walls, cpus = [], []
    for _ in range(max(1, repeat)):
        t0, c0 = time.perf_counter(), time.process_time()
        solved = run_take(take_config(folder, name, face_name, rig=rig_section), quiet=True, overwrite=True)[0]
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    got = columns(solved, [c.name for c in controls])
    return {"frames": int(solved.frames.size), "seconds": statistics.median(walls),
            "cpu_seconds": statistics.median(cpus), "runs_seconds": walls,
            "probing_seconds": solved.info["rig"]["seconds"], "probes": solved.info["rig"]["probes"],
            "refined_frames": solved.info["rig"].get("refined_frames"), "controls_rmse": rmse(got, truth),
            "mean_residual_mm": float(np.nanmean(solved.residual_rms) * 1e3)}


def rigify_figures(folder, capture, frames, say, docs=None, *, repeat=1, reference=False, long_only=False):
    """The Rigify face: a long take of known curves (time, accuracy; ``repeat`` runs, the medians;
    ``reference``: also the slow reference path) and a real capture against the shape keys."""
    out = {}
    mesh = open_character()
    t0 = time.perf_counter()
    face, rig = rig_samples_rigs.build_rigify_face(mesh)
    out["generate_seconds"] = time.perf_counter() - t0
    face_name, controls = face.name, rig_target.preset_controls("rigify_face", face, rig)
    long_take = control_curves(controls, frames, seed=3)
    write_take(folder, face, controls, long_take)
    bpy.ops.wm.save_as_mainfile(filepath=str(Path(folder) / "rig.blend"))
    rig_section = '[rig]\npreset = "rigify_face"\nobject = "rig"\n'
    out["long_take"] = long = _timed_solves(folder, face_name, rig_section, controls, long_take, repeat)
    say(f"rigify: {frames} frames solved in {long['seconds']:.1f} s wall, {long['cpu_seconds']:.1f} s CPU "
        f"(median of {repeat}; probing {long['probing_seconds']:.1f} s, {long['probes']} probes); controls RMSE "
        f"{long['controls_rmse']:.6f}, mean residual {long['mean_residual_mm']:.4f} mm")
    if frames == BEFORE["frames"] and BEFORE["seconds"]:
        long["before_state"] = {**BEFORE, "speedup_wall": BEFORE["seconds"] / long["seconds"],
                                "speedup_cpu": BEFORE["cpu_seconds"] / long["cpu_seconds"]}
        say(f"rigify: {long['before_state']['speedup_wall']:.1f}x faster than the before-state "
            f"({BEFORE['seconds']:.1f} s wall, {BEFORE['cpu_seconds']:.1f} s CPU, controls RMSE "
            f"{BEFORE['controls_rmse']:.6f}, residual {BEFORE['mean_residual_mm']:.4f} mm)")
    if reference:
        rig_solve.REFERENCE = True
        try:
            ref = _timed_solves(folder, face_name, rig_section, controls, long_take, 1, name="reference")
        finally:
            rig_solve.REFERENCE = False
        long["reference"] = {**ref, "speedup_wall": ref["seconds"] / long["seconds"],
                             "speedup_cpu": ref["cpu_seconds"] / long["cpu_seconds"]}
        say(f"rigify: the reference path {ref['seconds']:.1f} s wall, {ref['cpu_seconds']:.1f} s CPU "
            f"({long['reference']['speedup_wall']:.1f}x / {long['reference']['speedup_cpu']:.1f}x the fast path's "
            f"time); controls RMSE {ref['controls_rmse']:.6f}, residual {ref['mean_residual_mm']:.4f} mm")
    if long_only:
        return out
    if capture is not None:
        sing = dict(markers=str(capture), source="", stable=FACIAL_SING_STABLE, neutral=(1, 100),
                    extra=FACIAL_SING_BINDING)
        res = {}
        for name, obj, rig_text in (("keys", "Face", ""), ("rigify", face_name, rig_section)):
            res[name] = run_take(take_config(folder, f"sing_{name}", obj, rig=rig_text, **sing,
                                             outputs=f'blend = "sing_{name}.blend"\n'), quiet=True)[0]
        keys_mm, rig_mm = (float(np.nanmean(res[n].residual_rms) * 1e3) for n in ("keys", "rigify"))
        out["capture"] = {"frames": int(res["rigify"].frames.size), "shape_keys_residual_mm": keys_mm,
                          "rigify_residual_mm": rig_mm, "ratio": rig_mm / keys_mm}
        say(f"capture: mean marker residual {rig_mm:.3f} mm on the Rigify face, {keys_mm:.3f} mm on the shape keys "
            f"({rig_mm / keys_mm:.2f}x)")
        if docs is not None:
            out["picture"] = str(render_rigify(Path(folder) / "sing_rigify.blend", face_name, res["rigify"],
                                               Path(docs) / "rigify_face.png"))
    return out


def render_rigify(blend, face_name, result, path, *, count=5, size=(190, 216)):
    """Frames of the keyed Rigify face (Workbench, front view), the busiest of the take, side by side."""
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    scene = bpy.context.scene
    face = bpy.data.objects[face_name]
    for obj in scene.objects:
        obj.hide_render = obj is not face
    activity = np.nansum(np.abs(result.weights - np.nanmedian(result.weights[:100], axis=0)), axis=1)
    picks = [int(result.frames[0])]
    for i in np.argsort(-activity):
        if all(abs(result.frames[i] - p) > result.frames.size / (2 * count) for p in picks):
            picks.append(int(result.frames[i]))
        if len(picks) == count:
            break
    render = scene.render
    render.engine = "BLENDER_WORKBENCH"
    render.resolution_x, render.resolution_y = size
    render.film_transparent = True
    render.image_settings.file_format = "TARGA_RAW"
    render.image_settings.color_mode = "RGBA"
    scene.display.shading.light, scene.display.shading.color_type = "STUDIO", "MATERIAL"
    world = np.array(face.matrix_world)
    corners = np.array(face.bound_box) @ world[:3, :3].T + world[:3, 3]
    centre, height = corners.mean(axis=0), np.ptp(corners[:, 2])
    cam = bpy.data.objects.new("RigCamera", bpy.data.cameras.new("RigCamera"))
    cam.data.type, cam.data.ortho_scale = "ORTHO", height * 1.05
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location = (centre[0], centre[1] - 2.0, centre[2])
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    tiles = []
    with tempfile.TemporaryDirectory(prefix="facecap-rig-") as tmp:
        for frame in picks:
            scene.frame_set(frame)
            render.filepath = str(Path(tmp) / "tile.tga")
            mark_rendered()  # a review page forked from here could not render
            bpy.ops.render.render(write_still=True)
            tiles.append(read_tga(Path(tmp) / "tile.tga"))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, compose(tiles, len(tiles)))
    return path
