"""Long marker CSV files: one row per sample, ``frame,marker,x,y[,z]`` (see :func:`read_long_csv`)."""

import numpy as np

from ..errors import InputFileError
from ..markers import MarkerSet
from .csv import AXES, cell_float, data_rows, duplicate_names, sniff, time_column
from .timing import check_markerset, finish

LONG_MARKER_HEADERS = ("marker", "name", "label", "marker_name")


def is_long_header(header):
    low = [h.strip().lower() for h in header]
    return any(h in LONG_MARKER_HEADERS for h in low) and "x" in low and "y" in low


def read_long_csv(path, *, units=None, fps=None, unit_scale=None, up_axis=None, delimiter=None,
                  decimal=None, notes=None):
    """Read a long marker CSV: one row per sample, ``frame,marker,x,y[,z]``.

    Columns are found by name (any order): ``frame`` (or a time column as for the wide
    format), ``marker`` / ``name`` / ``label``, ``x``, ``y`` and optionally ``z``. Markers keep
    the order of first appearance; a (frame, marker) pair missing from the file is a gap, and
    one that appears twice is an error. Options as for :func:`read_wide_csv`.
    """
    notes = [] if notes is None else notes
    sn = sniff(path, delimiter=delimiter, decimal=decimal)
    low = [h.lower() for h in sn.header]
    dup = duplicate_names(sn.header, key=str.lower)
    if dup:
        raise InputFileError(sn.path, f"duplicate columns {dup}", line=sn.header_line)
    key_col, time_scale = time_column(sn.header)
    name_col = next((i for i, h in enumerate(low) if h in LONG_MARKER_HEADERS), None)
    if key_col is None or name_col is None or "x" not in low or "y" not in low:
        raise InputFileError(sn.path, "expected columns frame (or time), marker, x, y[, z]",
                             line=sn.header_line)
    axis_cols = [low.index(a) for a in AXES if a in low]
    dim = len(axis_cols)
    width = len(sn.header)
    keys, names, coords = [], [], []
    lines = []
    for line, row in data_rows(sn):
        if len(row) != width:
            raise InputFileError(sn.path, f"{len(row)} fields but the header has {width}", line=line)
        name = row[name_col].strip()
        if not name:
            raise InputFileError(sn.path, "empty marker name", line=line, field=sn.header[name_col])
        vals = []
        for c in [key_col] + axis_cols:
            try:
                vals.append(cell_float(row[c], sn.decimal))
            except ValueError:
                raise InputFileError(sn.path, f"expected a number, got {row[c].strip()!r}",
                                     line=line, field=sn.header[c]) from None
        if np.isnan(vals[0]):
            raise InputFileError(sn.path, "missing frame number", line=line, field=sn.header[key_col])
        keys.append(vals[0])
        names.append(name)
        coords.append(vals[1:])
        lines.append(line)
    if not keys:
        raise InputFileError(sn.path, "no data rows after the header", line=sn.header_line)
    order = list(dict.fromkeys(names))
    keys = np.asarray(keys)
    uniq, frame_idx = np.unique(keys, return_inverse=True)
    lookup = {n: i for i, n in enumerate(order)}
    marker_idx = np.array([lookup[n] for n in names])
    flat = frame_idx * len(order) + marker_idx
    seen, first = np.unique(flat, return_index=True)
    if seen.size != flat.size:
        dup_rows = np.setdiff1d(np.arange(flat.size), first)
        r = int(dup_rows[0])
        raise InputFileError(sn.path, f"marker {names[r]!r} appears twice at {sn.header[key_col]} {keys[r]:g}",
                             line=lines[r])
    positions = np.full((uniq.size, len(order), dim), np.nan)
    positions[frame_idx, marker_idx] = np.asarray(coords)
    times = None if time_scale is None else uniq * time_scale
    raw = check_markerset(lambda: MarkerSet(tuple(order), uniq if times is None else np.arange(uniq.size),
                                            positions, fps=60.0 if fps is None else fps, units="m",
                                            source=str(sn.path)), sn.path)
    return check_markerset(lambda: finish(raw, units=units, unit_scale=unit_scale, up_axis=up_axis,
                                          times=times, fps=fps, notes=notes, file_fps=None), sn.path)


__all__ = ["LONG_MARKER_HEADERS", "is_long_header", "read_long_csv"]
