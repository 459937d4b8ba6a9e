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


def guess_units(positions):
    """Guess m/cm/mm from the size of a face: the median marker spread is ~0.05-0.2 m.

    Returns (units, reason) or (None, reason) when nothing is visible.
    """
    finite = positions[np.isfinite(positions).all(axis=-1)] if positions.size else positions
    if finite.size == 0:
        return None, "no visible samples"
    spread = float(np.median(np.ptp(finite, axis=0)))
    if spread > 30:
        return "mm", f"median extent {spread:.3g}"
    if spread > 3:
        return "cm", f"median extent {spread:.3g}"
    return "m", f"median extent {spread:.3g}"


def y_up_to_z_up(positions):
    """(x, y, z) Y-up right-handed -> (x, -z, y) Z-up right-handed (Blender)."""
    out = np.empty_like(positions)
    out[..., 0] = positions[..., 0]
    out[..., 1] = -positions[..., 2]
    out[..., 2] = positions[..., 1]
    return out


def frames_from_times(times, *, fps=None, where="timestamps"):
    """Frame numbers for ``times`` (seconds) at ``fps`` (estimated when None).

    Returns (frames, fps, regular): ``regular`` is False when the steps vary by more than
    RATE_TOLERANCE, in which case ``frames`` are fractional and the caller should resample.
    """
    times = np.asarray(times, dtype=np.float64)
    if times.size > 1 and np.any(np.diff(times) <= 0):
        raise FacecapError(f"{where}: timestamps must increase strictly")
    steps = np.diff(times)
    if fps is None:
        if steps.size == 0:
            raise FacecapError(f"{where}: one timestamp gives no frame rate; pass fps")
        fps = 1.0 / float(np.median(steps))
    if not np.isfinite(fps) or fps <= 0:
        raise FacecapError(f"{where}: frame rate must be positive; got {fps}")
    raw = times * fps
    regular = steps.size == 0 or bool(np.all(np.abs(steps * fps - 1.0) <= RATE_TOLERANCE))
    if regular:
        frames = np.round(raw) + 0.0  # no -0.0
        if np.any(np.diff(frames) <= 0):
            regular = False
        else:
            return frames, float(fps), True
    return raw, float(fps), False


def resample(times, positions, fps):
    """Linear resampling of (F, M, D) ``positions`` sampled at ``times`` onto whole frames.

    A resampled sample is a gap when either bracketing source sample is a gap or the two are more
    than 2.5 frames apart (interpolation would invent motion). Returns (frames, positions).
    """
    raw = np.asarray(times, dtype=np.float64) * fps
    span = raw[-1] - raw[0]
    if span > 10 * raw.size + 1000:
        raise FacecapError(f"timestamps span {span / fps:.6g} s for {raw.size} samples; refusing to resample "
                           f"to {span:.0f} frames at {fps:g} fps (wrong time column or rate?)")
    frames = np.arange(np.ceil(raw[0] - 1e-9), np.floor(raw[-1] + 1e-9) + 1.0)
    if frames.size == 0:
        frames = np.array([np.round(raw[0])])
    hi = np.clip(np.searchsorted(raw, frames, side="left"), 1, max(raw.size - 1, 1))
    lo = hi - 1
    if raw.size == 1:
        return frames, positions[:1].copy()
    span = raw[hi] - raw[lo]
    t = np.clip((frames - raw[lo]) / span, 0.0, 1.0)[:, None, None]
    out = positions[lo] * (1.0 - t) + positions[hi] * t
    exact_lo = np.isclose(frames, raw[lo])
    exact_hi = np.isclose(frames, raw[hi])
    out[exact_lo] = positions[lo][exact_lo]
    out[exact_hi] = positions[hi][exact_hi]
    wide = (span > 2.5) & ~exact_lo & ~exact_hi
    out[wide] = np.nan
    return frames, out


def finish(markers, **options):
    """:func:`finish_arrays` on an existing MarkerSet's names, frames, positions, fps and segments."""
    return finish_arrays(markers.names, markers.frames, markers.positions, source=markers.source,
                         file_fps=markers.fps, segments=markers.segments, **options)


def finish_arrays(names, frames, positions, *, source="", file_fps=60.0, segments=None, units=None,
                  file_units=None, unit_scale=None, up_axis=None, times=None, fps=None, labels=None,
                  notes=None):
    """Apply units, axis and timing to a reader's raw MarkerSet.

    The MarkerSet is built once, at the end (no intermediate copies of a large take).

    Parameters
    ----------
    names, frames, positions
        Positions (F, M, D) in the file's units; ``frames`` are frame numbers (ignored when
        ``times`` is given).
    source : str
    file_fps : float
        The file's frame rate, used when ``fps`` is None and there are no timestamps.
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
        Receives one line per thing done.

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
    if chosen is None:
        if dim == 2:
            chosen = "px"
            notes.append("2D data: units taken as pixels")
        else:
            chosen, why = guess_units(positions)
            chosen = chosen or "m"
            notes.append(f"units not given: guessed {chosen} ({why})")
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
    axis = None if up_axis is None else str(up_axis).strip().upper()
    if axis not in (None, "Z", "Y"):
        raise FacecapError(f"`up_axis` must be 'Y' or 'Z'; got {up_axis!r}")
    if axis == "Y":
        if dim != 3:
            raise FacecapError(f"{where}: up_axis='Y' needs 3D markers")
        positions = y_up_to_z_up(positions)
        notes.append("converted Y-up to Z-up: (x, y, z) -> (x, -z, y)")
    rate = file_fps if fps is None else float(fps)
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


__all__ = ["MarkerSet", "UNIT_CHOICES", "finish", "finish_arrays", "frames_from_times", "guess_units", "normalise_units",
           "resample", "segments_from_labels", "y_up_to_z_up"]
