"""One entry point for every capture file: ``read_markers(path)`` and ``read_weights(path)``.

Formats (detected from the extension, then from the content):

==============  =================  ==========================================================
format          extensions         notes
==============  =================  ==========================================================
``c3d``         .c3d               POINT:LABELS/UNITS/RATE, first frame, residual < 0 = gap
``trc``         .trc               OpenSim / Motion Analysis; units and rate from the header
``csv``         .csv .txt .tsv     wide ``frame,<m>_x,<m>_y,<m>_z``; text columns -> segments
``csv-long``    .csv .txt .tsv     ``frame,marker,x,y,z`` (detected from the header)
``json``        .json              schema in :mod:`facecap.solvers.io.json`
==============  =================  ==========================================================

Common options: ``units`` ("m", "cm", "mm", "bu" with ``unit_scale``, "px"; None = from the file
or guessed), ``fps`` (None = from the file), ``unit_scale`` (metres per unit), ``up_axis``
("Z" or "Y"). CSV readers also take ``delimiter`` and ``decimal``.

Readers describe what they found or decided in notes: lines starting ``warning:`` (the data were
changed or are suspect: repeated labels renamed, a truncated file) are also raised as warnings by
:func:`read_markers`; ``hint:`` lines suggest a setting (``up_axis``). :func:`capture_kind` tells
a solved-weights CSV (:func:`read_weights`) from a marker file. See docs/capture-data.md.
"""

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FacecapError, InputFileError
from ..markers import UNIT_SCALE, MarkerSet
from .c3d import read_c3d
from .c3d_write import write_c3d
from .csv import read_wide_csv, sniff, time_column
from .csv_long import is_long_header, read_long_csv
from .csv_write import write_markers_csv
from .json import read_json, write_json
from .limits import check_input_file
from .timing import FPS_ASSUMED, UNITS_GUESSED
from .trc import read_trc, write_trc
from .weights import WeightTrack, read_weights

FORMATS = ("c3d", "trc", "csv", "csv-long", "json")
EXTENSIONS = {".c3d": "c3d", ".trc": "trc", ".json": "json", ".csv": "csv", ".txt": "csv", ".tsv": "csv"}
_OPTIONS = {
    "c3d": ("units", "fps", "unit_scale", "up_axis"),
    "trc": ("units", "fps", "unit_scale", "up_axis"),
    "json": ("units", "fps", "unit_scale", "up_axis"),
    "csv": ("units", "fps", "unit_scale", "up_axis", "delimiter", "decimal", "columns"),
    "csv-long": ("units", "fps", "unit_scale", "up_axis", "delimiter", "decimal"),
}
#: Notes that mean the data were changed or are suspect, not just described: also raised as warnings.
_CHANGED = ("resampled", "warning:")


@dataclass(frozen=True, eq=False)
class ImportResult:
    """A MarkerSet and what the reader found or did (``notes``), and the detected ``format``.

    ``decided`` says where the units and the frame rate came from: ``{"units": "given" | "file" |
    "guessed" | "2D (pixels)", "fps": "given" | "file" | "timestamps" | "assumed"}``.
    """

    markers: MarkerSet
    format: str
    notes: tuple = field(default_factory=tuple)
    decided: dict = field(default_factory=dict)


def detect_format(path):
    """Format name of ``path`` (see FORMATS), from its extension and, for text, its header."""
    path = Path(path)
    check_input_file(path)
    fmt = EXTENSIONS.get(path.suffix.lower())
    if fmt is None:
        try:
            with open(path, "rb") as fh:
                head = fh.read(512)
        except FileNotFoundError:
            raise InputFileError(path, "file not found") from None
        except OSError as exc:
            raise InputFileError(path, f"cannot read: {exc.strerror}") from None
        if len(head) >= 2 and head[1] == 0x50 and head[0] >= 2:
            return "c3d"
        if head.startswith(b"PathFileType"):
            return "trc"
        if head.lstrip().startswith(b"{"):
            return "json"
        fmt = "csv"
    if fmt == "csv" and is_long_header(sniff(path).header):
        return "csv-long"
    return fmt


def import_markers(path, *, format=None, units=None, fps=None, **options):
    """Read any supported marker file; returns an ImportResult (markers, format, notes).

    Parameters
    ----------
    path : path-like
    format : str or None
        One of FORMATS; None detects it.
    units, fps : see the module docstring.
    **options
        ``unit_scale``, ``up_axis`` and, for CSV, ``delimiter`` and ``decimal``.
    """
    check_input_file(path)
    fmt = detect_format(path) if format is None else format
    if fmt not in FORMATS:
        raise FacecapError(f"`format` must be one of {', '.join(FORMATS)}; got {format!r}")
    unknown = sorted(set(options) - set(_OPTIONS[fmt]))
    if unknown:
        raise FacecapError(f"option(s) {unknown} do not apply to {fmt} files; "
                           f"allowed: {', '.join(_OPTIONS[fmt])}")
    notes = []
    reader = {"c3d": read_c3d, "trc": read_trc, "json": read_json, "csv": read_wide_csv,
              "csv-long": read_long_csv}[fmt]
    markers = reader(path, units=units, fps=fps, notes=notes, **options)
    check_magnitude(path, markers)
    return ImportResult(markers=markers, format=fmt, notes=tuple(notes), decided=_decided(notes, units, fps))


#: Largest coordinate a take may hold: 10 km (3D, in metres) or 10 million pixels (2D). Beyond it the
#: file is damaged (a C3D's data block shifted) or its units are wrong, and the fits would overflow.
MAX_COORDINATE_M = 1e4
MAX_COORDINATE_PX = 1e7


def check_magnitude(path, markers):
    """InputFileError naming the file when a coordinate lies beyond ``MAX_COORDINATE_M`` / ``_PX``."""
    pos = markers.positions
    if pos.size == 0:
        return
    with np.errstate(invalid="ignore"):
        largest = float(np.nanmax(np.abs(pos))) if np.isfinite(pos).any() else 0.0
    scale = UNIT_SCALE.get(markers.units)
    limit = MAX_COORDINATE_PX if markers.dim == 2 or scale is None else MAX_COORDINATE_M / scale
    if largest > limit:
        unit = markers.units or "units"
        raise InputFileError(path, f"coordinates reach {largest:.3g} {unit}, beyond the {limit:.3g} {unit} any capture "
                                   "holds: a damaged file, or the wrong units")


def _decided(notes, units, fps):
    """Where units and frame rate came from, from what was given and the readers' notes."""
    def said(text):
        return any(n.startswith(text) for n in notes)

    unit_from = ("given" if units is not None else "guessed" if said(UNITS_GUESSED)
                 else "2D (pixels)" if said("2D data: units taken as pixels") else "file")
    fps_from = ("given" if fps is not None else "assumed" if said(FPS_ASSUMED)
                else "timestamps" if any("timestamps" in n for n in notes) else "file")
    return {"units": unit_from, "fps": fps_from}


def capture_kind(path):
    """"weights" for a solved-weights CSV (Live Link Face, MediaPipe, ``frame,<shape>,...``),
    otherwise "markers" (including files that cannot be read: the marker readers say why)."""
    if detect_format(path) != "csv":
        return "markers"
    try:
        header = [h.lower() for h in sniff(path).header]
    except FacecapError:
        return "markers"
    if {"timecode", "blendshapecount", "_neutral"} & set(header):
        return "weights"
    key, _ = time_column(header)
    coords = [h for h in header if h.rpartition("_")[2] in ("x", "y", "z") and h.rpartition("_")[0]]
    return "weights" if key is not None and len(header) > 1 and not coords else "markers"


def read_markers(path, *, units=None, fps=None, **options):
    """Read any supported marker file as a MarkerSet (see :func:`import_markers`).

    Notes saying the data were changed (variable-rate resampling) are raised as warnings.
    """
    result = import_markers(path, units=units, fps=fps, **options)
    for note in result.notes:
        if any(word in note for word in _CHANGED):
            warnings.warn(f"{path}: {note}", stacklevel=2)
    return result.markers


def write_markers(path, markers):
    """Write ``markers`` in the format of ``path``'s extension (.csv, .c3d, .trc, .json)."""
    fmt = EXTENSIONS.get(Path(path).suffix.lower())
    writers = {"csv": write_markers_csv, "c3d": write_c3d, "trc": write_trc, "json": write_json}
    if fmt not in writers:
        raise FacecapError(f"{path}: cannot write this extension; use .csv, .c3d, .trc or .json")
    writers[fmt](path, markers)


__all__ = ["EXTENSIONS", "FORMATS", "ImportResult", "WeightTrack", "capture_kind", "detect_format", "import_markers",
           "read_markers", "read_weights", "write_markers"]
