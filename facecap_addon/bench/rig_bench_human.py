"""``rig-bench``'s whole Rigify human (``rig_samples_rigs.build_rigify_human``) against the head-only rig.

* the cost of one pose while probing (CPU, the median of ``repeat`` runs of 200 random poses) on the
  head-only Rigify face and on the whole human, in the same run, and on the human without the proxy
  armature (``rig_proxy``: the whole armature evaluated, as before); the three take turns, a run of
  each per round (each saved once and opened again), and the human's ratio to the head-only rig is
  the median of the rounds' ratios, so that the machine's load falls on both alike;
* the real capture c3dorg_29_Facial-Sing solved onto the human's face and onto the same face's shape
  keys: wall and CPU time, the time of each stage (probing, the solve), the mean marker residual.
"""

import statistics
import time
from pathlib import Path

import bpy
import numpy as np

from . import rig_samples_rigs
from ..headless.headless import run_take
from ..rig import rig_proxy, rig_target
from ..rig.rig_eval import RigEvaluator
from .rig_bench import FACIAL_SING_BINDING, FACIAL_SING_STABLE, open_character, take_config
from .rig_samples import marker_points

RIG = '[rig]\npreset = "rigify_face"\nobject = "rig"\n'


def pose_cost(face, rig, markers, *, poses=200, repeat=3, proxy=True):
    """Median CPU milliseconds per pose of the evaluator's fast path on random control values."""
    controls = rig_target.preset_controls("rigify_face", face, rig)
    use, rig_proxy.USE = rig_proxy.USE, proxy
    try:
        evaluator = RigEvaluator(face, controls, markers)
    finally:
        rig_proxy.USE = use
    rng = np.random.default_rng(0)
    values = rng.uniform([c.lower for c in controls], [c.upper for c in controls], size=(poses, len(controls)))
    cpu = []
    for _ in range(repeat):
        c0 = time.process_time()
        evaluator.evaluate(values)
        cpu.append((time.process_time() - c0) / poses * 1e3)
    evaluated = len(evaluator.posed.pose.bones)
    evaluator.close()
    return {"ms": statistics.median(cpu), "runs_ms": cpu, "bones": len(rig.pose.bones), "evaluated_bones": evaluated,
            "deforming_bones": len(evaluator.bones)}


def _take_turns(cases, markers, repeat):
    """``pose_cost`` of each case (name -> (blend, face, rig, proxy)), one run of each per round."""
    runs = {name: [] for name in cases}
    for _ in range(repeat):
        for name, (blend, face, rig, proxy) in cases.items():
            bpy.ops.wm.open_mainfile(filepath=str(blend))
            runs[name].append(pose_cost(bpy.data.objects[face], bpy.data.objects[rig], markers, repeat=1,
                                        proxy=proxy))
    return {name: dict(r[0], ms=statistics.median(x["ms"] for x in r), runs_ms=[x["ms"] for x in r])
            for name, r in runs.items()}


def human_figures(folder, capture, say, *, repeat=3):
    """The head-only rig and the whole human: cost per pose, and Facial-Sing onto the human."""
    folder = Path(folder)
    mesh = open_character()
    markers = list(marker_points(mesh))
    face, rig = rig_samples_rigs.build_rigify_face(mesh)
    head = (folder / "head_only.blend", face.name, rig.name)
    bpy.ops.wm.save_as_mainfile(filepath=str(head[0]))
    mesh = open_character()
    face, rig = rig_samples_rigs.build_rigify_human(mesh)
    face_name = face.name
    human = (folder / "rig.blend", face.name, rig.name)
    bpy.ops.wm.save_as_mainfile(filepath=str(human[0]))
    out = _take_turns({"head_only": (*head, True), "human": (*human, True), "human_whole_armature": (*human, False)},
                      markers, repeat)
    # paired by round: the load of the shared machine moves both runs of a round alike
    out["round_ratios"] = [h / f for h, f in zip(out["human"]["runs_ms"], out["head_only"]["runs_ms"])]
    out["ratio"] = statistics.median(out["round_ratios"])
    rounds = ", ".join(f"{r:.2f}" for r in out["round_ratios"])
    say(f"rigify human: {out['human']['ms']:.2f} ms CPU a pose ({out['human']['evaluated_bones']} of "
        f"{out['human']['bones']} bones evaluated) against {out['head_only']['ms']:.2f} ms on the head-only rig "
        f"({out['ratio']:.2f}x, the median of the rounds' ratios {rounds}); "
        f"the whole armature {out['human_whole_armature']['ms']:.2f} ms "
        f"({out['human_whole_armature']['ms'] / out['head_only']['ms']:.2f}x); medians of {repeat} rounds")
    if capture is None:
        return out
    sing = dict(markers=str(capture), source="", stable=FACIAL_SING_STABLE, neutral=(1, 100), extra=FACIAL_SING_BINDING)
    res = {}
    for name, obj, rig_text in (("keys", "Face", ""), ("human", face_name, RIG)):
        t0, c0 = time.perf_counter(), time.process_time()
        result = run_take(take_config(folder, f"sing_{name}", obj, rig=rig_text, **sing), quiet=True,
                          overwrite=True)[0]
        res[name] = {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                     "residual_mm": float(np.nanmean(result.residual_rms) * 1e3),
                     "stages": {k: round(v, 2) for k, v in result.timings.items()}}
        if name == "human":
            info = result.info["rig"]
            res[name].update(probing_seconds=info["seconds"], probes=info["probes"], converged=info.get("converged"),
                             iterations=info.get("iterations"), refined_frames=info.get("refined_frames"),
                             warnings=list(result.warnings))
    res["frames"] = int(result.frames.size)
    res["ratio"] = res["human"]["residual_mm"] / res["keys"]["residual_mm"]
    out["capture"] = res
    h, k = res["human"], res["keys"]
    say(f"capture onto the rigify human ({res['frames']} frames): {h['seconds']:.1f} s wall, {h['cpu_seconds']:.1f} s "
        f"CPU (probing {h['probing_seconds']:.1f} s, {h['probes']} poses; the solve converged: {h['converged']}), "
        f"residual {h['residual_mm']:.3f} mm; onto the shape keys {k['seconds']:.1f} s, {k['residual_mm']:.3f} mm "
        f"({res['ratio']:.2f}x)")
    return out
