"""Pieces of a headless take's solve request that do not need the take's character: the request of a take
whose target is a rig, what to do with shape keys that drivers set, the animator's corrections, the
report's source fields."""

import dataclasses

from ...solvers.config.rig import RigSettings
from ...solvers.errors import ConfigError
from ...solvers.solve import SolveRequest
from ...solvers.tuning.store import load_version, read_corrections_csv
from ...solvers.video.cli import showing_progress
from ...solvers.video.flow_config import LandmarkTake
from ..rig import drivers
from . import console
from .landmark_take import landmark_request


def rig_request(config, obj, take, *, tune, say, quiet=False):
    """(the SolveRequest, the report's source fields) of a take whose target is a rig (``[rig]``): its controls are
    the shapes, the rig probed with progress (Ctrl-C stops it); a landmark take's eyes and scores reach the controls
    that read as shape weights."""
    from ..rig.rig_solve import rig_target_for_take  # loads bpy

    with showing_progress("rig probing", quiet=quiet or console.quiet(), unit="pose") as progress:
        target, fields = rig_target_for_take(config, obj, take.markers, say=say, progress=progress)
    tuning, version = config.tuning, None
    if tuning is not None and tuning.library is not None:
        version = load_version(tuning.library)
    request = SolveRequest(character=None, settings=config.settings, inputs=take.inputs, markers=take.markers,
                           version=version, corrections=corrections_for(config, target.control_names) if tune else None,
                           mu=None if tuning is None else tuning.mu, parent="" if version is None else version.name,
                           controls=config.controls or None, rig=target)
    if take.landmarks is not None:
        weights = target.weight_controls
        request, note = landmark_request(config, request, take, weights, (lambda _m: None) if quiet else say)
        take.notes = tuple(take.notes) + ((note,) if note else ()) + rig_weights_note(target, weights)
    return request, {**source_fields(config, take), "rig": fields}


def rig_weights_note(target, weights):
    """A note for a landmark take onto the rig ``target`` whose controls that read as shape weights are ``weights``
    (``RigTarget.weight_controls``): what of the video's blendshape scores and eyes the rig did not get."""
    if not weights:
        return ("[rig] none of the rig's controls reads as a shape weight (at rest at 0, limits 0 and 1), so the "
                "video's blendshape scores and its eyes' lids and irises do not reach it: solved from the landmarks "
                "alone (docs/video.md)",)
    others = len(target.control_names) - len(weights)
    if not others:
        return ()
    return (f"[rig] the video's blendshape scores and eyes reach the {len(weights)} control(s) that read as shape "
            f"weights (at rest at 0, limits 0 and 1); the other {others} are solved from the landmarks alone",)


def with_driven_keys(config, obj, take):
    """(config, notes): a shape-key take onto a mesh some of whose keys drivers set. Where every such
    driver reads only the mesh's own keys (correctives, in-betweens) and the solve is geometric on
    3D markers, the take is solved as the ``shape_keys`` rig (the driven keys fire through their
    drivers); otherwise they are left out of the solve (``scene_data.solvable_blocks``) and named."""
    if config.rig is not None or take.markers is None or getattr(obj, "type", None) != "MESH":
        return config, ()
    found = drivers.driven_keys(obj)
    if not found:
        return config, ()
    if config.settings.strategy == "geometric" and take.markers.dim == 3 and drivers.solved_through_drivers(obj):
        note = (f"{len(found)} shape key(s) of '{obj.name}' are set by drivers on its own keys ({', '.join(sorted(found)[:6])}"
                f"{'...' if len(found) > 6 else ''}): solved through their drivers, as [rig] preset = \"shape_keys\"")
        return dataclasses.replace(config, rig=RigSettings(preset="shape_keys")), (note,)
    return config, (drivers.left_out_note(obj, found),)


def shape_names(character):
    return character.shape_names if hasattr(character, "shape_names") else character.names


def corrections_for(config, names):
    tuning = config.tuning
    if tuning is None or tuning.corrections is None:
        raise ConfigError("the tune command needs the animator's corrections (frame,<shape>,... CSV)",
                          path=config.path, key="tuning.corrections")
    return read_corrections_csv(tuning.corrections, names)


def source_fields(config, take):
    """Where the take came from, for the report."""
    if take.markers is not None and isinstance(config.video, LandmarkTake):
        return {"video_file": config.video.path, "source": {**take.source, "fps": take.markers.fps}}
    if take.markers is not None:
        m = take.markers
        return {"markers_file": str(config.markers_path),
                "source": {**take.source, "fps": m.fps, "segments": dict(m.segments.items())}}
    if take.footage is not None:
        info = take.footage.info
        return {"video_file": config.video.path, "examples_file": str(config.examples_weights_path),
                "source": {"format": "video", "kind": info.kind, "fps": info.fps, "width": info.width,
                           "height": info.height, "scale": info.scale, "frames": [info.frames[0], info.frames[-1]],
                           "count": info.n_frames}}
    track = take.inputs.weights
    return {"weights_file": str(config.weights_path),
            "source": {"format": track.format, "fps": track.fps, "timecode": track.timecode}}
