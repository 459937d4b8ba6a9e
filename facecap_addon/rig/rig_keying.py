"""Keying a rig's solved controls: one new action per animated ID on its ``FaceCap Solve`` layer.

Exactly as shape keys (``take.key_weights``): each ID whose controls were solved (the armature
object for bone channels, the control object for custom properties, the mesh's shape-key
datablock for shape keys) gets a new action placed in its ``FaceCap Solve`` NLA strip; the
animator's active action above it is never touched. A quaternion control keys its vector part and
the ``w`` that keeps it a unit quaternion. The per-frame diagnostics ride on the first ID's action.
"""

import bpy
import numpy as np

from ...solvers.errors import FacecapError
from ..scene import anim, layers
from ..scene.take import DIAGNOSTIC_CURVES, MARKER_ERROR_PREFIX


def _columns(controls, result):
    """{owner key: (owner, [(path, index)], [column (F,)], [sampled])} of the solved controls."""
    index = {n: k for k, n in enumerate(result.shape_names)}
    out = {}
    quats = {}
    for c in controls:
        k = index.get(c.name)
        if k is None:
            continue
        owner = out.setdefault(id(c.owner), (c.owner, [], [], []))
        owner[1].append(c.curve)
        owner[2].append(result.weights[:, k])
        owner[3].append(False)
        if c.path.endswith("rotation_quaternion") and c.index > 0:
            quats.setdefault((id(c.owner), c.path), []).append(result.weights[:, k])
    for (key, path), parts in quats.items():
        xyz = np.sum([p * p for p in parts], axis=0)
        owner = out[key]
        owner[1].append((path, 0))
        owner[2].append(np.sqrt(np.clip(1.0 - xyz, 0.0, 1.0)))
        owner[3].append(False)
    return out


def key_controls(controls, result, action_name, *, take_name=""):
    """Key ``result`` (shape names = control names, weights = control values) as the solve layer of
    every ID the controls live on; returns the new actions (the first carries the diagnostics).

    All or nothing: every action is made first and only then placed on its ID's solve track, so a
    failure while making them (or an interrupt) leaves every solve layer as it was."""
    columns_of = _columns(controls, result)
    for owner, *_ in columns_of.values():  # what would stop placing one layer, checked before any is made
        ad = owner.animation_data
        if ad is not None and ad.use_tweak_mode:
            raise FacecapError(f"'{owner.name}' is in NLA tweak mode; exit tweak mode before solving")
    made = []
    try:
        for n, (owner, curves, columns, sampled) in enumerate(columns_of.values()):
            groups = ["FaceCap Controls"] * len(curves)
            if n == 0:
                props = list(DIAGNOSTIC_CURVES)
                columns = columns + [result.residual_rms * 1e3, np.asarray(result.at_bound, dtype=np.float64)]
                per_marker = getattr(result, "frame_marker_residual", None)
                if per_marker is not None and per_marker.shape == (result.frames.size, len(result.marker_names)):
                    props += [MARKER_ERROR_PREFIX + m for m in result.marker_names]
                    columns += list(per_marker.T * 1e3)
                for prop in props:
                    owner[prop] = 0.0
                curves = curves + [(f'["{p}"]', 0) for p in props]
                groups += ["FaceCap Diagnostics"] * len(props)
                sampled = sampled + [True] * len(props)
            values = np.column_stack(columns).astype(np.float32)
            name = action_name if n == 0 else f"{action_name} {owner.name}"
            action = anim.new_action_with_curves(owner, name=anim.unique_action_name(name), curves=curves,
                                                 frames=result.frames, values=values, group=groups, assign=False,
                                                 sampled=sampled)
            made.append((owner, action))
    except BaseException:
        for _, action in made:
            bpy.data.actions.remove(action)
        raise
    for owner, action in made:
        strip = layers.place_solved_action(owner, action, take_name or action_name)
        if anim.LAYERED_ACTIONS and strip.action_slot is None:
            slot = next((s for s in action.slots if s.target_id_type == owner.id_type), None)
            if slot is not None:
                strip.action_slot = slot
    return [action for _, action in made]
