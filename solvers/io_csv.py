"""Wide CSV files: markers (``frame,<name>_x,<name>_y[,<name>_z],...``) and weights (``frame,<shape>,...``)."""

import csv
import io
import warnings
from pathlib import Path

import numpy as np

from .errors import FacecapError, InputFileError
from .fileio import atomic_path
from .markers import MarkerSet

GAP_TOKENS = ("", "na", "nan", "n/a", "null", "none")
FRAME_HEADERS = ("frame", "frames", "frame_number", "frame#")
AXES = ("x", "y", "z")


def _read_rows(path):
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except UnicodeDecodeError as exc:
        raise InputFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot read: {exc.strerror}") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputFileError(path, "empty file; expected a header line", line=1)
    header = lines[0]
    delimiter = ";" if header.count(";") > header.count(",") else ","
    rows = list(csv.reader(io.StringIO(text), delimiter=delimiter))
    # Drop fully blank lines (a trailing newline, spacing) but keep line numbers for messages.
    numbered = [(i + 1, row) for i, row in enumerate(rows) if any(cell.strip() for cell in row)]
    return path, delimiter, numbered


def _numeric_block(path, numbered, columns, header):
    """Convert the cells of ``columns`` to float64 (gaps -> NaN), naming the first bad cell."""
    cells = np.array([[row[c].strip() for c in columns] for _, row in numbered[1:]], dtype=str)
    if cells.size == 0:
        return np.zeros((0, len(columns)))
    lowered = np.char.lower(cells)
    cells = np.where(np.isin(lowered, GAP_TOKENS), "nan", cells)
    try:
        return cells.astype(np.float64)
    except ValueError:
        for r in range(cells.shape[0]):
            for j, c in enumerate(columns):
                try:
                    float(cells[r, j])
                except ValueError:
                    line = numbered[r + 1][0]
                    raise InputFileError(
                        path, f"expected a number, got {cells[r, j]!r}", line=line, field=header[c]
                    ) from None
        raise


def _check_row_lengths(path, numbered, width):
    for line, row in numbered[1:]:
        if len(row) != width:
            raise InputFileError(
                path, f"{len(row)} fields but the header has {width}", line=line
            )


def _frame_column(path, header):
    lowered = [h.strip().lower() for h in header]
    for i, h in enumerate(lowered):
        if h in FRAME_HEADERS:
            return i
    raise InputFileError(path, f"no frame column; expected the first header to be 'frame', got {header[0]!r}", line=1)


def read_markers_csv(path, *, units="m", fps=60.0):
    """Read a wide marker CSV.

    Columns ``<name>_x, <name>_y`` and optionally ``<name>_z`` per marker (3D needs all
    three); ``,`` or ``;`` delimited; empty, ``NA`` or ``NaN`` cells are gaps. Columns that
    are not marker coordinates are ignored with a warning.

    Parameters
    ----------
    path : path-like
    units : str
        Unit of the numbers in the file ("m", "cm" or "mm"); kept on the MarkerSet.
    fps : float
        Frame rate of the take.

    Returns
    -------
    MarkerSet
    """
    path, _, numbered = _read_rows(path)
    header = [h.strip() for h in numbered[0][1]]
    width = len(header)
    if len(set(header)) != width:
        dup = sorted({h for h in header if header.count(h) > 1})
        raise InputFileError(path, f"duplicate columns {dup}", line=1)
    if len(numbered) < 2:
        raise InputFileError(path, "no data rows after the header", line=1)
    _check_row_lengths(path, numbered, width)
    frame_col = _frame_column(path, header)

    axes_by_name = {}
    ignored = []
    for i, h in enumerate(header):
        if i == frame_col:
            continue
        base, sep, axis = h.rpartition("_")
        if sep and base and axis.lower() in AXES:
            axes_by_name.setdefault(base, {})[axis.lower()] = i
        else:
            ignored.append(h)
    if not axes_by_name:
        raise InputFileError(path, "no marker columns; expected '<name>_x', '<name>_y', '<name>_z'", line=1)
    dims = {len(a) for a in axes_by_name.values()}
    dim = max(dims)
    for name, axes in axes_by_name.items():
        wanted = AXES[:dim]
        missing = [a for a in wanted if a not in axes]
        if missing:
            raise InputFileError(
                path, f"marker '{name}' lacks column(s) {[f'{name}_{a}' for a in missing]}", line=1
            )
    if ignored:
        warnings.warn(f"{path}: ignored non-coordinate column(s) {ignored}", stacklevel=2)

    names = list(axes_by_name)
    columns = [axes_by_name[n][a] for n in names for a in AXES[:dim]]
    values = _numeric_block(path, numbered, columns, header)
    frames = _numeric_block(path, numbered, [frame_col], header)[:, 0]
    bad = np.flatnonzero(~np.isfinite(frames))
    if bad.size:
        raise InputFileError(path, "missing frame number", line=numbered[bad[0] + 1][0], field=header[frame_col])
    order_bad = np.flatnonzero(np.diff(frames) <= 0)
    if order_bad.size:
        line = numbered[order_bad[0] + 2][0]
        raise InputFileError(path, "frame numbers must increase from row to row", line=line, field=header[frame_col])
    positions = values.reshape(len(frames), len(names), dim)
    return MarkerSet(names=tuple(names), frames=frames, positions=positions, fps=float(fps), units=units, source=str(path))


def write_markers_csv(path, markers, *, delimiter=","):
    """Write a MarkerSet as a wide CSV (gaps as empty cells), atomically."""
    axes = AXES[: markers.dim]
    header = ["frame"] + [f"{n}_{a}" for n in markers.names for a in axes]
    flat = markers.positions.reshape(markers.n_frames, -1)
    _write_table(path, header, markers.frames, flat, delimiter)


def write_weights_csv(path, frames, names, weights, *, delimiter=","):
    """Write ``frame,<shape>,...`` with one row per frame, atomically."""
    _write_table(path, ["frame", *names], np.asarray(frames), np.asarray(weights), delimiter)


def read_weights_csv(path):
    """Read ``frame,<shape>,...``. Returns (frames (F,), names tuple, weights (F, K))."""
    path, _, numbered = _read_rows(path)
    header = [h.strip() for h in numbered[0][1]]
    if len(numbered) < 2:
        raise InputFileError(path, "no data rows after the header", line=1)
    _check_row_lengths(path, numbered, len(header))
    frame_col = _frame_column(path, header)
    cols = [i for i in range(len(header)) if i != frame_col]
    weights = _numeric_block(path, numbered, cols, header)
    frames = _numeric_block(path, numbered, [frame_col], header)[:, 0]
    return frames, tuple(header[i] for i in cols), weights


def _format_frames(frames):
    if np.all(frames == np.round(frames)):
        return [str(int(f)) for f in frames]
    return [repr(float(f)) for f in frames]


def _write_table(path, header, frames, values, delimiter):
    if values.ndim != 2 or values.shape != (len(frames), len(header) - 1):
        raise FacecapError(
            f"{path}: values must have shape ({len(frames)}, {len(header) - 1}); got {values.shape}"
        )
    frame_text = _format_frames(np.asarray(frames, dtype=np.float64))
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(delimiter.join(header) + "\n")
        for f, row in zip(frame_text, values):
            cells = ["" if np.isnan(v) else f"{v:.9g}" for v in row]
            fh.write(f + delimiter + delimiter.join(cells) + "\n")
