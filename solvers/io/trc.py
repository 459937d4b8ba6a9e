"""TRC marker files (Motion Analysis / OpenSim): tab-separated text with a 5-line header.

::

    PathFileType  4  (X/Y/Z)  take.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    60  60  100  3  mm  60  1  100
    Frame#  Time  M1        M2        M3
                  X1 Y1 Z1  X2 Y2 Z2  X3 Y3 Z3
    1  0.000  ...

Empty cells (and ``NaN``) are gaps; a row may stop early when its last markers are missing. A sample
written as exactly ``0, 0, 0`` is a gap too: OpenSim and Motion Analysis write missing markers so (no
real marker sits exactly at the origin of the capture volume). Comma-separated TRC files (pyomeca)
are read as well.
"""

import numpy as np

from ..errors import FacecapError, InputFileError
from .csv import GAP_TOKENS
from .files import atomic_path
from .limits import check_input_file
from .timing import UNIT_ALIASES, check_markerset, finish_arrays, unique_names


def _cells(line):
    line = line.rstrip("\r\n")
    return line.split("\t") if "\t" in line else line.split()


def _read_lines(path):
    check_input_file(path)
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

    Header values may be separated by several tabs (OpenSim). Data columns beyond the named
    markers (unlabelled trajectories) are read as markers ``unnamed_<n>`` (n: the column's marker
    number), with a warning note. Options as for :func:`facecap.solvers.io.timing.finish`.
    """
    notes = [] if notes is None else notes
    path = str(path)
    lines = _read_lines(path)
    if not any(line.strip() for line in lines):
        raise InputFileError(path, "empty file; expected a TRC header ('PathFileType' on line 1)", line=1)
    if not lines[0].startswith("PathFileType"):
        raise InputFileError(path, "not a TRC file; expected 'PathFileType' on line 1", line=1)
    if len(lines) < 5 or not lines[3].strip():
        held = sum(1 for line in lines[:4] if line.strip())
        raise InputFileError(path, f"truncated TRC header: {held} of 5 header lines", line=held + 1)
    if "\t" not in lines[0] and "," in lines[0]:  # comma-separated (pyomeca): no cell can hold a comma then
        lines = [line.replace(",", "\t") for line in lines]
        notes.append("comma-separated TRC")
    meta = _header_values(lines[1], lines[2])
    rate = _header_rate(path, meta)
    names_row = _cells(lines[3])
    if len(names_row) < 2 or names_row[0].strip().lower() not in ("frame#", "frame"):
        raise InputFileError(path, "expected 'Frame#', 'Time' and marker names", line=4)
    names = [n.strip() for n in names_row[2:] if n.strip()]
    frames, rows, line_numbers = _data_rows(path, lines, names)
    width = max(len(names), max((len(r) + 2) // 3 for r in rows))
    if width == 0:
        raise InputFileError(path, "no markers: line 4 names none and the rows hold no coordinates", line=4)
    names = _all_names(names, width, meta, notes)
    bad = np.flatnonzero(np.diff(frames) <= 0)
    if bad.size:
        raise InputFileError(path, "frame numbers must increase from row to row",
                             line=line_numbers[bad[0] + 1], field="Frame#")
    declared_frames = meta.get("NumFrames", "").strip()
    if declared_frames.isdigit() and int(declared_frames) != len(rows):
        notes.append(f"NumFrames says {declared_frames}, the file holds {len(rows)} rows")
    positions = np.full((len(rows), 3 * width), np.nan)
    for i, row in enumerate(rows):
        positions[i, :len(row)] = row
    positions = positions.reshape(len(rows), width, 3)
    zero = (positions == 0.0).all(axis=2)
    if zero.any():  # OpenSim and Motion Analysis write a missing marker as 0, 0, 0
        positions[zero] = np.nan
        notes.append(f"{int(zero.sum())} sample(s) written as 0, 0, 0 read as gaps (how OpenSim and Motion "
                     "Analysis write a missing marker)")
    file_units = UNIT_ALIASES.get(meta.get("Units", "").strip().lower())
    if meta.get("Units") and file_units is None:
        notes.append(f"Units {meta.get('Units')!r} not understood")
    return check_markerset(lambda: finish_arrays(
        names, np.asarray(frames), positions, source=path, file_fps=rate, units=units,
        file_units=file_units, unit_scale=unit_scale, up_axis=up_axis, fps=fps, notes=notes), path)


def _header_values(keys_line, values_line):
    """{key: value} of header lines 2-3; values separated by several tabs (OpenSim) are realigned."""
    keys = [k.strip() for k in _cells(keys_line) if k.strip()]
    values = [v.strip() for v in _cells(values_line)]
    if len(values) != len(keys):
        values = [v for v in values if v]
    return dict(zip(keys, values))


def _header_rate(path, meta):
    rate = meta.get("DataRate") or meta.get("CameraRate")
    try:
        rate = float(rate) if rate else None
    except ValueError:
        raise InputFileError(path, f"expected a number, got {rate!r}", line=3, field="DataRate") from None
    if rate is not None and (not np.isfinite(rate) or rate <= 0):
        raise InputFileError(path, f"frame rate must be positive; got {rate}", line=3, field="DataRate")
    return rate


def _data_rows(path, lines, names):
    """(frame numbers, coordinate rows without trailing empty cells, line numbers) of the data lines."""
    frames, rows, line_numbers = [], [], []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        cells = _cells(line)
        if len(cells) < 2:
            raise InputFileError(path, "expected frame number and time", line=number)
        frame = _number(path, cells[0], number, "Frame#")
        if np.isnan(frame):
            raise InputFileError(path, "missing frame number", line=number, field="Frame#")
        coords = cells[2:]
        while coords and not coords[-1].strip():
            coords.pop()
        rows.append([_number(path, c, number, _field(names, j)) for j, c in enumerate(coords)])
        frames.append(frame)
        line_numbers.append(number)
    if not rows:
        raise InputFileError(path, "zero frames: no data rows after the header", line=5)
    return frames, rows, line_numbers


def _field(names, j):
    """Error field of coordinate ``j`` of a row: ``<marker>X`` or, beyond the named markers, its column."""
    return names[j // 3] + "XYZ"[j % 3] if j // 3 < len(names) else f"column {j + 3}"


def _all_names(names, width, meta, notes):
    """``width`` unique names: line 4's, then ``unnamed_<n>`` for data columns beyond them."""
    declared = meta.get("NumMarkers", "").strip()
    if len(names) < width:
        extra = width - len(names)
        notes.append(f"warning: the rows hold {width} markers, line 4 names {len(names)}"
                     + (f" (NumMarkers {declared})" if declared else "")
                     + f": the other {extra} are read as unnamed_{len(names) + 1}..unnamed_{width}")
        taken = set(names)
        names = names + [_free(f"unnamed_{k + 1}", taken) for k in range(len(names), width)]
    elif declared.isdigit() and int(declared) != len(names):
        notes.append(f"NumMarkers says {declared}, line 4 names {len(names)} markers")
    return unique_names(names, notes, where="line 4")


def _free(name, taken):
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def write_trc(path, markers):
    """Write a 3D MarkerSet as a TRC file (gaps as empty cells), atomically."""
    if markers.dim != 3:
        raise FacecapError(f"{path}: TRC holds 3D points; got {markers.dim}D markers")
    bad = [n for n in markers.names if "\t" in n or "\n" in n or "\r" in n or n != n.strip() or not n]
    if bad:
        raise FacecapError(f"{path}: TRC marker names cannot be empty, contain tabs or line breaks, or begin or end "
                           f"with a space: {bad[:5]}; rename them, or write .csv or .json")
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
