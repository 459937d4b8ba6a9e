"""Marker and weight CSV files.

* **Wide** markers: one row per frame, ``frame`` (or ``Frame``, ``time`` / ``timestamp`` in
  seconds, ``time_ms`` in milliseconds) then ``<name>_x, <name>_y[, <name>_z]`` per marker.
  Delimiter ``,`` ``;`` tab or ``|`` is detected from the header; with a non-comma delimiter a
  decimal comma (``0,25``) is detected from the data. Empty, ``NA``, ``NaN``, ``N/A``, ``null``
  cells are gaps. Extra text columns (blenderFace's ``Stimulustype``) become
  ``MarkerSet.segments``: each run of equal non-empty labels is a segment ``(first, last)``.
  Extra numeric columns are ignored (noted).
* **Long** markers: one row per sample, ``frame,marker,x,y[,z]`` (column names ``marker``,
  ``name`` or ``label``; ``time`` instead of ``frame`` allowed), read by
  :func:`facecap.solvers.io.csv_long.read_long_csv`.
* **Weights**: ``frame,<shape>,...`` (:func:`read_weights_csv`; the writers are in
  :mod:`~facecap.solvers.io.csv_write`, the long reader in :mod:`~facecap.solvers.io.csv_long`).

Purely numeric files (numbers and empty cells) are parsed by a vectorised reader (about 0.1 us a
cell); files with anything else (gap words, text columns, quotes, ragged rows) by numpy's text
parser; anything that refuses is re-read cell by cell so that the error names the line and field.
All three give bit-identical arrays. Header lines are read whole, however long.
"""

import collections
import csv
import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FacecapError, InputFileError
from ..markers import MarkerSet
from .csv_vector import SlowPath as _SlowPath
from .csv_vector import vector_numeric as _vector_numeric

# The writers live in csv_write; imported here so `from .csv import write_markers_csv` keeps working.
from .csv_write import AXES, segment_labels, text_of_cell, write_markers_csv, write_weights_csv  # noqa: F401
from .csv_columns import FRAME_HEADERS, TIME_HEADERS, header_cells, header_columns
from .limits import check_input_file
from .timing import check_markerset, finish_arrays, segments_from_labels

GAP_TOKENS = ("", "na", "nan", "n/a", "null", "none", "-nan")
_GAP_SPELLINGS = ("", "NA", "na", "N/A", "n/a", "null", "NULL", "None", "none")  # nan: parsed by numpy
DELIMITERS = (",", ";", "\t", "|")
SNIFF_BYTES = 1 << 16


@dataclass(frozen=True)
class Sniffed:
    """What :func:`sniff` found at the top of a delimited text file."""

    path: Path
    delimiter: str
    decimal: str
    header: tuple
    header_line: int


def _open_text(path):
    check_input_file(path)
    try:
        return open(path, encoding="utf-8-sig", newline="")
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except IsADirectoryError:
        raise InputFileError(path, "is a directory, expected a file") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None


def _decode_error(path, exc):
    return InputFileError(path, f"not a text file ({exc.reason} at byte {exc.start})")


def sniff(path, *, delimiter=None, decimal=None, columns=None):
    """Find the header line, delimiter and decimal separator of a delimited text file.

    The header line is read whole, however long (a 1,000-marker header is ~190 KB); the decimal
    separator is detected from the next 49 lines (their first SNIFF_BYTES characters each).
    ``columns``: the names of a file without a header row (``header_columns``); its first
    non-blank line is then data.
    """
    path = Path(path)
    with _open_text(path) as fh:
        try:
            header_text, header_line, sample = _head_lines(fh)
        except UnicodeDecodeError as exc:
            raise _decode_error(path, exc) from None
    if header_text is None:
        raise InputFileError(path, "empty file; expected a header line", line=1)
    if columns is not None:  # no header row: the first line is data, part of the sample
        sample = [header_text] + sample
    if delimiter is None:
        unquoted = re.sub(r'"(?:[^"]|"")*"', "", header_text)  # a quoted name's commas do not count
        counts = [unquoted.count(d) for d in DELIMITERS]
        delimiter = DELIMITERS[int(np.argmax(counts))] if max(counts) else ","
    elif delimiter not in DELIMITERS:
        raise FacecapError(f"`delimiter` must be one of {DELIMITERS!r}; got {delimiter!r}")
    if decimal is None:
        decimal = "."
        if delimiter != ",":
            cells = [c.strip() for line in sample for c in line.split(delimiter)]
            commas = sum(1 for c in cells if _is_comma_number(c))
            dots = sum(1 for c in cells if "." in c and _is_float(c))
            if commas > dots:
                decimal = ","
    elif decimal not in (".", ","):
        raise FacecapError(f"`decimal` must be '.' or ','; got {decimal!r}")
    if decimal == "," and delimiter == ",":
        raise FacecapError("`decimal` ',' needs a delimiter other than ','")
    if columns is not None:
        first = header_cells(header_text, delimiter)
        header = header_columns(path, columns, len(first))
        return Sniffed(path, delimiter, decimal, header, header_line - 1)
    return Sniffed(path, delimiter, decimal, header_cells(header_text, delimiter), header_line)


def _head_lines(fh):
    """(header text, its 1-based line number, up to 49 following lines); header None when all blank.

    ``fh`` is opened with ``newline=""``, so readline splits at ``\r\n``, ``\r`` and ``\n`` alike.
    """
    number = 0
    for line in iter(fh.readline, ""):
        number += 1
        if "\x00" in line:
            raise InputFileError(fh.name, "not a text file (contains NUL bytes)", line=number)
        if line.strip():
            break
    else:
        return None, number, []
    sample = []
    for _ in range(49):
        more = fh.readline(SNIFF_BYTES)
        if not more:
            break
        if "\x00" in more:
            raise InputFileError(fh.name, "not a text file (contains NUL bytes)", line=number + len(sample) + 1)
        sample.append(more.rstrip("\r\n"))
    return line.rstrip("\r\n"), number, sample


def duplicate_names(names, *, key=None):
    """Sorted names that occur more than once (compared by ``key(name)`` when given); linear time."""
    keys = [key(n) for n in names] if key is not None else list(names)
    counts = collections.Counter(keys)
    return sorted({n for n, k in zip(names, keys) if counts[k] > 1})


def _shorten(names, limit=10):
    """A list of names for a message: the first ``limit`` and how many more."""
    names = list(names)
    return str(names) if len(names) <= limit else f"{names[:limit]} and {len(names) - limit} more"


def _is_float(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def _is_comma_number(text):
    return text.count(",") == 1 and _is_float(text.replace(",", "."))


def data_rows(sn):
    """Yield (line_number, cells) for every non-blank data row, with decoding/CSV errors as InputFileError."""
    fh = _open_text(sn.path)
    with fh:
        reader = csv.reader(fh, delimiter=sn.delimiter)
        try:
            for row in reader:
                if reader.line_num <= sn.header_line:
                    continue
                if any(cell.strip() for cell in row):
                    yield reader.line_num, row
        except UnicodeDecodeError as exc:
            raise _decode_error(sn.path, exc) from None
        except csv.Error as exc:
            raise InputFileError(sn.path, f"malformed CSV ({exc})", line=reader.line_num + 1) from None


def cell_float(text, decimal):
    cell = text.strip()
    if cell.lower() in GAP_TOKENS:
        return np.nan
    if decimal == ",":
        cell = cell.replace(",", ".")
    value = float(cell)  # ValueError handled by the caller
    if not np.isfinite(value) and not np.isnan(value):
        raise ValueError("infinite")
    return value


def _slow_numeric(sn, columns):
    """Cell-by-cell reading of ``columns``: exact errors with line and field. Returns (lines, values)."""
    width = len(sn.header)
    lines, values = [], []
    for line, row in data_rows(sn):
        if len(row) != width:
            raise InputFileError(sn.path, f"{len(row)} fields but the header has {width}", line=line)
        out = []
        for c in columns:
            try:
                out.append(cell_float(row[c], sn.decimal))
            except ValueError:
                raise InputFileError(sn.path, f"expected a number, got {row[c].strip()!r}",
                                     line=line, field=sn.header[c]) from None
        lines.append(line)
        values.append(out)
    return lines, np.array(values, dtype=np.float64).reshape(len(values), len(columns))


CHUNK_CHARS = 1 << 22


def _prepared_chunks(fh, sn):
    """Yield blocks of data lines with every gap spelling replaced by ``nan`` (C-speed str.replace)."""
    d = sn.delimiter
    width = len(sn.header)
    for _ in range(sn.header_line):
        if '"' in fh.readline():
            raise _SlowPath  # the csv module reads a quoted header cell on across lines
    while True:
        lines = fh.readlines(CHUNK_CHARS)
        if not lines:
            return
        lines = [line.rstrip("\r\n") for line in lines]
        lines = [line for line in lines if line.replace(d, "").strip()]  # as _rows: skip rows of blank cells
        if not lines:
            continue
        if any(line.count(d) != width - 1 for line in lines):
            raise _SlowPath
        block = "\n".join(lines)
        if '"' in block:
            raise _SlowPath
        if sn.decimal == ",":
            block = block.replace(",", ".")
        sep = d + "\n" + d
        block = d + block.replace("\n", sep) + d
        for token in _GAP_SPELLINGS:
            bad = d + token + d
            if bad in block:
                good = d + "nan" + d
                block = block.replace(bad, good).replace(bad, good)
        yield block[1:-1].replace(sep, "\n")


def _fast_numeric(sn, columns):
    """numpy's C parser over pre-processed blocks; raises _SlowPath for anything unusual."""
    parts = []
    with _open_text(sn.path) as fh:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                for block in _prepared_chunks(fh, sn):
                    parts.append(np.loadtxt(io.StringIO(block), delimiter=sn.delimiter, usecols=columns,
                                            ndmin=2, dtype=np.float64, comments=None, quotechar=None))
        except (ValueError, UserWarning, UnicodeDecodeError, _SlowPath):
            raise _SlowPath from None
    if not parts:
        raise _SlowPath
    values = np.concatenate(parts) if len(parts) != 1 else parts[0]
    del parts
    if np.isinf(values).any():
        raise _SlowPath
    return values


def read_numeric_columns(sn, columns):
    """(F, len(columns)) float64 of the data rows; gaps NaN; errors name line and field.

    Three readers, each falling back to the next on anything it does not handle: the vectorised
    one (numbers and empty cells only), numpy's text parser, and the cell-by-cell reader whose
    errors name line and field. All three return bit-identical arrays where they succeed.
    """
    columns = list(columns)
    for reader in (_vector_numeric, _fast_numeric):
        try:
            return None, reader(sn, columns)
        except _SlowPath:
            pass
    return _slow_numeric(sn, columns)


def read_text_columns(sn, columns):
    """List (one per column) of per-row stripped strings (``'`` taken off a formula-like text, as written)."""
    out = [[] for _ in columns]
    for _, row in data_rows(sn):
        for j, c in enumerate(columns):
            out[j].append(text_of_cell(row[c].strip()) if c < len(row) else "")
    return out


def time_column(header):
    for i, h in enumerate(header):
        low = h.strip().lower()
        if low in FRAME_HEADERS:
            return i, None
    for i, h in enumerate(header):
        low = h.strip().lower()
        if low in TIME_HEADERS:
            return i, TIME_HEADERS[low]
    return None, None


@dataclass(frozen=True)
class WideLayout:
    key_col: int
    time_scale: float  # None: frame numbers
    names: tuple
    dim: int
    columns: tuple
    extra: tuple


def wide_layout(sn):
    """Column roles of a wide marker CSV; InputFileError for a header that cannot be one."""
    header = list(sn.header)
    path = sn.path
    if header and all(_is_float(h) or h.lower() in GAP_TOKENS for h in header):
        raise InputFileError(path, "no header row: line 1 holds numbers; name the columns in the take config, "
                             "e.g. [source] columns = [\"frame\", \"nose\", \"chin\"] (a marker name stands for its "
                             "x, y, z columns)", line=sn.header_line)
    dup = duplicate_names(header)
    if dup:
        raise InputFileError(path, f"duplicate columns {_shorten(dup)}", line=sn.header_line)
    key_col, time_scale = time_column(header)
    if key_col is None:
        raise InputFileError(path, "no frame column; expected a 'frame' or 'time' column, "
                             f"got {header[0]!r} first", line=sn.header_line)
    axes_by_name, extra = {}, []
    for i, h in enumerate(header):
        if i == key_col:
            continue
        base, sep, axis = h.rpartition("_")
        if sep and base and axis.lower() in AXES and axis.lower() not in axes_by_name.get(base, {}):
            axes_by_name.setdefault(base, {})[axis.lower()] = i
        else:
            extra.append(i)
    if not axes_by_name:
        raise InputFileError(path, "no marker columns; expected '<name>_x', '<name>_y', '<name>_z'",
                             line=sn.header_line)
    dim = max(len(a) for a in axes_by_name.values())
    dim = max(dim, 2)
    for name, axes in axes_by_name.items():
        missing = [a for a in AXES[:dim] if a not in axes]
        extra_axes = [a for a in axes if a not in AXES[:dim]]
        if missing or extra_axes:
            raise InputFileError(path, f"marker '{name}' lacks column(s) {[f'{name}_{a}' for a in missing]}",
                                 line=sn.header_line)
    names = tuple(axes_by_name)
    columns = tuple(axes_by_name[n][a] for n in names for a in AXES[:dim])
    return WideLayout(key_col, time_scale, names, dim, columns, tuple(extra))


def _parse_wide(path, *, delimiter=None, decimal=None, columns=None):
    sn = sniff(path, delimiter=delimiter, decimal=decimal, columns=columns)
    lay = wide_layout(sn)
    lines, values = read_numeric_columns(sn, (lay.key_col,) + lay.columns)
    if values.shape[0] == 0:
        raise InputFileError(sn.path, "no data rows after the header", line=sn.header_line)
    key = values[:, 0]
    bad = np.flatnonzero(~np.isfinite(key))
    field = sn.header[lay.key_col]
    if bad.size or np.any(np.diff(key) <= 0):
        lines = lines or _data_line_numbers(sn)  # the fast path does not keep line numbers
    if bad.size:
        what = "missing frame number" if lay.time_scale is None else "missing timestamp"
        raise InputFileError(sn.path, what, line=lines[bad[0]], field=field)
    order_bad = np.flatnonzero(np.diff(key) <= 0)
    if order_bad.size:
        what = "frame numbers" if lay.time_scale is None else "timestamps"
        raise InputFileError(sn.path, f"{what} must increase from row to row",
                             line=lines[order_bad[0] + 1], field=field)
    positions = values[:, 1:].reshape(len(key), len(lay.names), lay.dim)
    labels, numeric_extra, text_extra = None, [], []
    if lay.extra:
        texts = read_text_columns(sn, lay.extra)
        keep = []
        for c, cells in zip(lay.extra, texts):
            if all(_is_float(v) or v.lower() in GAP_TOKENS for v in cells):
                numeric_extra.append(sn.header[c])
            else:
                text_extra.append(sn.header[c])
                keep.append(cells)
        if len(keep) == 1:
            labels = keep[0]
        elif keep:
            labels = [" | ".join(f"{sn.header[c]}={v}" for c, v in zip(lay.extra, row) if v)
                      for row in zip(*keep)]
    return sn, lay, key, positions, labels, numeric_extra, text_extra


def _data_line_numbers(sn):
    return [line for line, _ in data_rows(sn)]


def read_wide_csv(path, *, units=None, fps=None, unit_scale=None, up_axis=None, delimiter=None,
                  decimal=None, columns=None, notes=None):
    """Read a wide marker CSV (see the module docstring) with units, axis and timing applied.

    Parameters
    ----------
    path : path-like
    units : str or None
        "m", "cm", "mm", "bu" (with ``unit_scale``) or "px"; None guesses from the face size.
    fps : float or None
        Frame rate; with a time column None estimates it from the timestamps, otherwise 60.
    unit_scale : float or None
        Metres per unit for ``units="bu"``.
    up_axis : {"Z", "Y", None}
    delimiter, decimal : str or None
        Override detection.
    columns : list of str or None
        The column names of a file without a header row (see :func:`header_columns`).
    notes : list or None
        Receives a line per thing detected or done.

    Returns
    -------
    MarkerSet
    """
    notes = [] if notes is None else notes
    sn, lay, key, positions, labels, numeric_extra, text_extra = _parse_wide(
        path, delimiter=delimiter, decimal=decimal, columns=columns)
    if columns is not None:
        notes.append(f"no header row: columns from `columns` ({len(sn.header)} columns)")
    if sn.delimiter != "," or sn.decimal != ".":
        notes.append(f"delimiter {sn.delimiter!r}, decimal {sn.decimal!r}")
    if numeric_extra:
        notes.append(f"ignored numeric column(s) {numeric_extra}")
    if text_extra:
        notes.append(f"text column(s) {text_extra} read as segment labels")
    times = None if lay.time_scale is None else key * lay.time_scale
    return check_markerset(lambda: finish_arrays(
        lay.names, key if times is None else np.arange(len(key), dtype=np.float64), positions,
        source=str(sn.path), units=units, unit_scale=unit_scale, up_axis=up_axis, times=times, fps=fps,
        labels=labels, notes=notes), sn.path)


def read_markers_csv(path, *, units="m", fps=60.0):
    """Read a wide marker CSV with a frame column, units and fps as given (the original API).

    Text columns become ``segments`` and, as before, every non-coordinate column is reported
    with a warning. Use :func:`facecap.solvers.io.read_markers` for timestamps, unit
    detection and every other format.

    Returns
    -------
    MarkerSet
    """
    sn, lay, key, positions, labels, numeric_extra, text_extra = _parse_wide(path)
    if lay.time_scale is not None:
        raise InputFileError(sn.path, f"no frame column; expected the first header to be 'frame', "
                             f"got {sn.header[0]!r}", line=sn.header_line)
    if numeric_extra or text_extra:
        warnings.warn(f"{sn.path}: ignored non-coordinate column(s) {numeric_extra + text_extra}"
                      + (f"; {text_extra} kept as segment labels" if text_extra else ""), stacklevel=2)
    segments = segments_from_labels(labels, key) if labels is not None else {}
    return check_markerset(lambda: MarkerSet(lay.names, key, positions, fps=float(fps), units=units,
                                             source=str(sn.path), segments=segments), sn.path)

def read_weights_csv(path):
    """Read ``frame,<shape>,...``. Returns (frames (F,), names tuple, weights (F, K))."""
    sn = sniff(path)
    header = list(sn.header)
    key_col, _ = time_column(header)
    if key_col is None or time_column(header)[1] is not None:
        raise InputFileError(sn.path, f"no frame column; expected the first header to be 'frame', "
                             f"got {header[0]!r}", line=sn.header_line)
    cols = [i for i in range(len(header)) if i != key_col]
    lines, values = read_numeric_columns(sn, [key_col] + cols)
    if values.shape[0] == 0:
        raise InputFileError(sn.path, "no data rows after the header", line=sn.header_line)
    return values[:, 0], tuple(header[i] for i in cols), values[:, 1:]


__all__ = ["cell_float", "data_rows", "duplicate_names", "read_markers_csv", "read_weights_csv", "read_wide_csv",
           "sniff", "time_column", "write_markers_csv", "write_weights_csv"]
