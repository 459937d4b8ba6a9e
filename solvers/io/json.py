"""JSON marker files for pipelines.

Schema (one object; keys not listed are ignored)::

    {
      "facecap_markers": 1,                  # required: schema version, must be 1
      "fps": 60.0,                           # required: frames per second (> 0)
      "units": "mm",                         # optional: "m", "cm", "mm" or "px"
      "up_axis": "Z",                        # optional: "Z" (default) or "Y" (converted to Z-up)
      "frames": [1, 2, 3],                   # optional: strictly increasing frame numbers;
      "first_frame": 1,                      #   otherwise first_frame (default 1), first_frame + 1, ...
      "markers": ["browL", "browR"],         # required: unique names, M of them
      "positions": [                         # required: F frames x M markers x D (2 or 3) numbers;
        [[0.1, 0.2, 0.3], null],             #   null is a gap
        ...
      ],
      "segments": {"posed_happy": [[120, 180]]}   # optional: label -> [[first, last], ...]
    }

:func:`write_json` writes this schema; :func:`read_json` validates every key and names the
first wrong one (``positions[12][3]``) in its error.
"""

import json
import math

import numpy as np

from ..errors import FacecapError, InputFileError
from ..markers import MarkerSet
from .files import write_text_atomic
from .limits import check_input_file
from .timing import check_markerset, finish

SCHEMA_VERSION = 1


#: Integers with more digits than this are read as floats (so beyond 1e308, infinite, and refused
#: where a finite number is needed) instead of raising Python's int-digit-limit ValueError.
MAX_INT_DIGITS = 300


def _parse_int(text):
    return int(text) if len(text) <= MAX_INT_DIGITS else float(text)


def _load(path):
    check_input_file(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            return json.load(fh, parse_int=_parse_int)
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a directory, expected a file") from None
    except UnicodeDecodeError as exc:
        raise InputFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"invalid JSON: {exc.msg} (column {exc.colno})", line=exc.lineno) from None
    except RecursionError:
        raise InputFileError(path, "invalid JSON: nested too deeply") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def read_json(path, *, units=None, fps=None, unit_scale=None, up_axis=None, notes=None):
    """Read a facecap JSON marker file (schema in the module docstring) as a MarkerSet."""
    notes = [] if notes is None else notes
    path = str(path)
    doc = _load(path)
    if not isinstance(doc, dict):
        raise InputFileError(path, f"expected a JSON object, got {type(doc).__name__}")
    if doc.get("facecap_markers") != SCHEMA_VERSION:
        raise InputFileError(path, f"expected schema version {SCHEMA_VERSION}, got {doc.get('facecap_markers')!r}",
                             field="facecap_markers")
    rate = doc.get("fps")
    if not _is_number(rate) or rate <= 0:
        raise InputFileError(path, f"expected a positive number, got {rate!r}", field="fps")
    names = doc.get("markers")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise InputFileError(path, "expected a non-empty list of marker names", field="markers")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputFileError(path, f"duplicate marker names {dup}", field="markers")
    rows = doc.get("positions")
    if not isinstance(rows, list) or not rows:
        raise InputFileError(path, "zero frames: expected a non-empty list of frames", field="positions")
    dim = None
    out = np.full((len(rows), len(names), 3), np.nan)
    for f, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != len(names):
            raise InputFileError(path, f"expected a list of {len(names)} samples", field=f"positions[{f}]")
        for m, sample in enumerate(row):
            if sample is None:
                continue
            if dim is None and isinstance(sample, list) and len(sample) in (2, 3):
                dim = len(sample)
            if not isinstance(sample, list) or len(sample) != dim or not all(_is_number(v) for v in sample):
                raise InputFileError(path, f"expected null or a list of {dim or '2 or 3'} finite numbers",
                                     field=f"positions[{f}][{m}]")
            out[f, m, :dim] = sample
    positions = out[:, :, : (dim or 3)]
    frames = doc.get("frames")
    if frames is None:
        first = doc.get("first_frame", 1)
        if not _is_number(first):
            raise InputFileError(path, f"expected a number, got {first!r}", field="first_frame")
        frames = first + np.arange(len(rows), dtype=np.float64)
    else:
        if not isinstance(frames, list) or len(frames) != len(rows) or not all(_is_number(v) for v in frames):
            raise InputFileError(path, f"expected {len(rows)} numbers, one per frame", field="frames")
        frames = np.asarray(frames, dtype=np.float64)
        if np.any(np.diff(frames) <= 0):
            raise InputFileError(path, "frame numbers must increase strictly", field="frames")
    segments = _segments(path, doc.get("segments", {}))
    file_units = doc.get("units")
    if file_units is not None and not isinstance(file_units, str):
        raise InputFileError(path, f"expected a string, got {file_units!r}", field="units")
    axis = doc.get("up_axis") if up_axis is None else up_axis
    if axis is not None and (not isinstance(axis, str) or axis.upper() not in ("Y", "Z")):
        raise InputFileError(path, f"expected 'Y' or 'Z', got {axis!r}", field="up_axis")
    raw = check_markerset(lambda: MarkerSet(tuple(names), frames, positions, fps=float(rate), units="m",
                                            source=path, segments=segments), path)
    return check_markerset(lambda: finish(raw, units=units, file_units=file_units, unit_scale=unit_scale,
                                          up_axis=axis, fps=fps, notes=notes), path)


def _segments(path, value):
    if not isinstance(value, dict):
        raise InputFileError(path, "expected an object {label: [[first, last], ...]}", field="segments")
    out = {}
    for label, spans in value.items():
        if not isinstance(spans, list):
            raise InputFileError(path, "expected a list of [first, last] pairs", field=f"segments.{label}")
        for span in spans:
            if (not isinstance(span, list) or len(span) != 2 or not all(_is_number(v) for v in span)
                    or span[0] > span[1]):
                raise InputFileError(path, "expected [first, last] with first <= last", field=f"segments.{label}")
            out.setdefault(str(label), []).append((float(span[0]), float(span[1])))
    return out


def write_json(path, markers):
    """Write a MarkerSet in the schema above (gaps as null), atomically."""
    if not isinstance(markers, MarkerSet):
        raise FacecapError("`markers` must be a MarkerSet")
    pos = markers.positions
    rows = [[None if np.isnan(s[0]) else [float(v) for v in s] for s in frame] for frame in pos]
    doc = {
        "facecap_markers": SCHEMA_VERSION,
        "fps": float(markers.fps),
        "units": markers.units,
        "frames": [float(f) if f != int(f) else int(f) for f in markers.frames],
        "markers": list(markers.names),
        "positions": rows,
        "segments": {k: [[a, b] for a, b in v] for k, v in markers.segments.items()},
    }
    write_text_atomic(path, json.dumps(doc, separators=(",", ":")) + "\n")
