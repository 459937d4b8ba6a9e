"""Units, up-axis and timing shared by every marker reader.

Readers hand a raw MarkerSet (in the file's own units, axes and frame numbering) to
:func:`finish`, which applies what the user asked for and returns the notes it made: units
given or detected, a Y-up to Z-up conversion, timestamps turned into frames, and variable-rate
timestamps resampled to a fixed rate.
"""

import numpy as np

from ..errors import FacecapError, InputFileError
from ..markers import UNIT_SCALE, MarkerSet

#: Units a reader accepts; "bu" (Blender units) needs ``unit_scale`` (metres per unit).
UNIT_CHOICES = ("m", "cm", "mm", "bu", "px")
UNIT_ALIASES = {
    "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
    "cm": "cm", "centimeter": "cm", "centimeters": "cm", "centimetre": "cm", "centimetres": "cm",
    "mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
    "bu": "bu", "blender": "bu", "px": "px", "pixel": "px", "pixels": "px",
}
#: A timestamp step this far (relative) from the median step makes the take "variable rate".
RATE_TOLERANCE = 0.02


def normalise_units(units, *, what="units"):
    """Canonical unit name for ``units`` (None stays None); FacecapError naming the choices."""
    if units is None:
        return None
    key = str(units).strip().lower()
    if key not in UNIT_ALIASES:
        raise FacecapError(f"`{what}` must be one of {', '.join(UNIT_CHOICES)}; got {units!r}")
    return UNIT_ALIASES[key]


#: Frame rate used when neither the file nor the user gives one (noted).
DEFAULT_FPS = 60.0
#: Note prefixes that say a value was not given but decided (``ImportResult.decided`` reads them).
UNITS_GUESSED = "units not given: guessed"
FPS_ASSUMED = "frame rate assumed:"


def y_up_evidence(positions):
    """Why (F, M, 3) positions in metres look Y-up, or None: the markers stand high on Y (median
    above 0.3 m, three times their median |z|), as a body or a face does above a floor in a Y-up lab."""
    finite = positions[np.isfinite(positions).all(axis=-1)]
    if finite.shape[0] < 3:
        return None
    y, z = np.median(finite[:, 1]), np.median(finite[:, 2])
    if y > 0.3 and y > 3 * abs(z):
        return f"the markers stand high on Y (median y {y:.2f} m, z {z:.2f} m)"
    return None


#: Median marker extent (metres) a face's markers span; outside it the guessed units are questioned.
FACE_SPAN = (0.03, 0.4)


def guess_units(positions, *, with_spread=False):
    """Guess m/cm/mm from the size of a face: the median marker spread is ~0.05-0.2 m.

    Returns (units, reason) or (None, reason) when nothing is visible; with ``with_spread``
    also the median extent in file units (NaN when nothing is visible).
    """
    finite = positions[np.isfinite(positions).all(axis=-1)] if positions.size else positions
    if finite.size == 0:
        return (None, "no visible samples", np.nan) if with_spread else (None, "no visible samples")
    spread = float(np.median(np.ptp(finite, axis=0)))
    units = "mm" if spread > 30 else "cm" if spread > 3 else "m"
    why = f"median extent {spread:.3g}"
    return (units, why, spread) if with_spread else (units, why)


def y_up_to_z_up(positions):
    """(x, y, z) Y-up right-handed -> (x, -z, y) Z-up right-handed (Blender)."""
    out = np.empty_like(positions)
    out[..., 0] = positions[..., 0]
    out[..., 1] = -positions[..., 2]
    out[..., 2] = positions[..., 1]
    return out


#: Frame rates an estimate from timestamps snaps to when within SNAP_TOLERANCE (relative).
STANDARD_RATES = (23.976, 24.0, 25.0, 29.97, 30.0, 48.0, 50.0, 59.94, 60.0, 90.0, 100.0, 120.0, 240.0)
SNAP_TOLERANCE = 1e-3
#: Two times closer than this (in frames) are the same frame. Absolute, not relative: Live Link Face
#: timecodes are times of day, about 1.4 million frames, where a relative tolerance spans frames.
FRAME_TOLERANCE = 1e-6
#: A resampled frame between two samples farther apart than this (frames) is a gap, not interpolated.
MAX_BRIDGE = 2.5
#: Samples are taken as on the frame grid (their times rounded to frames) while every one is within this
#: (frames) of its whole frame, counted from the first sample. Timestamps rounded to the millisecond at
#: 60 fps are within 0.03; a clock drifting against the rate (Live Link Face at 59.94 fps with 60 fps
#: timecodes: 0.13 frame) is beyond it, and the rows are interpolated onto the grid instead.
GRID_TOLERANCE = 0.05


def estimate_rate(times):
    """Frame rate from the median timestamp step, snapped to a standard rate within 0.1 %."""
    steps = np.diff(np.asarray(times, dtype=np.float64))
    fps = 1.0 / float(np.median(steps))
    if np.isfinite(fps) and fps > 0:
        near = min(STANDARD_RATES, key=lambda r: abs(fps / r - 1.0))
        if abs(fps / near - 1.0) < SNAP_TOLERANCE:
            return near
    return fps


def frames_from_times(times, *, fps=None, where="timestamps"):
    """Frame numbers for ``times`` (seconds) at ``fps`` (estimated when None).

    Returns (frames, fps, regular): ``regular`` is False when the steps vary by more than
    RATE_TOLERANCE, a sample lies more than GRID_TOLERANCE off the frame grid (counted from the first
    sample: a drifting clock) or rounding would skip or repeat a frame, in which case ``frames`` are
    fractional and the caller should resample.
    """
    times = np.asarray(times, dtype=np.float64)
    if times.size > 1 and np.any(np.diff(times) <= 0):
        raise FacecapError(f"{where}: timestamps must increase strictly")
    steps = np.diff(times)
    if fps is None:
        if steps.size == 0:
            raise FacecapError(f"{where}: one timestamp gives no frame rate; pass fps")
        fps = estimate_rate(times)
    if not np.isfinite(fps) or fps <= 0:
        raise FacecapError(f"{where}: frame rate must be positive; got {fps}")
    raw = times * fps
    regular = steps.size == 0 or bool(np.all(np.abs(steps * fps - 1.0) <= RATE_TOLERANCE))
    if regular and raw.size > 1:
        regular = grid_offset(raw) <= GRID_TOLERANCE
    if regular:
        frames = np.round(raw) + 0.0  # no -0.0
        if np.all(np.diff(frames) == 1.0):  # drift can make rounding skip or repeat a frame
            return frames, float(fps), True
    return raw, float(fps), False


def grid_offset(raw):
    """The largest distance (frames) of the samples at ``raw`` (times in frames) from the whole-frame grid
    through the first sample."""
    rel = np.asarray(raw, dtype=np.float64) - raw[0]
    return float(np.max(np.abs(rel - np.round(rel)))) if rel.size else 0.0


def resample(times, positions, fps):
    """Linear resampling of (F, M, D) ``positions`` sampled at ``times`` onto whole frames.

    A resampled sample is a gap when either bracketing source sample is a gap or the two are more
    than MAX_BRIDGE frames apart (interpolation would invent motion). Times are compared in frames
    with an absolute tolerance, FRAME_TOLERANCE, relative to the first sample's whole frame, so
    times of day (~1e6 frames) interpolate as exactly as times near zero. Returns (frames, positions).
    """
    raw = np.asarray(times, dtype=np.float64) * fps
    span = raw[-1] - raw[0]
    if span > 10 * raw.size + 1000:
        raise FacecapError(f"timestamps span {span / fps:.6g} s for {raw.size} samples; refusing to resample "
                           f"to {span:.0f} frames at {fps:g} fps (wrong time column or rate?)")
    origin = np.floor(raw[0])
    rel = raw - origin
    frames = np.arange(np.ceil(rel[0] - FRAME_TOLERANCE), np.floor(rel[-1] + FRAME_TOLERANCE) + 1.0)
    if frames.size == 0:
        frames = np.array([np.round(rel[0])])
    if raw.size == 1:
        return frames + origin, positions[:1].copy()
    hi = np.clip(np.searchsorted(rel, frames, side="left"), 1, raw.size - 1)
    lo = hi - 1
    gap = rel[hi] - rel[lo]
    t = np.clip((frames - rel[lo]) / gap, 0.0, 1.0)[:, None, None]
    out = positions[lo] * (1.0 - t) + positions[hi] * t
    exact_lo = np.abs(frames - rel[lo]) <= FRAME_TOLERANCE
    exact_hi = np.abs(frames - rel[hi]) <= FRAME_TOLERANCE
    out[exact_lo] = positions[lo][exact_lo]
    out[exact_hi] = positions[hi][exact_hi]
    out[(gap > MAX_BRIDGE) & ~exact_lo & ~exact_hi] = np.nan
    return frames + origin, out


def bridged_gaps(times, fps):
    """How many whole frames :func:`resample` leaves as gaps because they fall in dropouts longer than MAX_BRIDGE."""
    raw = np.asarray(times, dtype=np.float64) * fps
    rel = raw - np.floor(raw[0])
    a, b = rel[:-1], rel[1:]
    wide = (b - a) > MAX_BRIDGE
    inside = np.floor(b[wide] - FRAME_TOLERANCE) - np.ceil(a[wide] + FRAME_TOLERANCE) + 1
    return int(np.sum(np.maximum(inside, 0)))


def finish(markers, **options):
    """:func:`finish_arrays` on an existing MarkerSet's names, frames, positions, fps and segments."""
    options.setdefault("file_fps", markers.fps)
    return finish_arrays(markers.names, markers.frames, markers.positions, source=markers.source,
                         segments=markers.segments, **options)


def finish_arrays(names, frames, positions, *, source="", file_fps=None, segments=None, units=None,
                  file_units=None, unit_scale=None, up_axis=None, times=None, fps=None, labels=None,
                  notes=None, up_hint=None):
    """Apply units, axis and timing to a reader's raw MarkerSet.

    The MarkerSet is built once, at the end (no intermediate copies of a large take).

    Parameters
    ----------
    names, frames, positions
        Positions (F, M, D) in the file's units; ``frames`` are frame numbers (ignored when
        ``times`` is given).
    source : str
    file_fps : float or None
        The file's frame rate, used when ``fps`` is None and there are no timestamps; None (the
        file has none): DEFAULT_FPS, with a note.
    segments : dict or None
    units : str or None
        What the user says the numbers are; overrides ``file_units``. "bu" needs ``unit_scale``.
    file_units : str or None
        What the file says; when both are None the units are guessed from the face size.
    unit_scale : float or None
        Metres per file unit for "bu" (Blender units); the result is then in metres.
    up_axis : {"Z", "Y", None}
        Up axis of the file; "Y" is converted to Blender's Z-up.
    times : ndarray (F,) or None
        Timestamps in seconds; converted to frames at ``fps`` (estimated when None), resampled
        when the rate varies.
    fps : float or None
    labels : sequence of str or None
        One segment label per input row ("" = none); turned into ``segments`` after timing.
    notes : list
        Receives one line per thing done; ``hint:`` lines suggest a setting, ``warning:`` lines say
        the data were changed or are suspect.
    up_hint : str or None
        What the file says that suggests it is Y-up (C3D: ``POINT:Y_SCREEN '+Y'``), "" when it says
        otherwise; None looks at the markers' heights instead. Only used when ``up_axis`` is None.

    Returns
    -------
    MarkerSet
    """
    notes = [] if notes is None else notes
    where = source or "markers"
    positions = np.asarray(positions, dtype=np.float64)
    dim = positions.shape[-1] if positions.ndim == 3 else 0
    segments = dict(segments or {})
    chosen = normalise_units(units) or normalise_units(file_units, what="file units")
    said = UNIT_ALIASES.get(str(file_units).strip().lower()) if file_units is not None else None
    if units is not None and said is not None and chosen != said:  # the user's word wins, but not silently
        factor = UNIT_SCALE.get(chosen, 1.0) / UNIT_SCALE.get(said, 1.0) if chosen in UNIT_SCALE else None
        notes.append(f"warning: the file says its units are {said}, read as {chosen} as asked ([source] units, "
                     f"--units)" + (f": {factor:g} times the size the file gives" if factor else "")
                     + "; drop the units option to use the file's")
    if chosen is None:
        if dim == 2:
            chosen = "px"
            notes.append("2D data: units taken as pixels")
        else:
            chosen, why, spread = guess_units(positions, with_spread=True)
            chosen = chosen or "m"
            text = f"{UNITS_GUESSED} {chosen} from the markers' size ({why}; a face spans 0.05-0.3 m)"
            metres = spread * UNIT_SCALE[chosen]
            if not FACE_SPAN[0] <= metres <= FACE_SPAN[1]:
                text += (f"; {metres:.3g} m is not a face's size: for Blender units set units = \"bu\" and unit_scale "
                         "(metres per unit, docs/capture-data.md)")
            notes.append(text + '; if wrong, set units = "m", "cm" or "mm" ([source] units, --units)')
    if chosen == "bu":
        if unit_scale is None or not np.isfinite(unit_scale) or unit_scale <= 0:
            raise FacecapError(f"{where}: units 'bu' (Blender units) need a positive unit_scale "
                               f"(metres per unit); got {unit_scale!r}")
        positions = positions * float(unit_scale)
        notes.append(f"Blender units scaled by {unit_scale:g} m per unit")
        chosen = "m"
    elif unit_scale is not None:
        if not np.isfinite(unit_scale) or unit_scale <= 0:
            raise FacecapError(f"{where}: unit_scale must be positive; got {unit_scale!r}")
        positions = positions * float(unit_scale)
        notes.append(f"positions scaled by {unit_scale:g}")
    if chosen not in UNIT_SCALE and chosen != "px":
        raise FacecapError(f"{where}: unsupported units {chosen!r}")
    if up_axis is None and dim == 3:
        hint = y_up_evidence(positions * UNIT_SCALE.get(chosen, 1.0)) if up_hint is None else up_hint
        if hint:
            notes.append(f"hint: {hint}: if the file is Y-up, set up_axis = \"Y\" ([source] up_axis, --up-axis Y) "
                         "to turn it Z-up for Blender")
    axis = None if up_axis is None else str(up_axis).strip().upper()
    if axis not in (None, "Z", "Y"):
        raise FacecapError(f"`up_axis` must be 'Y' or 'Z'; got {up_axis!r}")
    if axis == "Y":
        if dim != 3:
            raise FacecapError(f"{where}: up_axis='Y' needs 3D markers")
        positions = y_up_to_z_up(positions)
        notes.append("converted Y-up to Z-up: (x, y, z) -> (x, -z, y)")
    rate = file_fps if fps is None else float(fps)
    if rate is None:
        rate = DEFAULT_FPS
        if times is None:
            notes.append(f"{FPS_ASSUMED} {DEFAULT_FPS:g} fps (the file gives no frame rate): if wrong, set fps "
                         "([source] fps, --fps)")
    if times is not None:
        frames, rate, regular = frames_from_times(times, fps=fps, where=where)
        if regular:
            notes.append(f"timestamps at a regular {rate:.6g} fps turned into frames "
                         f"{int(frames[0])}..{int(frames[-1])}")
        else:
            steps = np.diff(np.asarray(times, dtype=np.float64))
            frames, positions = resample(times, positions, rate)
            notes.append(
                f"variable-rate timestamps (steps {steps.min() * 1e3:.4g}-{steps.max() * 1e3:.4g} ms) "
                f"resampled linearly to {rate:.6g} fps: {len(times)} samples -> {len(frames)} frames"
            )
            if labels is not None:
                raw = np.asarray(times, dtype=np.float64) * rate
                nearest = np.clip(np.searchsorted(raw, frames), 0, len(raw) - 1)
                left = np.clip(nearest - 1, 0, len(raw) - 1)
                nearest = np.where(np.abs(raw[left] - frames) < np.abs(raw[nearest] - frames), left, nearest)
                labels = [labels[i] for i in nearest]
    check_frame_range(frames, where, notes)
    if labels is not None:
        segments = segments_from_labels(list(labels), frames)
    return MarkerSet(names, frames, positions, fps=rate, units=chosen, source=source, segments=segments)


def segments_from_labels(labels, frames):
    """``{label: [(first, last), ...]}`` from one label per frame (empty = no segment)."""
    out = {}
    start = None
    for i, label in enumerate(list(labels) + [None]):
        if start is not None and label != labels[start]:
            out.setdefault(labels[start], []).append((float(frames[start]), float(frames[i - 1])))
            start = None
        if start is None and label:
            start = i
    return out


#: Frame numbers must stay below this in magnitude (Blender keys frames as 32-bit integers).
MAX_FRAME = 2 ** 31 - 1
#: Blender's timeline ends here (MAXFRAME); frames beyond it load, with a note.
BLENDER_MAX_FRAME = 1_048_574


def check_frame_range(frames, where, notes=None):
    """InputFileError-ready FacecapError when a frame number is not finite or not below 2^31 in magnitude."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.size == 0:
        return
    bad = ~np.isfinite(frames) | (np.abs(frames) > MAX_FRAME)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise FacecapError(f"{where}: frame number {frames[i]:.6g} (data row {i + 1}) is outside +-{MAX_FRAME} "
                           "(frame numbers are 32-bit in Blender); renumber the frames")
    if notes is not None and (frames.max() > BLENDER_MAX_FRAME or frames.min() < -BLENDER_MAX_FRAME):
        notes.append(f"warning: frames {frames.min():g}..{frames.max():g} run past Blender's timeline "
                     f"(+-{BLENDER_MAX_FRAME}); keys there cannot be shown")


def unique_names(names, notes, *, where="labels"):
    """``names`` with repeats suffixed ``_2``, ``_3``, ... (never clashing); a warning note names them."""
    names = list(names)
    taken = set(names)
    seen = set()
    renamed = []
    for i, name in enumerate(names):
        if name not in seen:
            seen.add(name)
            continue
        k = 2
        while f"{name}_{k}" in taken:
            k += 1
        names[i] = f"{name}_{k}"
        taken.add(names[i])
        renamed.append((name, names[i]))
    if renamed:
        shown = ", ".join(f"{a!r} -> {b!r}" for a, b in renamed[:8])
        more = f" and {len(renamed) - 8} more" if len(renamed) > 8 else ""
        notes.append(f"warning: {where} repeats {len(renamed)} name(s); the repeats are kept as {shown}{more}")
    return tuple(names)


def check_markerset(build, path):
    """Call ``build()`` and turn a MarkerSet validation error into an InputFileError for ``path``."""

    try:
        return build()
    except InputFileError:
        raise
    except FacecapError as exc:
        text = str(exc)
        prefix = f"{path}: "
        raise InputFileError(path, text[len(prefix):] if text.startswith(prefix) else text) from None


__all__ = ["BLENDER_MAX_FRAME", "DEFAULT_FPS", "FPS_ASSUMED", "MAX_FRAME", "MarkerSet", "UNITS_GUESSED", "UNIT_CHOICES", "bridged_gaps", "check_frame_range",
           "estimate_rate", "finish", "finish_arrays", "frames_from_times", "grid_offset", "guess_units", "normalise_units",
           "resample", "segments_from_labels", "unique_names", "y_up_evidence", "y_up_to_z_up"]
