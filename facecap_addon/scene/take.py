"""Scene <-> solver adapters for a take: marker empties, settings, keyed results."""

import glob
import json
from pathlib import Path

import bpy
import numpy as np

from ...solvers.capture.align import region_patterns
from ...solvers.character.basis import Basis
from ...solvers.character.shape_options import Region
from ...solvers.character.template import HumanTemplate, template_path
from ...solvers.errors import FacecapError
from ...solvers.io import import_markers
from ...solvers.io.weights import read_weights
from ...solvers.markers import MarkerSet
from ...solvers.pipeline import RetargetSettings
from ...solvers.strategies.base import Target
from ...solvers.strategies.options import (
    ActorSettings,
    CalibrationSettings,
    ExamplePairs,
    ExampleSettings,
    MappingSettings,
    PCASettings,
    RefineSettings,
    StrategyInputs,
)
from ...solvers.transforms import matrix_to_euler_xyz
from ...solvers.video.response import profile_contents
from . import anim, layers, rom_markers
from .import_scene import pixels_from_scene
from .scene_data import solvable_blocks

LOCATION = [("location", 0), ("location", 1), ("location", 2)]


def _patterns(text):
    return tuple(p.strip() for p in text.split(",") if p.strip())


def shape_options(settings):
    """bounds, locks and regions for RetargetSettings from the Solve panel's shape and region lists."""
    bounds = tuple((glob.escape(s.name), s.lower, s.upper) for s in settings.shapes)
    locks = tuple((glob.escape(s.name), s.lock_value) for s in settings.shapes if s.lock)
    regions = []
    for region in settings.regions:
        shapes = tuple(glob.escape(s.name) for s in settings.shapes if s.region == region.name)
        if shapes:
            regions.append(Region(region.name, shapes, _patterns(region.markers) or ("*",)))
    unassigned = tuple(glob.escape(s.name) for s in settings.shapes if not s.region)
    if regions and unassigned:
        regions.append(Region("rest of the face", unassigned, ("*",)))
    return {"bounds": bounds, "locks": locks, "regions": tuple(regions)}


def strategy_settings(settings):
    """The strategy sections of RetargetSettings from the Solve panel."""
    s = settings
    poses = {}
    for pose in s.calib_poses:
        poses.setdefault(pose.name, []).append((pose.first, pose.last))
    curve = f"gamma:{s.parallel_gamma:g}" if s.parallel_curve == "gamma" else s.parallel_curve
    return {
        "actor": ActorSettings(template=s.actor_template.strip() or "auto", unseen_shapes=s.unseen_shapes,
                               exclusive=s.exclusive),
        "calibration": CalibrationSettings(
            poses=tuple((name, tuple(ranges)) for name, ranges in poses.items()),
            neutral_frames=(s.calib_neutral_first, s.calib_neutral_last),
            split=tuple(dict.fromkeys(p.name for p in s.calib_poses if p.split)),
            align=s.calib_align,
            **rom_markers.rom_calibration(s),
        ),
        "mapping": MappingSettings(
            table=tuple((row.source, row.target, row.gain) for row in s.mapping if row.source and row.target),
            aliases=s.mapping_aliases, gain=s.parallel_gain, offset=s.parallel_offset, curve=curve,
            mirror=s.parallel_mirror,
            neutral_frames=(s.parallel_neutral_first, s.parallel_neutral_last) if s.parallel_use_neutral else None,
        ),
        "examples": ExampleSettings(ridge=s.ridge, kernel=s.rbf_kernel, rbf_smoothing=s.rbf_smoothing,
                                    degree=s.rbf_degree, n_components=s.n_components or None, far=s.rbf_far),
        "pca": PCASettings(mode=s.pca_mode, ica=s.pca_ica, n_basis=s.pca_n_basis, variance=s.pca_variance),
        "refine": RefineSettings(max_iterations=s.refine_max_iterations, tol=s.refine_tol,
                                 stiffness=s.refine_stiffness),
    }


def master_markers(settings):
    """The performer's master T-pose stored in the .blend (``settings.master_data``), or None."""

    if not settings.master_data:
        return None
    data = json.loads(settings.master_data)
    pos = np.array(data["positions"], dtype=np.float64)[None]
    return MarkerSet(tuple(data["names"]), np.array([1.0]), pos, fps=settings.fps, units="m",
                     source=f"master T-pose '{data.get('source', '')}'")


def store_master(settings, names, pose, source):
    """Store a master T-pose (M, 3, metres) in the .blend."""

    pose = np.asarray(pose, dtype=np.float64)
    settings.master_data = json.dumps({"names": list(names), "positions": np.round(pose, 9).tolist(),
                                       "source": str(source)})
    settings.master_source = str(source)


def neutral_options(settings):
    """The [neutral] / [stabilise] / [align] / [output] head part of RetargetSettings from the sidebar."""

    mode = settings.neutral_mode
    out = {"stabilise_mode": settings.stabilise_mode, "align_regions": (), "landmarks": _patterns(settings.landmarks)}
    if settings.align_regions:
        out["align_regions"] = region_patterns(True)
    if mode == "RANGES":
        out["neutral_ranges"] = ((settings.neutral_first, settings.neutral_last),
                                 (settings.neutral_end_first, settings.neutral_end_last))
    elif mode == "DETECT":
        out["neutral_detect"] = True
    elif mode == "FILE":
        if not settings.neutral_file:
            raise FacecapError("choose the neutral file first (Stabilise panel)")
        out["neutral_file"] = bpy.path.abspath(settings.neutral_file)
    if settings.use_master:
        master = master_markers(settings)
        if master is None:
            raise FacecapError("no master T-pose stored: load one first (Stabilise panel)")
        out["master"] = master
    if settings.head_target is not None:
        bone = settings.head_bone.strip()
        out["head_target"] = settings.head_target.name + (f":{bone}" if bone else "")
    return out


def can_stabilise(settings):
    """A take is loaded and its stable set is chosen (ticked markers, or automatic)."""
    return settings.marker_collection is not None and (settings.auto_stable or sum(m.stable for m in settings.markers) >= 3)


def retarget_settings(settings):
    """Frozen solver settings from the scene's PropertyGroup."""
    stable = tuple(m.name for m in settings.markers if m.stable)
    return RetargetSettings(
        **shape_options(settings),
        **strategy_settings(settings),
        **neutral_options(settings),
        auto_stable=settings.auto_stable,
        stable_markers=stable,
        neutral_frames=(settings.neutral_first, settings.neutral_last),
        strategy=settings.strategy,
        regularisation=settings.regularisation,
        sparsity=settings.sparsity,
        symmetry=settings.symmetry,
        smoothing=(settings.smoothing_first, settings.smoothing_second),
        fine_iterations=settings.fine_iterations,
        head_smoothing=settings.head_smoothing,
    )


def markers_from_collection(settings):
    """Read the take's marker empties back into a MarkerSet (metres); missing keys are gaps."""
    coll = settings.marker_collection
    if coll is None:
        raise FacecapError("no marker collection: import a take first")
    return markers_from_empties(coll, [m.name for m in settings.markers], settings.fps)


def markers_from_empties(coll, names, fps):
    """A MarkerSet (metres) from the keyed marker empties of ``coll`` (``names`` first, in order;
    every empty when none of them is there)."""
    objects = {o.get("facecap_marker", o.name): o for o in coll.objects if o.type == "EMPTY"}
    names = [n for n in names if n in objects] or sorted(objects)
    if not names:
        raise FacecapError(f"collection '{coll.name}' holds no marker empties")
    tracks = [anim.read_curves(objects[n], LOCATION) for n in names]
    frames = np.unique(np.concatenate([f for f, _ in tracks]))
    if frames.size == 0:
        raise FacecapError(f"the marker empties in '{coll.name}' have no keys")
    pos = np.full((frames.size, len(names), 3), np.nan)
    for m, (f, v) in enumerate(tracks):
        pos[np.searchsorted(frames, f), m] = v
    if coll.get("facecap_dim", 3) == 2:  # tracked footage: pixels, drawn in the XZ plane

        return MarkerSet(tuple(names), frames, pixels_from_scene(pos), fps=fps, units="px",
                         source=f"collection '{coll.name}'")
    return MarkerSet(tuple(names), frames, pos, fps=fps, units="m", source=f"collection '{coll.name}'")


def character_target(obj):
    """The character as non-geometric strategies see it: shape-key names and slider ranges (the keys
    drivers set left out)."""
    key = getattr(obj.data, "shape_keys", None)
    if key is None or len(key.key_blocks) < 2:
        raise FacecapError(f"object '{obj.name}' has no shape keys to solve for")
    blocks = solvable_blocks(obj)
    return Target(tuple(b.name for b in blocks), np.array([b.slider_min for b in blocks], dtype=np.float64),
                  np.array([b.slider_max for b in blocks], dtype=np.float64))


def examples_from_action(action, obj):
    """ExamplePairs from the keyed frames of ``action`` on ``obj``'s shape keys.

    Every frame that has a key on any ``key_blocks["<shape>"].value`` curve is a posed example;
    each curve is evaluated there (a shape keyed elsewhere but not on that frame takes its curve's
    value), shapes without a curve are 0.
    """
    key = obj.data.shape_keys
    if key is None:
        raise FacecapError(f"object '{obj.name}' has no shape keys")
    curves = {}
    for fc in anim.action_fcurves(action, key):
        path = fc.data_path
        if path.startswith('key_blocks["') and path.endswith('"].value'):
            curves[path[len('key_blocks["'):-len('"].value')]] = fc
    if not curves:
        raise FacecapError(f"action '{action.name}' keys no shape-key values of '{obj.name}'")
    keyed = []
    for fc in curves.values():
        co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
        fc.keyframe_points.foreach_get("co", co)
        keyed.append(co[0::2])
    frames = np.unique(np.round(np.concatenate(keyed)))
    names = tuple(curves)
    values = np.array([[curves[n].evaluate(float(f)) for n in names] for f in frames], dtype=np.float64)
    return ExamplePairs(frames.astype(np.float64), values, names)


def strategy_inputs(settings, strategy=None):
    """StrategyInputs for ``strategy`` (default: the Solve panel's), read from the scene and the files
    the panel names."""

    strategy = strategy or settings.strategy
    inputs, notes = {}, []
    if strategy == "semantic":
        rom_markers.check_rom(settings)  # a ROM sheet needs its take; markers that name no pose are refused
        inputs.update(_actor_inputs(settings, notes))
    if strategy in ("calibrated", "refine", "semantic"):
        calibration = calibration_markers(settings, notes)
        if calibration is not None:
            inputs["calibration"] = calibration
    elif strategy in ("linear", "rbf", "pca"):
        if settings.examples_action is not None:
            if settings.target is None:
                raise FacecapError("choose the character first")
            inputs["examples"] = examples_from_action(settings.examples_action, settings.target)
    elif strategy == "parallel" and settings.weights_path:
        track = read_weights(bpy.path.abspath(settings.weights_path))
        inputs["weights"] = track
        notes.extend(track.notes)
    return StrategyInputs(**inputs, notes=tuple(notes))


def calibration_markers(settings, notes):
    """The calibration take the Solve panel names (its collection of marker empties, or a file), or None."""
    if settings.calib_source == "COLLECTION":
        if settings.calib_collection is None:
            return None
        return markers_from_empties(settings.calib_collection, [m.name for m in settings.markers], settings.fps)
    if not settings.calib_path:
        return None
    imported = import_markers(bpy.path.abspath(settings.calib_path), units=settings.calib_units)
    notes.extend(imported.notes)
    return imported.markers


def _actor_inputs(settings, notes):
    """The semantic solve's knowledge of the actor from the Solve panel: a performer profile, the human template."""
    out = {}
    if settings.actor_profile:
        path = bpy.path.abspath(settings.actor_profile)
        if profile_contents(path)[0]:
            out["profile"] = Basis.load_npz(path)
        else:
            notes.append(f"the performer profile {Path(path).name} holds what a ROM on camera or a guide followed "
                         "measured of the blendshape scores, and no measured shapes")
    template = human_template(settings, notes)
    if template is not None:
        out["template"] = template
    return out


def human_template(settings, notes):
    """The Solve panel's human template ("auto": the installed one, if any; "none"; or a path), or None."""
    template = settings.actor_template.strip() or "auto"
    if template == "none":
        return None
    path = template_path() if template == "auto" else Path(bpy.path.abspath(template))
    if template == "auto" and not path.is_file():
        return None
    notes.append(f"the human template: {path}")
    return HumanTemplate.load(path)


def source_channel_names(settings):
    """Names on the source side of the mapping table: calibration poses, or the weights file's channels."""

    if settings.strategy == "parallel":
        if not settings.weights_path:
            raise FacecapError("choose the weights file first")

        return read_weights(bpy.path.abspath(settings.weights_path)).names
    names = []
    split = {p.name for p in settings.calib_poses if p.split}
    for pose in settings.calib_poses:
        for name in ([pose.name + "Left", pose.name + "Right"] if pose.name in split else [pose.name]):
            if name not in names:
                names.append(name)
    if not names:
        raise FacecapError("define calibration poses first")
    return tuple(names)


DIAGNOSTIC_CURVES = ("facecap_residual_mm", "facecap_at_bound")
MARKER_ERROR_PREFIX = "facecap_error_mm_"


def key_weights(obj, result, action_name, *, take_name=""):
    """Key the solved weights on ``obj``'s shape keys as the *solve layer*; returns the new action.

    The action goes into the ``FaceCap Solve`` NLA strip (``layers``); the animator's own active
    action is never touched, so manual keys survive re-solves. The same action carries the
    per-frame diagnostics as custom-property curves on the shape-key datablock
    (``facecap_residual_mm``, ``facecap_at_bound``) and, when the result has them, the per-marker
    error (``facecap_error_mm_<marker>``, group "FaceCap Marker Error"), visible in the Graph Editor.
    The weights are keys; the diagnostics are samples (one per frame, NaN where a frame has no
    value; read-only until *Convert to Keyframes*).
    """
    key = obj.data.shape_keys
    if key is None:
        raise FacecapError(f"object '{obj.name}' has no shape keys")
    curves = [(layers.shape_path(n), 0) for n in result.shape_names]
    groups = ["FaceCap Weights"] * len(curves)
    columns = [result.weights, result.residual_rms, np.asarray(result.at_bound, dtype=np.float64)]
    scales = [1.0, 1e3, 1.0]
    props = list(DIAGNOSTIC_CURVES)
    groups += ["FaceCap Diagnostics"] * len(DIAGNOSTIC_CURVES)
    per_marker = getattr(result, "frame_marker_residual", None)
    if per_marker is not None and per_marker.shape == (result.frames.size, len(result.marker_names)):
        props += [MARKER_ERROR_PREFIX + n for n in result.marker_names]
        groups += ["FaceCap Marker Error"] * len(result.marker_names)
        columns.append(per_marker)
        scales.append(1e3)
    for prop in props:
        key[prop] = 0.0
    curves += [(f'["{p}"]', 0) for p in props]
    values = _float32_columns(columns, scales)
    # the diagnostics as samples: nobody edits them, and keys would double the keying and the .blend
    # (measured on the 36,000-frame CLI take: see docs/performance.md)
    sampled = [False] * len(result.shape_names) + [True] * len(props)
    action = anim.new_action_with_curves(key, name=action_name, curves=curves, frames=result.frames, values=values,
                                         group=groups, assign=False, sampled=sampled)
    layers.place_solved_action(key, action, take_name or action_name)
    if getattr(result, "head_target", "") and result.stabilise is not None:
        scale = getattr(result.alignment, "scale", 1.0) if result.alignment is not None else 1.0
        key_head_on_target(result.head_target, result.stabilise, f"{action_name} Head", scale=scale,
                           frames=result.frames)
    return action


def _float32_columns(columns, scales, block=8192):
    """``np.column_stack([c * s ...])`` as float32, the precision Blender keeps, filled in blocks of
    rows: no float64 (F, C) copy or (F, M) temporaries (on 100 minutes at 60 fps: 175 MB instead of
    about 700 MB beside Blender's keys). Each value is rounded once, from the float64 product."""
    n = columns[0].shape[0]
    widths = [1 if c.ndim == 1 else c.shape[1] for c in columns]
    out = np.empty((n, sum(widths)), dtype=np.float32)
    for a in range(0, n, block):
        col = 0
        for c, s, k in zip(columns, scales, widths):
            part = c[a : a + block]
            out[a : a + block, col : col + k] = (part if s == 1.0 else part * s).reshape(-1, k)
            col += k
    return out


def _head_pose(stab):
    """Per-frame head rotation Rh (F, 3, 3) and the displacement (F, 3) of the head's reference centre.

    The raw markers are ``Rh (x - c) + c + delta`` for a stabilised point x, with c the centroid of
    the stable markers in the reference head frame.
    """
    Rh = stab.head_rotations()
    c = stab.reference.mean(axis=0)
    s = stab.scale_array()
    raw_c = np.einsum("fij,fj->fi", Rh, c[None] - stab.translations) / s[:, None]
    return Rh, raw_c - c, c


def _euler(R):
    # Unwrapped so a head turning past 180 deg never flips between frames.
    return np.unwrap(matrix_to_euler_xyz(R), axis=0)


def _unreliable(stab):
    bad = np.asarray(stab.flagged, dtype=bool)
    if stab.unreliable is not None:
        bad = bad | np.asarray(stab.unreliable, dtype=bool)
    return bad.astype(np.float64)


def key_head_on_target(target, stab, name, *, scale=1.0, frames=None):
    """Key the removed head motion onto a character's head object or bone.

    ``target`` is "Object" or "Armature:bone" (an object in ``bpy.data.objects``). The object (or
    bone) keeps its rest placement and turns about its own origin by the actor's head rotation;
    its translation is the actor's head displacement times ``scale`` (actor -> character). Euler
    angles are unwrapped (no flips); flagged frames get no key. A ``facecap_unreliable`` curve
    (1 = the head fit is flagged or unreliable there) is keyed on the object. ``frames``: the take's
    frame numbers (default: the stabilised markers', which a result may have released).
    """

    obj_name, _, bone_name = target.partition(":")
    obj = bpy.data.objects.get(obj_name)
    if obj is None:
        raise FacecapError(f"head target: no object named '{obj_name}'")
    Rh, delta, pivot = _head_pose(stab)
    delta = delta * scale
    bad = np.asarray(stab.flagged, dtype=bool)
    obj["facecap_unreliable"] = 0.0
    obj["facecap_head_pivot"] = [float(v) for v in pivot]  # the actor-space point the head turns about
    if not bone_name:
        rest = obj.get("facecap_rest")
        if rest is None:
            rest = [v for row in obj.matrix_basis for v in row]
            obj["facecap_rest"] = rest
        rest = np.array(rest, dtype=np.float64).reshape(4, 4)
        rot = np.einsum("fij,jk->fik", Rh, rest[:3, :3] / np.linalg.norm(rest[:3, :3], axis=0))
        loc = rest[:3, 3] + delta
        path = ""
    else:
        if obj.type != "ARMATURE" or bone_name not in obj.pose.bones:
            raise FacecapError(f"head target: '{obj_name}' has no bone '{bone_name}'")
        pbone = obj.pose.bones[bone_name]
        pbone.rotation_mode = "XYZ"
        B = np.array(obj.data.bones[bone_name].matrix_local, dtype=np.float64)
        Binv = np.linalg.inv(B)
        P = np.tile(np.eye(4), (len(Rh), 1, 1))
        P[:, :3, :3] = np.einsum("fij,jk->fik", Rh, B[:3, :3])
        P[:, :3, 3] = B[:3, 3] + delta
        L = np.einsum("ij,fjk->fik", Binv, P)
        rot, loc = L[:, :3, :3], L[:, :3, 3]
        path = f'pose.bones["{bone_name}"].'
    values = np.concatenate([loc, _euler(rot)], axis=1)
    values[bad] = np.nan
    values = np.column_stack([values, _unreliable(stab)])
    curves = [(path + "location", i) for i in range(3)] + [(path + "rotation_euler", i) for i in range(3)]
    curves.append(('["facecap_unreliable"]', 0))
    frames = stab.markers.frames if frames is None else frames
    return anim.new_action_with_curves(obj, name=name, curves=curves, frames=frames, values=values)


def key_head_motion(scene, stab, name):
    """An empty called ``name`` keyed with the removed head motion (location + unwrapped Euler rotation).

    Stabilising the same take again re-keys the empty an earlier Stabilise made for it (marked
    ``facecap_head = name``) and replaces that run's action, instead of adding ``name.001`` each time; an
    object of the user's is never taken over."""

    head = next((o for o in bpy.data.objects if o.get("facecap_head") == name and o.type == "EMPTY"), None)
    if head is None:
        head = bpy.data.objects.new(name, None)
        head.empty_display_type = "ARROWS"
        head.empty_display_size = 0.05
        head["facecap_head"] = name
    if head.name not in scene.collection.all_objects:
        scene.collection.objects.link(head)
    earlier = head.animation_data.action if head.animation_data is not None else None
    if earlier is not None and earlier.get("facecap_head") == name:  # the earlier run's: its name is free again
        head.animation_data.action = None
        earlier.use_fake_user = False  # anim gives every action one; this one is replaced, not kept
        if earlier.users == 0:
            bpy.data.actions.remove(earlier)
    Rh = stab.head_rotations()  # raw = Rh @ stabilised - Rh @ t
    loc = -np.einsum("fij,fj->fi", Rh, stab.translations)
    # Unwrapped so a head turning past 180 deg never flips between frames.
    euler = np.unwrap(matrix_to_euler_xyz(Rh), axis=0)
    values = np.concatenate([loc, euler], axis=1)
    values[stab.flagged] = np.nan
    head["facecap_unreliable"] = 0.0
    values = np.column_stack([values, _unreliable(stab)])
    curves = LOCATION + [("rotation_euler", 0), ("rotation_euler", 1), ("rotation_euler", 2), ('["facecap_unreliable"]', 0)]
    action = anim.new_action_with_curves(head, name=name, curves=curves, frames=stab.markers.frames, values=values)
    action["facecap_head"] = name  # the next Stabilise of this take replaces it
    return head
