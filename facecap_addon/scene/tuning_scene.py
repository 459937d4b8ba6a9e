"""The scene side of tuning: per-shape controls, library versions, the animator's corrections.

What the loop tunes are the target's shape keys, or, with a rig as the target (Solve > Target), the
rig's controls: ``channels`` names them, and the corrections, the frames the animator edited and
the layer continued without them are read from the shape keys' layers (``layers``) or from the
controls' (``rig.rig_layers``).

Solving itself goes through ``scene_solve`` (the sidebar's side of the one solve path). Library
versions live in the .blend: a row per version in ``settings.library_versions`` and the
arrays (``LibraryVersion.to_arrays``) as one compressed ``.npz`` in a scene ID property (base64),
so a version round-trips bit-exactly and nothing is ever overwritten.
"""

import base64
import glob
import io
from dataclasses import replace

import numpy as np

from ...solvers.character.shape_controls import ShapeControl, resolve_controls
from ...solvers.errors import FacecapError
from ...solvers.tuning.take import LibraryVersion
from ..rig import rig_layers
from ..rig.rig_solve import rig_controls, rig_settings
from . import anim, layers, take

#: scene ID property holding {version name: base64 npz}
LIBRARY_PROP = "facecap_libraries"


def rig_channels(settings):
    """The rig's controls the loop tunes (``rig_target.Control``), or None when the target is its shape keys."""
    rig = rig_settings(settings)
    return None if rig is None else rig_controls(rig, settings.target)


def channels(settings):
    """Names of what the loop tunes: the rig's controls, or the target's shape keys."""
    controls = rig_channels(settings)
    return shape_names(settings.target) if controls is None else [c.name for c in controls]


def channel_values(settings, frames):
    """(names, solve (F, K), final (F, K)): the solve layer and what plays, per tuned channel, at ``frames``."""
    frames = np.asarray(frames, dtype=np.float64)
    controls = rig_channels(settings)
    if controls is not None:
        return [c.name for c in controls], *rig_layers.layer_values(controls, frames)
    names = shape_names(settings.target)
    return names, *layers.layer_values(settings.target.data.shape_keys, names, frames)


def solved(settings):
    """Whether the target (or its rig) has a solve layer to tune."""
    if settings.target is None:
        return False
    if settings.rig_preset != "NONE":
        try:
            return rig_layers.solved(rig_channels(settings))
        except FacecapError:  # the rig's object or controls are gone: nothing to tune
            return False
    key = getattr(settings.target.data, "shape_keys", None)
    return key is not None and layers.solved_action(key) is not None


def edited_frames(settings):
    """Frames the animator keyed above the solve that change what plays."""
    controls = rig_channels(settings)
    if controls is not None:
        return rig_layers.edited_frames(controls)
    return layers.edited_frames(settings.target.data.shape_keys, shape_names(settings.target))


def diagnostics_owner(settings):
    """The ID whose solve layer carries the residual curve: the shape keys, or the rig's first control's ID."""
    controls = rig_channels(settings)
    return settings.target.data.shape_keys if controls is None else controls[0].owner


def shape_names(obj):
    key = getattr(obj.data, "shape_keys", None)
    if key is None:
        raise FacecapError(f"object '{obj.name}' has no shape keys")
    return [b.name for b in key.key_blocks if b != key.reference_key]


# -- per-shape controls ----------------------------------------------------------------------------
def shape_controls(settings, *, with_locks=False):
    """{escaped shape name: ShapeControl} for the shapes whose sidebar controls change anything.

    Locks are solve options (``take.shape_options``); ``with_locks`` adds them, for presets.
    """
    out = {}
    for s in settings.shapes:
        control = _control(s, with_locks)
        if control != ShapeControl():
            out[glob.escape(s.name)] = control
    return out


def _control(s, with_locks=False):
    return ShapeControl(
        gain=s.gain, offset=s.offset, clamp=(s.clamp_min, s.clamp_max) if s.use_clamp else None,
        curve=f"gamma:{s.gamma:g}" if s.curve == "gamma" else s.curve, smoothing=s.smoothing, mute=s.mute,
        lock=s.lock_value if with_locks and s.lock else None,
    )


def controls_with_gain_offset(settings, names, gain, offset):
    """``shape_controls`` as they will be once ``compose_gain_offset`` has written the fitted gain and offset
    (nothing is written: a solve can run with them and be dropped)."""
    out = shape_controls(settings)
    items = {s.name: s for s in settings.shapes}
    for n, (g, o) in _composed(items, names, gain, offset).items():
        out[glob.escape(n)] = replace(_control(items[n]), gain=g, offset=o)
    return out


def _composed(items, names, gain, offset, tol=1e-6):
    """{shape: (gain, offset)} of the shapes a fit changes, composed on their current controls."""
    return {n: (float(g * items[n].gain), float(g * items[n].offset + o)) for n, g, o in zip(names, gain, offset)
            if n in items and not (abs(g - 1.0) <= tol and abs(o) <= tol)}


def set_controls(settings, controls):
    """Write {shape or glob: ShapeControl} into the shape list (shapes not listed are left alone)."""

    names = [s.name for s in settings.shapes]
    for item, c in zip(settings.shapes, resolve_controls(names, controls)):
        if c is None:
            continue
        item.gain, item.offset, item.smoothing, item.mute = c.gain, c.offset, c.smoothing, c.mute
        item.use_clamp = c.clamp is not None
        if c.clamp is not None:
            item.clamp_min, item.clamp_max = c.clamp
        if c.curve.startswith("gamma:"):
            item.curve, item.gamma = "gamma", float(c.curve[6:])
        else:
            item.curve = c.curve
        if c.lock is not None:
            item.lock, item.lock_value = True, c.lock


def compose_gain_offset(settings, names, gain, offset, *, tol=1e-6):
    """Put a fitted ``corrected = gain * keyed + offset`` on top of each shape's current gain/offset.

    ``keyed`` already carries the current controls (y = g1 curve(w) + o1), so the new ones are
    g = gain g1, o = gain o1 + offset. Returns the names of the shapes that changed.
    """
    items = {s.name: s for s in settings.shapes}
    changed = _composed(items, names, gain, offset, tol)
    for n, (g, o) in changed.items():
        items[n].gain, items[n].offset = g, o
    return list(changed)


# -- library versions in the .blend -------------------------------------------------------------------
def store_version(scene, version):
    """Keep ``version`` in the .blend (a new row; an existing name is never replaced)."""
    settings = scene.facecap
    if version.name in settings.library_versions:
        return settings.library_versions[version.name]
    buf = io.BytesIO()
    np.savez_compressed(buf, **version.to_arrays())
    store = scene.get(LIBRARY_PROP)
    if store is None:
        scene[LIBRARY_PROP] = {}
        store = scene[LIBRARY_PROP]
    store[version.name] = base64.b64encode(buf.getvalue()).decode("ascii")
    row = settings.library_versions.add()
    row.name, row.parent, row.strategy, row.kind = version.name, version.parent, version.strategy, version.kind
    row.created = version.created
    summary = version.summary or {}
    for field in ("corrected_before", "corrected_after", "others_moved"):
        value = summary.get(field, summary.get(field.replace("corrected_", "corrected_rmse_")))
        if value is not None:
            setattr(row, field, float(value))
    row.note = "; ".join(summary.get("notes", ()))[:500]
    return row


def load_version(scene, name):
    """The LibraryVersion ``name`` stored in the .blend."""

    store = scene.get(LIBRARY_PROP)
    if store is None or name not in store:
        raise FacecapError(f"library version '{name}' is not stored in this .blend")
    with np.load(io.BytesIO(base64.b64decode(store[name])), allow_pickle=False) as data:
        return LibraryVersion.from_arrays({k: data[k] for k in data.files})


# -- corrections ------------------------------------------------------------------------------------
def corrections(settings):
    """{frame: {shape or control: final value}} at the tuning frames: what the animator says is right."""
    frames = np.array(sorted({t.frame for t in settings.tuning_frames}), dtype=np.float64)
    if not frames.size:
        raise FacecapError("no tuning frames: add the frames you corrected first")
    names, _, final = channel_values(settings, frames)
    return {float(f): dict(zip(names, map(float, row))) for f, row in zip(frames, final)}


def frame_change(settings, frames):
    """RMS over the shapes (a rig's controls: over their ranges) of (final - solve) at ``frames``: how
    much the animator changed each."""
    _, solve, final = channel_values(settings, frames)
    controls = rig_channels(settings)
    span = 1.0 if controls is None else np.array([max(c.upper - c.lower, 1e-12) for c in controls])
    return np.sqrt(np.mean(((final - solve) / span) ** 2, axis=1))


def take_in_corrections(settings, frames):
    """Continue the layer above the solve as a copy without its shape keys at ``frames``.

    After a retune (or a gain/offset fit) the solve itself hits the corrected frames; left in place,
    the correction offsets would count twice. The animator's action is not modified: it keeps a fake
    user and the copy (``<name> tuned``) becomes the active action. Curves left without keys are
    removed (an empty curve would evaluate to 0). Returns the new action, or None when there is no layer
    (a rig's: its controls' layers, each continued so; the first new action).
    """
    controls = rig_channels(settings)
    if controls is not None:
        made = rig_layers.take_in_corrections(controls, frames)
        return made[0] if made else None
    curves = {(layers.shape_path(n), 0) for n in shape_names(settings.target)}
    return layers.continue_without(settings.target.data.shape_keys, curves, frames)


TUNE_MARKER = "tune"


def sync_markers(scene):
    """Timeline markers named ``tune`` at the tuning frames (seen in the Dope Sheet and Graph Editor)."""
    for m in [m for m in scene.timeline_markers if m.name == TUNE_MARKER]:
        scene.timeline_markers.remove(m)
    for frame in sorted({t.frame for t in scene.facecap.tuning_frames}):
        scene.timeline_markers.new(TUNE_MARKER, frame=frame)


def residual_curve(key):
    """(frames, residual mm) from the solve layer's ``facecap_residual_mm`` curve."""
    action = layers.solved_action(key)
    if action is None:
        raise FacecapError("solve the take first")
    frames, values = anim.read_curves(key, [(f'["{take.DIAGNOSTIC_CURVES[0]}"]', 0)], action=action)
    ok = np.isfinite(values[:, 0])
    return frames[ok], values[ok, 0]


def next_worst_frame(frames, residual, after=None, *, spread=5):
    """The worst frame, or the next one after ``after`` in the order worst-first, among peaks.

    Peaks: frames whose residual is the largest within +/- ``spread`` frames (neighbours of a bad
    frame are usually bad for the same reason). ``after`` not a peak (or None): the worst peak.
    """
    order = np.argsort(-residual, kind="stable")
    peaks = []
    for i in order:
        if all(abs(frames[i] - frames[j]) > spread for j in peaks):
            peaks.append(i)
    peak_frames = [float(frames[i]) for i in peaks]
    if after is not None and float(after) in peak_frames:
        return peak_frames[(peak_frames.index(float(after)) + 1) % len(peak_frames)]
    return peak_frames[0]
