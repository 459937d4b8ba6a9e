"""Already-solved blendshape weights: Live Link Face / ARKit CSV and MediaPipe-style CSV.

* **Live Link Face** (Epic's iOS app): ``Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,
  HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,
  RightEyeRoll``. Timecode ``HH:MM:SS:FF[.sub]`` at the timecode rate (``timecode_fps``, detected
  from the largest ``FF`` when not given: the next standard rate above it, 30 when below 24);
  frame 1 is the first row, ``WeightTrack.timecode`` keeps its timecode. Channel names are
  mapped to ARKit's lower-camel case.
* **MediaPipe** blendshape CSV: ``_neutral`` plus the 51 ARKit names MediaPipe outputs, with an
  optional ``frame`` / ``timestamp_ms`` / ``time`` column (otherwise row 1 is frame 1).
* Plain ``frame,<shape>,...`` (what facecap writes) is read too.

Variable-rate timestamps are resampled to ``fps`` (linear; the note says what was done).
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import FacecapError, InputFileError
from .arkit import ARKIT_52
from .csv import TIME_HEADERS, data_rows, duplicate_names, read_numeric_columns, read_text_columns, sniff, time_column
from .timing import MAX_BRIDGE, bridged_gaps, check_frame_range, frames_from_times, grid_offset, resample

HEAD_CHANNELS = ("HeadYaw", "HeadPitch", "HeadRoll")
EYE_CHANNELS = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
_ARKIT_BY_LOWER = {n.lower(): n for n in ARKIT_52}
_TIMECODE_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0)


@dataclass(frozen=True, eq=False)
class WeightTrack:
    """Per-frame blendshape weights from another solver.

    Attributes
    ----------
    frames : ndarray (F,)
    fps : float
    names : tuple of str, length K
        ARKit names where recognised (``eyeBlinkLeft``), otherwise as in the file.
    values : ndarray (F, K)
        Weights, usually in [0, 1]; NaN for a missing cell.
    head : ndarray (F, 3) or None
        Head yaw, pitch, roll in radians, as Live Link Face writes them (``HEAD_CHANNELS``), on ``frames``
        (resampled with the weights); None when the file has no head columns.
    eyes : ndarray (F, 6) or None
        Left eye yaw, pitch, roll then right eye yaw, pitch, roll in radians (``EYE_CHANNELS``): what
        the gaze shapes follow; None when the file has no eye columns.
    source : str
    format : str
        "livelinkface", "mediapipe" or "weights".
    timecode : str
        First timecode of the take ("" when the file has none).
    notes : tuple of str
    """

    frames: np.ndarray
    fps: float
    names: tuple
    values: np.ndarray
    head: np.ndarray = None
    eyes: np.ndarray = None
    source: str = ""
    format: str = "weights"
    timecode: str = ""
    notes: tuple = field(default_factory=tuple)

    #: The columns of ``head`` and ``eyes``, in order (not fields: the same for every track)
    HEAD_CHANNELS = HEAD_CHANNELS
    EYE_CHANNELS = EYE_CHANNELS

    def angles(self):
        """{column name: (F,) radians} of the head and eye angles the file has (empty without any)."""
        out = {}
        for names, values in ((HEAD_CHANNELS, self.head), (EYE_CHANNELS, self.eyes)):
            if values is not None:
                out.update({n: np.asarray(values)[:, j] for j, n in enumerate(names)})
        return out


def parse_timecode(text, rate):
    """Seconds for ``HH:MM:SS:FF[.sub]`` (``;`` allowed for drop-frame) at ``rate`` frames per second."""
    parts = text.strip().replace(";", ":").split(":")
    if len(parts) != 4:
        raise ValueError(text)
    h, m, s = int(parts[0]), int(parts[1]), int(parts[2])
    ff = float(parts[3])
    if not (0 <= m < 60 and 0 <= s < 60 and 0 <= ff and h >= 0 and np.isfinite(ff)):
        raise ValueError(text)
    return h * 3600 + m * 60 + s + ff / rate


def read_weights(path, *, fps=None, timecode_fps=None):
    """Read a solved-weights CSV (Live Link Face, MediaPipe or ``frame,<shape>``) as a WeightTrack.

    Timestamps (Live Link Face timecodes, time columns) become frames at ``fps``; when the samples
    are not on a regular grid (dropouts, drift) the weights are interpolated linearly onto it,
    and frames inside a dropout longer than ``timing.MAX_BRIDGE`` frames are gaps (NaN).

    Parameters
    ----------
    path : path-like
    fps : float or None
        Frame rate of the result; None takes the file's (estimated from timestamps; 60 for Live
        Link Face without usable timecodes, 30 for MediaPipe without a time column).
    timecode_fps : float or None
        Rate of the ``FF`` field of Live Link Face timecodes; None detects it.
    """
    notes = []
    sn = sniff(path)
    header = list(sn.header)
    path = sn.path
    dup = duplicate_names(header)
    if dup:
        raise InputFileError(path, f"duplicate columns {dup[:10]}", line=sn.header_line)
    low = [h.lower() for h in header]
    tc_col = low.index("timecode") if "timecode" in low else None
    key_col, time_scale = time_column(header)
    skip = {i for i, h in enumerate(low) if h in ("timecode", "blendshapecount")}
    if key_col is not None:
        skip.add(key_col)
    cols = [i for i in range(len(header)) if i not in skip]
    if not cols:
        raise InputFileError(path, "no weight columns", line=sn.header_line)
    kind = "livelinkface" if tc_col is not None or "blendshapecount" in low else (
        "mediapipe" if "_neutral" in low else "weights")
    _, values = read_numeric_columns(sn, ([key_col] if key_col is not None else []) + cols)
    if values.shape[0] == 0:
        raise InputFileError(path, "zero frames: no data rows after the header", line=sn.header_line)
    key = None
    if key_col is not None:
        key, values = values[:, 0], values[:, 1:]
    names = [header[i] for i in cols]
    timecode = ""
    if tc_col is not None:
        times, timecode = _timecode_times(sn, tc_col, timecode_fps, notes)
        times = times - times[0]  # frame 1 is the first row, exactly
    elif key is not None and time_scale is not None:
        times = key * time_scale
    else:
        times = None
    if times is not None:
        frames, values, fps_out = _on_frames(path, times, values, fps, notes)
        if tc_col is not None:
            frames = frames - frames[0] + 1.0
            notes.append(f"frame 1 is timecode {timecode}")
    else:
        frames = key if key is not None else np.arange(1, values.shape[0] + 1, dtype=np.float64)
        if key is None:
            notes.append("no frame or time column: row 1 is frame 1")
        elif np.any(~np.isfinite(frames)) or np.any(np.diff(frames) <= 0):
            raise InputFileError(path, "frame numbers must be present and increase from row to row",
                                 field=header[key_col])
        fps_out = fps or (30.0 if kind == "mediapipe" else 60.0)
        if not fps:
            notes.append(f"the file gives no frame rate: assumed {fps_out:g} fps; set `fps` if wrong")
    try:
        check_frame_range(frames, str(path))
    except FacecapError as exc:
        raise InputFileError(path, str(exc).split(": ", 1)[-1], field=header[key_col] if key_col is not None else None
                             ) from None
    return _track(path, sn, names, frames, fps_out, values, kind, timecode, notes)


def _timecode_times(sn, tc_col, timecode_fps, notes):
    """(seconds (F,), first timecode) of a Live Link Face ``Timecode`` column; the FF rate detected if not given."""
    path, header = sn.path, sn.header
    cells = read_text_columns(sn, [tc_col])[0]
    line_numbers = [line for line, _ in data_rows(sn)]
    ff = []
    for r, cell in enumerate(cells):
        parts = cell.replace(";", ":").split(":")
        try:
            ff.append(float(parts[3]) if len(parts) == 4 else np.nan)
        except ValueError:
            ff.append(np.nan)
        if not np.isfinite(ff[-1]):
            raise InputFileError(path, f"expected a timecode HH:MM:SS:FF, got {cell!r}",
                                 line=line_numbers[r], field=header[tc_col])
    ff_max = max(ff)
    rate = timecode_fps or (30.0 if ff_max < 24 else next((r for r in _TIMECODE_RATES if ff_max < r), 60.0))
    secs = []
    for r, cell in enumerate(cells):
        try:
            secs.append(parse_timecode(cell, rate))
        except (ValueError, IndexError, OverflowError):
            raise InputFileError(path, f"expected a timecode HH:MM:SS:FF, got {cell!r}",
                                 line=line_numbers[r], field=header[tc_col]) from None
    notes.append(f"timecode rate {rate:g} fps" + ("" if timecode_fps else " (detected)"))
    return np.asarray(secs), cells[0]


def _on_frames(path, times, values, fps, notes):
    """(frames, values, fps): timestamps turned into frames, resampled when irregular."""
    if np.any(~np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise InputFileError(path, "timestamps must be present and increase strictly")
    try:
        frames, rate, regular = frames_from_times(times, fps=fps, where=str(path))
    except FacecapError as exc:
        raise InputFileError(path, str(exc).split(": ", 1)[-1]) from None
    if fps is None:
        notes.append(f"frame rate {rate:.6g} fps from the timestamps (median step "
                     f"{np.median(np.diff(times)) * 1e3:.4g} ms); set `fps` to resample to another")
    if regular:
        return frames, values, rate
    try:
        frames, resampled = resample(times, values[:, None, :], rate)
    except FacecapError as exc:
        raise InputFileError(path, str(exc)) from None
    dropped = bridged_gaps(times, rate)
    drift = grid_offset(times * rate)
    notes.append(f"irregular timestamps (rows up to {drift:.2g} frame off the frame grid) resampled (linear) to "
                 f"{rate:.6g} fps: {len(times)} rows -> "
                 f"{len(frames)} frames" + (f"; {dropped} frame(s) in dropouts longer than {MAX_BRIDGE:g} "
                                            "frames left as gaps" if dropped else ""))
    return frames, resampled[:, 0, :], rate


def _track(path, sn, names, frames, fps, values, kind, timecode, notes):
    head = _take(names, values, HEAD_CHANNELS)
    eyes = _take(names, values, EYE_CHANNELS)
    extra = set(HEAD_CHANNELS + EYE_CHANNELS)
    keep = [j for j, n in enumerate(names) if n not in extra]
    shape_names = tuple(_ARKIT_BY_LOWER.get(names[j].lower(), names[j]) for j in keep)
    dup = duplicate_names(shape_names)
    if dup:
        raise InputFileError(path, f"two columns map to the same shape name {dup[:10]}", line=sn.header_line)
    weights = values[:, keep]
    outside = int(np.count_nonzero((weights < -1e-6) | (weights > 1 + 1e-6)))
    if outside:
        notes.append(f"{outside} weight(s) outside [0, 1]")
    return WeightTrack(frames=np.asarray(frames, dtype=np.float64), fps=float(fps), names=shape_names,
                       values=weights, head=head, eyes=eyes, source=str(path), format=kind,
                       timecode=timecode, notes=tuple(notes))


def _take(names, values, wanted):
    idx = [names.index(w) for w in wanted if w in names]
    if len(idx) != len(wanted):
        return None
    return values[:, idx]


__all__ = ["EYE_CHANNELS", "HEAD_CHANNELS", "TIME_HEADERS", "WeightTrack", "parse_timecode", "read_weights"]
