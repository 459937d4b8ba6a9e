"""Header rows of CSV files: the cells of one (``header_cells``, RFC 4180 quoting), and the header of a marker
CSV that has none, from the column names a take config gives (``[source] columns``)."""

from ..errors import FacecapError, InputFileError
from .csv_write import AXES, text_of_cell

#: Column names of the frame number, and of the time with their unit in seconds (the wide reader's too).
FRAME_HEADERS = ("frame", "frames", "frame_number", "frame#", "frame_no", "frameno")
TIME_HEADERS = {
    "time": 1.0, "times": 1.0, "t": 1.0, "time_s": 1.0, "time (s)": 1.0, "time[s]": 1.0, "seconds": 1.0,
    "timestamp": 1.0, "timestamps": 1.0, "time_sec": 1.0,
    "time_ms": 1e-3, "time (ms)": 1e-3, "timestamp_ms": 1e-3, "ms": 1e-3,
    "time_us": 1e-6, "timestamp_us": 1e-6,
}


def header_columns(path, columns, width):
    """The header of a CSV without one, from ``columns`` (``[source] columns``): ``frame`` or ``time`` (or
    another time header), then marker names; a plain marker name stands for its ``_x``, ``_y``, ``_z``
    columns, ``name_x``-style names for one column each (2D tracks: ``name_x``, ``name_y``). ``width``:
    the fields of the first data row, which the columns must match."""
    if isinstance(columns, str) or not all(isinstance(c, str) and c.strip() for c in columns):
        raise FacecapError(f"{path}: `columns` must be a list of column names; got {columns!r}")
    header = []
    for c in (c.strip() for c in columns):
        low = c.lower()
        if low in FRAME_HEADERS or low in TIME_HEADERS or c.rpartition("_")[2].lower() in AXES:
            header.append(c)
        else:
            header += [f"{c}_{a}" for a in "xyz"]
    if len(header) != width:
        raise InputFileError(path, f"`columns` describe {len(header)} columns ({', '.join(header[:6])}"
                             f"{', ...' if len(header) > 6 else ''}); the first row has {width} fields "
                             "(a plain marker name stands for 3 columns, x y z)", line=1)
    return tuple(header)


def header_cells(line, delimiter):
    """The cells of a header line (RFC 4180 quoting): unquoted cells stripped of spaces, quoted ones kept
    exactly as written (a name may begin or end with a space); a name facecap wrote with a ``'`` before its
    formula-like first character (``csv_write.formula_safe``) without it."""
    cells, cell, quoted, inside, i = [], [], False, False, 0
    while i < len(line):
        c = line[i]
        if inside:
            if c == '"' and line[i + 1:i + 2] == '"':
                cell.append('"')
                i += 1
            elif c == '"':
                inside = False
            else:
                cell.append(c)
        elif c == '"' and not "".join(cell).strip():
            cell, quoted, inside = [], True, True
        elif c == delimiter:
            cells.append("".join(cell) if quoted else "".join(cell).strip())
            cell, quoted = [], False
        else:
            cell.append(c)
        i += 1
    cells.append("".join(cell) if quoted else "".join(cell).strip())
    return tuple(text_of_cell(c) for c in cells)
