"""Pieces of a headless take's solve request that do not need the take's character: the request of a take
whose target is a rig, the animator's corrections, the report's source fields."""

from ...solvers.errors import ConfigError
from ...solvers.solve import SolveRequest
from ...solvers.tuning.store import load_version, read_corrections_csv
from ...solvers.video.flow_config import LandmarkTake


def rig_request(config, obj, take, *, tune, say, progress=None):
    """The SolveRequest of a take whose target is a rig (``[rig]``): its controls are the shapes;
    ``progress(done, total) -> bool`` sees the probes (False cancels)."""
    from ..rig.rig_solve import rig_target_for_take  # loads bpy

    target, fields = rig_target_for_take(config, obj, take.markers, say=say, progress=progress)
    tuning, version = config.tuning, None
    if tuning is not None and tuning.library is not None:
        version = load_version(tuning.library)
    request = SolveRequest(character=None, settings=config.settings, inputs=take.inputs, markers=take.markers,
                           version=version, corrections=corrections_for(config, target.control_names) if tune else None,
                           mu=None if tuning is None else tuning.mu, parent="" if version is None else version.name,
                           controls=config.controls or None, rig=target)
    return request, {**source_fields(config, take), "rig": fields}


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
