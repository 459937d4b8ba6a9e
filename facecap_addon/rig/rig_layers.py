"""A rig's two layers, as the tuning loop reads them: the solve layer and the animator's layer of each control.

A rig solve is keyed on the ``FaceCap Solve`` track of every ID its controls live on (the armature,
the sliders' object, the shape keys), with the animator's own action above it (``rig_keying``).
Retune and Fit Gain and Offset read here what the animator set: each control's solve value and its
final value (solve blended with the animator layer, as Blender plays it) at the tuning frames, the
frames the animator keyed, and afterwards continue the animator layers without the keys the solve
has learned (the shape-key side of all this is ``scene.layers`` and ``scene.tuning_scene``).
"""

import numpy as np

from ..scene import anim, layers


def _owners(controls):
    """{id(owner): (owner, [(column, control), ...])} in the controls' order."""
    out = {}
    for k, c in enumerate(controls):
        out.setdefault(id(c.owner), (c.owner, []))[1].append((k, c))
    return out


def solved(controls):
    """Whether some ID of the controls has a solve layer."""
    return any(layers.solved_action(owner) is not None for owner, _ in _owners(controls).values())


def _animator_curves(owner):
    ad = owner.animation_data
    if ad is None or ad.action is None:
        return {}
    return {(fc.data_path, fc.array_index): fc for fc in anim.action_fcurves(ad.action, owner)}


def layer_values(controls, frames):
    """(solve, final) (F, C): each control's solve-layer value and what Blender plays (the animator
    layer blended over it) at ``frames``; a control without a solve curve counts its current value."""
    frames = np.asarray(frames, dtype=np.float64)
    solve = np.full((frames.size, len(controls)), np.nan)
    for owner, items in _owners(controls).values():
        action = layers.solved_action(owner)
        if action is None:
            continue
        keyed, values = anim.read_curves(owner, [c.curve for _, c in items], action=action)
        for j, (k, _) in enumerate(items):
            ok = np.isfinite(values[:, j])
            if ok.any():
                solve[:, k] = np.interp(frames, keyed[ok], values[ok, j])
    for k, c in enumerate(controls):
        if np.isnan(solve[:, k]).all():
            solve[:, k] = c.get()
    final = solve.copy()
    for owner, items in _owners(controls).values():
        curves, ad = _animator_curves(owner), owner.animation_data
        for k, c in items:
            fc = curves.get(c.curve)
            if fc is not None and not fc.mute:
                upper = np.array([fc.evaluate(float(f)) for f in frames])
                final[:, k] = layers.blend(solve[:, k], upper, ad.action_blend_type, ad.action_influence)
    return solve, final


def edited_frames(controls, *, tolerance=1e-4):
    """Frames the animator keyed on some control where what plays differs from the solve by more
    than ``tolerance`` (of the control's range)."""
    keyed = []
    for owner, items in _owners(controls).values():
        curves = _animator_curves(owner)
        for _, c in items:
            fc = curves.get(c.curve)
            if fc is not None and len(fc.keyframe_points):
                co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
                fc.keyframe_points.foreach_get("co", co)
                keyed.append(co[0::2])
    frames = np.unique(np.round(np.concatenate(keyed))).astype(np.float64) if keyed else np.zeros(0)
    if not frames.size:
        return frames
    solve, final = layer_values(controls, frames)
    span = np.array([max(c.upper - c.lower, 1e-12) for c in controls])
    return frames[(np.abs(final - solve) / span > tolerance).any(axis=1)]


def take_in_corrections(controls, frames):
    """Continue each animator layer of the controls' IDs as a copy without its keys on the controls at
    ``frames`` (the solve hits them now); the animator's actions themselves are kept unchanged (fake
    user). Returns the new actions."""
    made = [layers.continue_without(owner, {c.curve for _, c in items}, frames)
            for owner, items in _owners(controls).values()]
    return [action for action in made if action is not None]
