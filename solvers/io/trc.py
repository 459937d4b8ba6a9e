"""TRC marker files (Motion Analysis / OpenSim): tab-separated text with a 5-line header.

::

    PathFileType  4  (X/Y/Z)  take.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    60  60  100  3  mm  60  1  100
    Frame#  Time  M1        M2        M3
                  X1 Y1 Z1  X2 Y2 Z2  X3 Y3 Z3
    1  0.000  ...

Empty cells (and ``NaN``) are gaps; a row may stop early when its last markers are missing.
"""

import numpy as np

from ..errors import FacecapError, InputFileError
from ..markers import MarkerSet
from .csv import GAP_TOKENS
from .files import atomic_path
from .timing import UNIT_ALIASES, check_markerset, finish


def _cells(line):
    line = line.rstrip("\r\n")
    return line.split("\t") if "\t" in line else line.split()


def _read_lines(path):
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a directory, expected a file") from None
    except UnicodeDecodeError as exc:
        raise InputFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None
    if "\x00" in text:
        raise InputFileError(path, "not a text file (contains NUL bytes)")
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _number(path, text, line, field):
    cell = text.strip()
    if cell.lower() in GAP_TOKENS:
        return np.nan
    try:
        value = float(cell)
    except ValueError:
        raise InputFileError(path, f"expected a number, got {cell!r}", line=line, field=field) from None
    if np.isinf(value):
        raise InputFileError(path, "expected a finite number", line=line, field=field)
    return value


def read_trc(path, *, units=None, fps=None, unit_scale=None, up_axis=None, notes=None):
    """Read a TRC file as a MarkerSet (units and rate from its header unless given).

    Options as for :func:`facecap.solvers.io.timing.finish`.
    """
    notes = [] if notes is None else notes
    path = str(path)
    lines = _read_lines(path)
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputFileError(path, "not a TRC file; expected 'PathFileType' on line 1", line=1)
    keys = [k.strip() for k in _cells(lines[1])]
    values = [v.strip() for v in _cells(lines[2])]
    meta = dict(zip(keys, values))
    rate = meta.get("DataRate") or meta.get("CameraRate")
    try:
        rate = float(rate) if rate is not None else None
    except ValueError:
        raise InputFileError(path, f"expected a number, got {rate!r}", line=3, field="DataRate") from None
    if rate is not None and (not np.isfinite(rate) or rate <= 0):
        raise InputFileError(path, f"frame rate must be positive; got {rate}", line=3, field="DataRate")
    names_row = _cells(lines[3])
    if len(names_row) < 3 or names_row[0].strip().lower() not in ("frame#", "frame"):
        raise InputFileError(path, "expected 'Frame#', 'Time' and marker names", line=4)
    names = [n.strip() for n in names_row[2:] if n.strip()]
    if not names:
        raise InputFileError(path, "no marker names", line=4)
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputFileError(path, f"duplicate marker names {dup}", line=4)
    declared = meta.get("NumMarkers")
    if declared is not None and declared.strip().isdigit() and int(declared) != len(names):
        raise InputFileError(path, f"NumMarkers says {declared} but line 4 names {len(names)} markers",
                             line=3, field="NumMarkers")
    width = 2 + 3 * len(names)
    frames, rows, line_numbers = [], [], []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        cells = _cells(line)
        if len(cells) > width:
            extra = cells[width:]
            if any(c.strip() for c in extra):
                raise InputFileError(path, f"{len(cells)} fields but {len(names)} markers need {width}", line=number)
            cells = cells[:width]
        if len(cells) < 2:
            raise InputFileError(path, "expected frame number and time", line=number)
        frame = _number(path, cells[0], number, "Frame#")
        if np.isnan(frame):
            raise InputFileError(path, "missing frame number", line=number, field="Frame#")
        row = [_number(path, c, number, names[(j) // 3] + "XYZ"[j % 3]) for j, c in enumerate(cells[2:])]
        row += [np.nan] * (width - 2 - len(row))
        frames.append(frame)
        rows.append(row)
        line_numbers.append(number)
    if not rows:
        raise InputFileError(path, "zero frames: no data rows after the header", line=5)
    frames = np.asarray(frames)
    bad = np.flatnonzero(np.diff(frames) <= 0)
    if bad.size:
        raise InputFileError(path, "frame numbers must increase from row to row",
                             line=line_numbers[bad[0] + 1], field="Frame#")
    declared_frames = meta.get("NumFrames", "").strip()
    if declared_frames.isdigit() and int(declared_frames) != len(rows):
        notes.append(f"NumFrames says {declared_frames}, the file holds {len(rows)} rows")
    positions = np.asarray(rows, dtype=np.float64).reshape(len(rows), len(names), 3)
    file_units = UNIT_ALIASES.get(meta.get("Units", "").strip().lower())
    if meta.get("Units") and file_units is None:
        notes.append(f"Units {meta.get('Units')!r} not understood")
    raw = check_markerset(lambda: MarkerSet(tuple(names), frames, positions,
                                            fps=(rate or 60.0) if fps is None else fps, units="m", source=path), path)
    return check_markerset(lambda: finish(raw, units=units, file_units=file_units, unit_scale=unit_scale,
                                          up_axis=up_axis, fps=fps, notes=notes), path)


def write_trc(path, markers):
    """Write a 3D MarkerSet as a TRC file (gaps as empty cells), atomically."""
    if markers.dim != 3:
        raise FacecapError(f"{path}: TRC holds 3D points; got {markers.dim}D markers")
    if any(("\t" in n or " " in n or not n) for n in markers.names):
        raise FacecapError(f"{path}: TRC marker names cannot contain tabs or spaces")
    units = markers.units if markers.units in ("m", "cm", "mm") else "m"
    f, m = markers.n_frames, markers.n_markers
    first = markers.frames[0]
    head = [
        f"PathFileType\t4\t(X/Y/Z)\t{getattr(path, 'name', str(path))}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{markers.fps:g}\t{markers.fps:g}\t{f}\t{m}\t{units}\t{markers.fps:g}\t{first:g}\t{f}",
        "Frame#\tTime\t" + "\t\t\t".join(markers.names) + "\t\t",
        "\t\t" + "\t".join(f"{a}{i + 1}" for i in range(m) for a in "XYZ"),
        "",
    ]
    flat = markers.positions.reshape(f, -1)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write("\n".join(head) + "\n")
        for frame, row in zip(markers.frames, flat):
            cells = ["" if np.isnan(v) else f"{v:.9g}" for v in row]
            fh.write(f"{frame:g}\t{(frame - first) / markers.fps:.9g}\t" + "\t".join(cells) + "\n")
