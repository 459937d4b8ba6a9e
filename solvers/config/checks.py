"""Checks of a take config against the take itself, once it is read: frame ranges inside the takes
they name, smoothing windows shorter than the take. Errors name the config key."""

import numpy as np

from ..errors import ConfigError, InputFileError
from ..options import MAX_FRAME


def _inside(config, key, ranges, frames, what):
    frames = np.asarray(frames, dtype=np.float64)
    if frames.size == 0:
        return
    first, last = float(frames[0]), float(frames[-1])
    for a, b in ranges:
        if a < first or b > last:
            raise ConfigError(f"frames {a}-{b} are not all inside the {what} ({first:g}-{last:g})", path=config.path,
                              key=key)


def _keyable(path, frames):
    """InputFileError naming the take's file when its frames go beyond what Blender can key."""
    if frames is None or not len(frames):
        return
    first, last = float(np.min(frames)), float(np.max(frames))
    if last > MAX_FRAME or first < -MAX_FRAME:
        raise InputFileError(path, f"frames {first:g} to {last:g}: Blender keys frames from -{MAX_FRAME} to "
                                   f"{MAX_FRAME} only (a stray row, or frame numbers that are sample counts?)")


def check_against_take(config, markers=None, inputs=None):
    """Raise ConfigError when a frame range or window of ``config`` does not fit the takes read.

    markers : the take's MarkerSet (None for ``parallel`` and video takes)
    inputs : StrategyInputs (the calibration take, the solved weights of ``parallel``)
    """
    s = config.settings
    _keyable(config.markers_path, None if markers is None else markers.frames)
    _keyable(config.weights_path, getattr(getattr(inputs, "weights", None), "frames", None))
    if markers is not None:
        if not s.neutral_detect and s.neutral_file is None:
            ranges = s.neutral_ranges or ((s.neutral_frames,) if s.neutral_frames else ())
            _inside(config, "neutral.frames", ranges, markers.frames, "take")
        half = int(round(s.head_smoothing * markers.fps))
        if half and 2 * half + 1 > markers.n_frames:
            raise ConfigError(f"{s.head_smoothing:g} s is {half} frames at {markers.fps:g} fps: the smoothing window "
                              f"is longer than the take ({markers.n_frames} frames)", path=config.path,
                              key="stabilise.head_smoothing")
    if inputs is None:
        return
    calibration = getattr(inputs, "calibration", None)
    if calibration is not None:
        cal = s.calibration
        if cal.neutral_frames:
            _inside(config, "calibration.neutral", (cal.neutral_frames,), calibration.frames, "calibration take")
        for name, ranges in cal.poses:
            _inside(config, f"calibration.poses.{name}", ranges, calibration.frames, "calibration take")
    track = getattr(inputs, "weights", None)
    if track is not None and s.mapping.neutral_frames is not None:
        _inside(config, "mapping.neutral", (s.mapping.neutral_frames,), track.frames, "solved weights")
