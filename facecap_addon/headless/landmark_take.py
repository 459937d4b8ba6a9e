"""The headless side of a landmark take (``[tracking] method = "landmarks"``): the footage's face landmarks
as a marker take in metres, the character's eye-look shapes held at the irises' gaze, its blink and
wide shapes at the lids' gap, through the solve, and the blendshape scores' response for this performer and
camera (a ROM on camera, ``[calibration] video``, or a performer profile)."""

import dataclasses
from pathlib import Path

import numpy as np

from ...solvers.capture.normalise import detect_neutral_frames
from ...solvers.capture.stabilise import stabilise_rigid
from ...solvers.pipeline.stages import neutral_ranges
from ...solvers.errors import ConfigError, FacecapError
from ...solvers.io.weights import read_weights
from ...solvers.solve import solve_job
from ...solvers.video.cli import run_showing_progress
from ...solvers.video.follow import fit_follow
from ...solvers.video.fusion import FaceScores, FusionTable
from ...solvers.video.gaze import gaze_locks
from ...solvers.video.landmarks import RIGID, metric_take, track_landmarks_job
from ...solvers.video.reading import Footage
from ...solvers.video.response import fit_response, profile_contents, profile_performer
from . import console


def read_landmarks(video, say, *, quiet=False):
    """(markers in metres without the irises, source fields for the report, notes, the LandmarkResult) of
    the ``LandmarkTake`` ``video``; Ctrl-C stops between two frames (``Cancelled``: nothing written)."""
    footage = Footage(video.path, **video.footage, color=True)
    job = track_landmarks_job(footage, smoothing=video.smoothing, iris=video.iris, models=video.models,
                              bundle=video.bundle)
    found = run_showing_progress(job, "landmarks", quiet=quiet or console.quiet())
    say(found.summary())
    info = footage.info
    source = {"format": "video landmarks", "units": "m", "kind": info.kind, "fps": info.fps, "width": info.width,
              "height": info.height, "scale": info.scale, "landmarks": found.report()}
    notes = ()  # the strategy inputs' own notes are the solve's to say (it warns with them), as for marker takes
    if not found.found.all():
        notes += (f"{int((~found.found).sum())} frame(s) without a face are gaps",)
    return metric_take(found, iris=False), source, notes, found


def neutral_indices(settings, markers):
    """Indices of the take's neutral frames: the ``[neutral] frames`` given, else detected as the solve
    detects them (on the take held still by its head-rigid points); None when neither applies."""
    frames = markers.frames
    ranges = neutral_ranges(settings)
    if ranges:
        return np.flatnonzero(np.any([(frames >= a) & (frames <= b) for a, b in ranges], axis=0))
    if not settings.neutral_detect:
        return None
    stable = [n for n in RIGID if n in markers.names]
    held = stabilise_rigid(markers, stable).markers
    return np.flatnonzero(np.isin(frames, detect_neutral_frames(held)[0]))


def with_scores(request, found, video, response=None, performer=None):
    """``request`` carrying the Face Landmarker's blendshape scores of ``found`` (corrected by the take's neutral
    frames, read through the performer's ``response`` if known, and combined with the solve per shape,
    ``solvers/video/fusion.py``, through the map with the ``performer``'s clip in it if known, smoothed over time
    with ``[tracking] smoothing``) unless the take has none or its ``[tracking] blendshapes`` is "ignore"."""
    if found.blendshapes is None or getattr(video, "blendshapes", "fuse") == "ignore":
        return request
    neutral = neutral_indices(request.settings, request.markers)
    if neutral is None or not len(neutral):
        return request
    scores = FaceScores(found.blendshapes, tuple(found.blendshape_names), neutral, response=response,
                        fps=request.markers.fps, smoothing=bool(video.smoothing), performer=performer)
    return dataclasses.replace(request, scores=scores)


def follow_clip(config, found, say, *, quiet=False):
    """The LandmarkResult of the clip that follows ``[calibration] guide`` (its ``video``, else the take ``found``
    itself), or None when the take follows no guide."""
    rom = config.video_rom
    if rom is None or rom.guide is None:
        return None
    if rom.path is None:
        clip = found
    else:
        say(f"[1/5] face landmarks in the clip that follows the guide, {rom.path}")
        video = config.video
        job = track_landmarks_job(Footage(rom.path, color=True), smoothing=video.smoothing, iris=video.iris,
                                  models=video.models, bundle=video.bundle)
        clip = run_showing_progress(job, "guide clip landmarks", quiet=quiet or console.quiet())
    if clip.blendshapes is None:
        raise ConfigError("following a guide calibrates the fusion of the Face Landmarker's blendshape scores, and "
                          "these landmarks have none (the older models ran: `python -m facecap landmark-models fetch`)",
                          path=config.path, key="calibration.guide")
    return clip


def fit_guide(config, request, clip, names, say):
    """(the performer's clip in the fusion map, report fields): the clip that follows ``[calibration] guide`` solved
    as the take is (``request``, before its own gaze and scores: the same character, whose shapes are ``names``,
    and settings, the clip's own neutral), fused uncalibrated to find where it performs the guide, and its frames
    with the guide's weights as their truth added to the map (``solvers/video/follow.py``)."""
    rom = config.video_rom
    guide = read_weights(rom.guide, fps=rom.guide_fps)
    for note in guide.notes:
        say(f"guide {Path(rom.guide).name}: {note}")
    markers = metric_take(clip, iris=False)
    frames = markers.frames
    if rom.neutral is not None:
        settings = dataclasses.replace(request.settings, neutral_frames=tuple(rom.neutral), neutral_ranges=(),
                                       neutral_detect=False, neutral_file=None)
        neutral = np.flatnonzero((frames >= rom.neutral[0]) & (frames <= rom.neutral[1]))
    else:
        settings = dataclasses.replace(request.settings, neutral_ranges=(), neutral_detect=True, neutral_file=None)
        neutral = metric_neutral(markers)
    solving = dataclasses.replace(request, markers=markers, settings=settings, scores=None)
    solving, _ = hold_gaze(solving, tuple(names), clip)
    solved = solve_job(solving).run()
    scores = FaceScores(clip.blendshapes, tuple(clip.blendshape_names), neutral, fps=markers.fps,
                        smoothing=bool(config.video.smoothing))
    offset = None
    if rom.guide_start is not None:
        if not frames[0] <= rom.guide_start <= frames[-1]:
            raise ConfigError(f"frame {rom.guide_start:g} is outside the clip (frames {frames[0]:g}-{frames[-1]:g})",
                              path=config.path, key="calibration.guide_start")
        offset = int(round(float(np.interp(rom.guide_start, frames, np.arange(len(frames))))))
    try:
        fit = fit_follow(guide.values, guide.names, guide.fps, solved.weights, solved.shape_names, scores,
                         offset=offset, guide_label=Path(rom.guide).name)
    except FacecapError as exc:
        raise ConfigError(f"{rom.path or 'the take'} following {rom.guide}: {exc}", path=config.path,
                          key="calibration.guide") from None
    say(f"guide followed: {fit.summary}")
    return fit.performer, {"from": rom.path or "the take", **fit.report()}


def score_response(config, found, say, *, quiet=False):
    """(the blendshape scores' response or None, report fields or None, notes) of a landmark take: fitted from
    its ROM on camera (``[calibration] video``, or the take ``found`` itself when ``[calibration] sequence`` names
    its sheet) against the tuning faces' (the fusion table's reference), else read from ``[actor] profile``."""
    rom = config.video_rom
    if rom is not None and rom.guide is not None:  # the guide's clip is fitted once the character is open
        return None, None, ()
    if rom is not None:
        video = config.video
        if rom.path is None:
            clip = found
        else:
            say(f"[1/5] face landmarks in the ROM on camera {rom.path}")
            job = track_landmarks_job(Footage(rom.path, color=True), smoothing=video.smoothing, iris=video.iris,
                                      models=video.models, bundle=video.bundle)
            clip = run_showing_progress(job, "ROM landmarks", quiet=quiet or console.quiet())
        key = "calibration.video" if rom.path is not None else "calibration.sequence"
        if clip.blendshapes is None:
            raise ConfigError("the ROM on camera calibrates the Face Landmarker's blendshape scores, and these "
                              "landmarks have none (the older models ran: `python -m facecap landmark-models fetch`)",
                              path=config.path, key=key)
        frames = clip.markers.frames
        if rom.neutral is not None:
            neutral = np.flatnonzero((frames >= rom.neutral[0]) & (frames <= rom.neutral[1]))
        else:
            neutral = landmark_neutral(clip)
        given = None if rom.holds is None else given_indices(rom.holds, frames, config.path)
        try:
            fit = fit_response(clip.blendshapes, clip.blendshape_names, neutral, rom.poses,
                               fps=clip.markers.fps or 30.0, reference=FusionTable.load().reference, sheet=rom.sheet,
                               given=given)
        except FacecapError as exc:
            raise ConfigError(f"{rom.path or 'the take'}: {exc}", path=config.path, key=key) from None
        say(f"ROM on camera: {fit.summary}")
        report = {"from": rom.path or "the take", "sheet": rom.sheet, **fit.report()}
        return fit.response, report, fit.notes
    if config.actor_profile_path is not None:
        _, response = profile_contents(config.actor_profile_path)
        name = config.actor_profile_path.name
        if response is None and profile_performer(config.actor_profile_path) is not None:
            return None, None, ()  # a guide followed: its clip joins the map (``performer_of``)
        if response is None:
            return None, None, (f"[actor] profile {name} holds no blendshape response (its calibration was measured "
                                "from markers, not a ROM on camera): the scores are fused uncalibrated; film the ROM "
                                "and store it with [calibration] video and [output] profile",)
        return response, {"from": str(config.actor_profile_path), "sheet": response.sheet,
                          "shapes": len(response.changed())}, ()
    return None, None, ()


def performer_of(config, source):
    """The performer's clip in the fusion map that ``[actor] profile`` holds (a guide followed), or None; said in
    the report's ``source`` fields."""
    rom = config.video_rom
    if config.actor_profile_path is None or (rom is not None and rom.guide is not None):
        return None
    performer = profile_performer(config.actor_profile_path)
    if performer is not None:
        source["guide_followed"] = {"from": str(config.actor_profile_path), "guide": performer.guide,
                                    "weighs_as_clips": performer.clips}
    return performer


def landmark_request(config, request, take, names, say):
    """(``request`` with the take's gaze held through the solve and its scores to fuse, a note naming the shapes
    the gaze holds, or None) for the character's shapes ``names``; a clip that follows a guide is fitted first
    (``fit_guide``: solved as the take is, before the take's own gaze), into ``take.performer``."""
    if take.follow is not None:
        take.performer, take.source["guide_followed"] = fit_guide(config, request, take.follow, names, say)
    request, note = hold_gaze(request, names, take.landmarks)
    return with_scores(request, take.landmarks, config.video, take.response, take.performer), note


def given_indices(holds, frames, config_path=None):
    """{label: index into ``frames``} of ``holds`` ((label, frame number), ...: ``[calibration] holds`` or the
    ``ROM: `` timeline markers, ``config_path`` None); an error naming the pose when a frame is outside the ROM
    clip (ConfigError naming the key when it comes from a config)."""
    frames = np.asarray(frames, dtype=np.float64)
    out = {}
    for label, frame in holds:
        if not frames[0] <= frame <= frames[-1]:
            message = f"'{label}' is placed at frame {frame:g}, outside the ROM clip (frames {frames[0]:g}-" \
                      f"{frames[-1]:g})"
            if config_path is None:
                raise FacecapError(f"the timeline marker 'ROM: {label}': {message}; drag it onto the ROM take")
            raise ConfigError(message, path=config_path, key="calibration.holds")
        out[label] = float(np.interp(frame, frames, np.arange(len(frames), dtype=np.float64)))
    return out


def landmark_neutral(found):
    """Indices of the neutral frames detected in a LandmarkResult, as a landmark take's solve detects them."""
    return metric_neutral(metric_take(found, iris=False))


def metric_neutral(markers):
    """Indices of the neutral frames detected in a landmark take already in metres (``metric_take``: the
    sidebar's landmark takes), stabilised on its head-rigid landmarks."""
    stable = [n for n in RIGID if n in markers.names]
    held = stabilise_rigid(markers, stable).markers
    return np.flatnonzero(np.isin(markers.frames, detect_neutral_frames(held)[0]))


def hold_gaze(request, shape_names, found):
    """``request`` with the character's eye-look shapes locked, frame by frame, at the irises' gaze of
    ``found`` (a LandmarkResult) and its blink and wide shapes at the lids' gap, both measured from the
    take's neutral frames; returns (request, a note naming the shapes, or None)."""
    neutral = neutral_indices(request.settings, request.markers)
    gazed = gaze_locks(shape_names, found.markers.positions, neutral)
    if not gazed:
        return request, None
    settings = dataclasses.replace(request.settings, locks=tuple(request.settings.locks) + gazed)
    note = f"eyes from the irises and lids: {', '.join(n for n, _ in gazed)}"
    return dataclasses.replace(request, settings=settings), note
