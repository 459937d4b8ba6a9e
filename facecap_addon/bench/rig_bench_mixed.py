"""``rig-bench``'s mixed control rig (``rig_samples_mixed``): bones in metres and radians beside sliders.

A take of known control curves (the jaw opening while the mouth smiles every 150 frames, so that
the corrective fires) is solved onto the rig's controls and, as the baseline, onto the same face's
plain shape keys (the drivers removed) and read back through the drivers. Compared: the controls
RMSE (each control's error over its range) on every frame and on the frames where the corrective
fires, the mean marker residual, and the wall time of each solve.
"""

import time
from pathlib import Path

import bpy
import numpy as np

from . import rig_samples_mixed as mixed
from ..headless.headless import run_take
from ..rig import rig_target
from .rig_bench import columns, control_curves, open_character, take_config, write_take


def mixed_rig_take(folder, frames, *, seed=3):
    """Build the mixed rig on the sample character, write its take of known curves to ``folder``
    (``take.csv``), save ``rig.blend`` and ``plain.blend`` (the same face without the drivers).
    Returns (control names, limits {name: (lower, upper)}, truth (F, C))."""
    folder = Path(folder)
    mesh = open_character()
    mixed.build_mixed_rig(mesh)
    controls = rig_target.spec_controls(mixed.controls_spec(), mesh)
    names = [c.name for c in controls]
    truth = mixed.with_corrective_events(names, control_curves(controls, frames, seed=seed), seed=seed)
    truth = mixed.truth_limits(truth, names)
    write_take(folder, mesh, controls, truth)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "rig.blend"))
    mesh.data.shape_keys.animation_data_clear()
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "plain.blend"))
    return names, {c.name: (c.lower, c.upper) for c in controls}, truth


def relative_rmse(got, truth, limits, names, rows=None):
    """RMSE over the controls of (error / range), on ``rows`` (default every frame)."""
    span = np.array([limits[n][1] - limits[n][0] for n in names])
    err = (np.asarray(got) - truth) / span
    if rows is not None:
        err = err[rows]
    return float(np.sqrt(np.nanmean(err ** 2)))


def solve_mixed(folder, names, limits, truth, *, say=print, plain=True):
    """The mixed rig's take solved onto its controls and (``plain``) onto the plain keys: a dict of figures."""
    rows = mixed.firing(names, truth)
    out = {"frames": int(len(truth)), "frames_firing": int(rows.sum())}
    t0 = time.perf_counter()
    rig = run_take(take_config(folder, "mixed", "Face", rig=mixed.rig_section()), quiet=True, overwrite=True)[0]
    out["rig"] = _figures(columns(rig, names), rig, truth, limits, names, rows, time.perf_counter() - t0)
    out["rig"]["converged"] = rig.info["rig"].get("converged")
    if plain:
        t0 = time.perf_counter()
        keys = run_take(take_config(folder, "plain", "Face", blend="plain.blend"), quiet=True, overwrite=True)[0]
        back = mixed.read_back(list(keys.shape_names), keys.weights, limits)
        out["plain"] = _figures(back, keys, truth, limits, names, rows, time.perf_counter() - t0)
        out["ratio"] = {k: out["rig"][k] / out["plain"][k] for k in ("controls_rmse", "firing_rmse", "residual_mm")}
    say(_line(out))
    return out


def _figures(got, result, truth, limits, names, rows, seconds):
    return {"controls_rmse": relative_rmse(got, truth, limits, names),
            "firing_rmse": relative_rmse(got, truth, limits, names, rows),
            "residual_mm": float(np.nanmean(result.residual_rms) * 1e3), "seconds": seconds,
            "per_control": dict(zip(names, np.sqrt(np.nanmean(((got - truth) / np.array(
                [limits[n][1] - limits[n][0] for n in names])) ** 2, axis=0)).round(4).tolist()))}


def _line(out):
    r = out["rig"]
    text = (f"mixed rig ({out['frames']} frames, corrective firing on {out['frames_firing']}): controls RMSE "
            f"{r['controls_rmse']:.4f}, where the corrective fires {r['firing_rmse']:.4f}, residual "
            f"{r['residual_mm']:.3f} mm, {r['seconds']:.1f} s")
    if "plain" in out:
        p, q = out["plain"], out["ratio"]
        text += (f"; plain keys read back through the drivers {p['controls_rmse']:.4f} / {p['firing_rmse']:.4f} / "
                 f"{p['residual_mm']:.3f} mm ({p['seconds']:.1f} s): {q['controls_rmse']:.2f}x / "
                 f"{q['firing_rmse']:.2f}x / {q['residual_mm']:.2f}x")
    return text


def mixed_rig_figures(folder, frames, say, *, long_frames=None):
    """The mixed rig on a ``frames``-frame take against the plain keys; with ``long_frames``, the
    time of a take that long onto the rig alone."""
    sub = Path(folder) / "mixed"
    sub.mkdir()
    names, limits, truth = mixed_rig_take(sub, frames)
    out = {"take": solve_mixed(sub, names, limits, truth, say=say)}
    if long_frames:
        sub = Path(folder) / "mixed_long"
        sub.mkdir()
        names, limits, truth = mixed_rig_take(sub, long_frames, seed=5)
        out["long"] = solve_mixed(sub, names, limits, truth, say=say, plain=False)
    return out
