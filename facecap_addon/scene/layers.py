# SPDX-License-Identifier: GPL-3.0-or-later
"""The solve layer and the animator's layer on a character's shape keys (NLA).

The solver owns one NLA track, ``FaceCap Solve``, holding one strip with the latest solved action.
The animator owns the *active action*, evaluated above the NLA stack and blended ``ADD`` by default,
so a key there is an offset on top of the solve (Blender remaps a slider value keyed in the UI into
that offset). Re-solving swaps the strip's action and never touches the active action: manual keys
survive any number of re-solves. Earlier solved actions keep a fake user; nothing is deleted.

``final = solve (+) animator layer`` is computed here with Blender's NLA blend rules for scalar
channels (``ADD``, ``SUBTRACT``, ``MULTIPLY``, ``REPLACE``, ``COMBINE``) and the layer's influence;
``tests/blender/test_layers.py`` checks it against Blender's own evaluation.
"""

import bpy
import numpy as np

from ...solvers.errors import FacecapError
from . import anim

SOLVE_TRACK = "FaceCap Solve"
#: custom property marking an action as a facecap solve (value: the take name)
SOLVE_TAG = "facecap_solve"


def shape_path(name):
    return f'key_blocks["{name}"].value'


def solve_track(key):
    """The ``FaceCap Solve`` NLA track of a shape-key datablock, or None."""
    ad = key.animation_data
    if ad is None:
        return None
    return next((t for t in ad.nla_tracks if t.name == SOLVE_TRACK), None)


def solved_action(key):
    """The action of the solve layer (None before the first solve)."""
    track = solve_track(key)
    if track is None or not len(track.strips):
        return None
    return track.strips[0].action


def place_solved_action(key, action, take_name=""):
    """Make ``action`` the solve layer of ``key``; the animator's active action is left alone.

    The first time, the track is created (on top of any NLA tracks the user already has) and the
    animator layer is set to blend ``ADD``. A solve assigned as the active action by an earlier
    facecap version is moved off the animator layer (kept with a fake user).
    """
    ad = anim.ensure_animation_data(key)
    if ad.use_tweak_mode:
        raise FacecapError(f"'{key.name}' is in NLA tweak mode; exit tweak mode before solving")
    action[SOLVE_TAG] = take_name or action.name
    action.use_fake_user = True
    if ad.action is not None and ad.action.get(SOLVE_TAG) is not None:
        ad.action.use_fake_user = True
        ad.action = None
    track = solve_track(key)
    if track is None:
        track = ad.nla_tracks.new()
        track.name = SOLVE_TRACK
        if ad.action is None:
            ad.action_blend_type = "ADD"
    for strip in list(track.strips):
        if strip.action is not None:
            strip.action.use_fake_user = True
        track.strips.remove(strip)
    start = int(np.floor(action.frame_range[0]))
    strip = track.strips.new(action.name, start, action)
    if anim.LAYERED_ACTIONS:
        slot = next((s for s in action.slots if s.target_id_type == "KEY"), None)
        if slot is not None:
            strip.action_slot = slot
    strip.blend_type = "REPLACE"
    strip.extrapolation = "HOLD"
    track.lock = True  # the solver's layer: edits belong on the animator layer above it
    return strip


def _edit_curves(key):
    ad = key.animation_data
    if ad is None or ad.action is None:
        return {}
    return {fc.data_path: fc for fc in anim.action_fcurves(ad.action, key) if fc.array_index == 0}


def _solve_columns(key, names, frames):
    """Solve-layer values of ``names`` at ``frames`` (linear between keys, held outside), NaN if no curve."""
    action = solved_action(key)
    out = np.full((frames.size, len(names)), np.nan)
    if action is None:
        return out
    keyed, values = anim.read_curves(key, [(shape_path(n), 0) for n in names], action=action)
    for k in range(len(names)):
        ok = np.isfinite(values[:, k])
        if ok.any():
            out[:, k] = np.interp(frames, keyed[ok], values[ok, k])
    return out


def _default_value():
    return float(bpy.types.ShapeKey.bl_rna.properties["value"].default)


def blend(lower, upper, mode, influence):
    """Blender's NLA blend of a scalar channel: ``lower`` (the solve) with ``upper`` (the layer)."""
    i = float(influence)
    if mode == "REPLACE":
        return lower * (1.0 - i) + upper * i
    if mode == "ADD":
        return lower + upper * i
    if mode == "SUBTRACT":
        return lower - upper * i
    if mode == "MULTIPLY":
        return lower * (1.0 - i) + lower * upper * i
    if mode == "COMBINE":
        return lower + (upper - _default_value()) * i
    raise FacecapError(f"unknown NLA blend mode '{mode}'")


def continue_without(id_data, curves, frames):
    """Continue ``id_data``'s animator layer as a copy without its keys on ``curves`` ((data path,
    index), ...) at ``frames``; the animator's action itself is kept unchanged (a fake user). Curves
    left without keys are removed (an empty curve would evaluate to 0). Returns the new action, or
    None when there is no animator layer."""
    ad = id_data.animation_data
    if ad is None or ad.action is None:
        return None
    old = ad.action
    old.use_fake_user = True
    slot = getattr(getattr(ad, "action_slot", None), "identifier", None)
    new = old.copy()
    new.name = anim.unique_action_name(f"{old.name} tuned")
    ad.action = new
    if anim.LAYERED_ACTIONS and slot is not None:
        match = next((s for s in new.slots if s.identifier == slot), None)
        if match is not None:
            ad.action_slot = match
    wanted = {round(float(f)) for f in frames}
    for fc in anim.action_fcurves(new, id_data):
        if (fc.data_path, fc.array_index) not in curves:
            continue
        for point in [p for p in fc.keyframe_points if round(p.co[0]) in wanted][::-1]:
            fc.keyframe_points.remove(point, fast=True)
        fc.update()
        if not len(fc.keyframe_points):
            anim.remove_fcurve(new, fc)
    return new


def layer_values(key, names, frames):
    """Solve layer and final (solve + animator layer) values of shapes ``names`` at ``frames``.

    Returns (solve, final), both (F, K); a shape with no solve curve counts its current slider
    value as the solve (what Blender shows below an empty layer).
    """
    frames = np.asarray(frames, dtype=np.float64)
    solve = _solve_columns(key, names, frames)
    for k, n in enumerate(names):
        if np.isnan(solve[:, k]).all():
            solve[:, k] = key.key_blocks[n].value if n in key.key_blocks else 0.0
    final = solve.copy()
    curves = _edit_curves(key)
    ad = key.animation_data
    for k, n in enumerate(names):
        fc = curves.get(shape_path(n))
        if fc is None or fc.mute:
            continue
        upper = np.array([fc.evaluate(float(f)) for f in frames])
        final[:, k] = blend(solve[:, k], upper, ad.action_blend_type, ad.action_influence)
    return solve, final


def edit_key_frames(key, names):
    """Sorted frames where the animator layer has a key on any of the shapes ``names``."""
    curves = _edit_curves(key)
    keyed = []
    for n in names:
        fc = curves.get(shape_path(n))
        if fc is None or not len(fc.keyframe_points):
            continue
        co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
        fc.keyframe_points.foreach_get("co", co)
        keyed.append(co[0::2])
    return np.unique(np.round(np.concatenate(keyed))).astype(np.float64) if keyed else np.zeros(0)


def edited_frames(key, names, *, tolerance=1e-4):
    """Frames the animator changed: keyed on the animator layer, with a final value differing from
    the solve by more than ``tolerance`` on some shape (anchor keys that change nothing are skipped)."""
    frames = edit_key_frames(key, names)
    if not frames.size:
        return frames
    solve, final = layer_values(key, names, frames)
    return frames[(np.abs(final - solve) > tolerance).any(axis=1)]
