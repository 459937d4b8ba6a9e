"""Writers of marker and weight CSV files (the readers are in :mod:`facecap.solvers.io.csv`).

Writers format blocks of rows at once (``%.9g``, empty for NaN) and replace their output
atomically: a wide marker CSV ``frame,<m>_x,<m>_y[,<m>_z]`` (plus a ``segment`` column when the
take has non-overlapping segments) and a weights CSV ``frame,<shape>,...``. Text cells (the header's
names, segment labels) are quoted as RFC 4180 says (the ``csv`` module), so a name holding the
delimiter or a quote reads back as it was; a line break, which facecap's readers do not take inside a
header or a label, is refused with the name. A text cell that a spreadsheet would run as a formula
(it starts with ``= + - @`` or a tab: a shape key named ``=HYPERLINK(...)`` in someone's character) is
written with a leading ``'`` (OWASP's advice for CSV injection), which spreadsheets show as text and
facecap's readers take off again (``formula_safe`` / ``text_of_cell``).
"""

import numpy as np

from ..errors import FacecapError
from .files import atomic_path

AXES = ("x", "y", "z")
#: First characters that make a spreadsheet read a cell as a formula (OWASP, "CSV Injection")
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def formula_safe(text):
    """``text`` as a CSV text cell a spreadsheet shows as text: a ``'`` before a formula's first character,
    and before a ``'`` that starts such a cell already (so that ``text_of_cell`` gives back exactly ``text``)."""
    if text[:1] in FORMULA_STARTS or (text[:1] == "'" and text[1:2] in FORMULA_STARTS + ("'",)):
        return "'" + text
    return text


def text_of_cell(cell):
    """The text ``formula_safe`` was given, from the cell it made (any other cell as it is)."""
    if cell[:1] == "'" and cell[1:2] in FORMULA_STARTS + ("'",):
        return cell[1:]
    return cell


def write_markers_csv(path, markers, *, delimiter=","):
    """Write a MarkerSet as a wide CSV (gaps as empty cells), atomically.

    Non-overlapping ``segments`` are written as a last ``segment`` text column.
    """
    axes = AXES[: markers.dim]
    header = ["frame"] + [f"{n}_{a}" for n in markers.names for a in axes]
    flat = markers.positions.reshape(markers.n_frames, -1)
    labels = segment_labels(markers)
    _write_table(path, header, markers.frames, flat, delimiter, labels=labels, kind="markers_csv")


def segment_labels(markers):
    """One label per frame from ``markers.segments``, or None if there are none or they overlap."""
    if not markers.segments:
        return None
    labels = [""] * markers.n_frames
    for label, spans in markers.segments.items():
        for first, last in spans:
            for i in np.flatnonzero(markers.frame_range_mask(first, last)):
                if labels[i]:
                    return None
                labels[i] = label
    return labels


def write_weights_csv(path, frames, names, weights, *, delimiter=","):
    """Write ``frame,<shape>,...`` with one row per frame, atomically."""
    _write_table(path, ["frame", *names], np.asarray(frames), np.asarray(weights), delimiter, kind="weights_csv")


def _format_frames(frames):
    if np.all(frames == np.round(frames)):
        return [str(int(f)) for f in frames]
    return [repr(float(f)) for f in frames]


def _write_table(path, header, frames, values, delimiter, *, labels=None, kind=None):
    if values.ndim != 2 or values.shape != (len(frames), len(header) - 1):
        raise FacecapError(
            f"{path}: values must have shape ({len(frames)}, {len(header) - 1}); got {values.shape}"
        )
    frame_text = _format_frames(np.asarray(frames, dtype=np.float64))
    if labels is not None:
        header = header + ["segment"]
        edged = sorted({label for label in labels if label != label.strip()})
        if edged:  # data cells are read stripped, quoted or not
            raise FacecapError(f"{path}: a CSV segment label cannot begin or end with a space: {edged[:5]}; rename it")
        labels = [_quoted(label, delimiter, path, "segment label") for label in labels]
    head = _text_row(header, delimiter, path)
    with atomic_path(path, kind=kind) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(head)
        for text in _data_lines(frame_text, values, delimiter, labels):
            fh.write(text)


def _no_line_break(text, path, what):
    if "\n" in text or "\r" in text:
        raise FacecapError(f"{path}: a CSV {what} cannot hold a line break (facecap's readers read a header or a "
                           f"label as one line): {text!r}; rename it")


def _text_row(cells, delimiter, path):
    """One CSV line of text ``cells``, quoted where RFC 4180 needs it (and where a reader would strip spaces)."""
    return delimiter.join(_quoted(cell, delimiter, path, "header name") for cell in cells) + "\n"


def _quoted(text, delimiter, path, what):
    """``text`` as one CSV cell, quoted as RFC 4180 does (``csv.QUOTE_MINIMAL``) and also when it has
    spaces at either end (unquoted cells are read stripped); a formula's first character is escaped
    (``formula_safe``)."""
    _no_line_break(text, path, what)
    text = formula_safe(text)
    if delimiter in text or '"' in text or text != text.strip():
        return '"' + text.replace('"', '""') + '"'
    return text


WRITE_BLOCK_CELLS = 1 << 18


def _data_lines(frame_text, values, delimiter, labels):
    """Blocks of data lines: the frame, ``f"{v:.9g}"`` per value (empty for NaN), the label.

    Numeric arrays are formatted a block of rows at a time by one ``%`` over a repeated row
    format (the same conversion as the f-string); the NaN cells, which ``%.9g`` writes as
    ``nan``, are then emptied. Other arrays, and labels that contain ``nan``, go cell by cell.
    """
    n, k = values.shape
    if k == 0 or values.dtype.kind not in "fiu" or (labels is not None and any("nan" in x for x in labels)):
        yield from _data_lines_per_cell(frame_text, values, delimiter, labels)
        return
    d = delimiter
    row = "%s" + (d + "%.9g") * k + ("" if labels is None else d + "%s") + "\n"
    step = max(1, WRITE_BLOCK_CELLS // k)
    for start in range(0, n, step):
        block = values[start:start + step]
        cells = np.empty((len(block), k + 1 + (labels is not None)), dtype=object)
        cells[:, 0] = frame_text[start:start + step]
        cells[:, 1:k + 1] = block
        if labels is not None:
            cells[:, -1] = labels[start:start + step]
        text = (row * len(block)) % tuple(cells.ravel().tolist())
        if np.isnan(block).any():
            gap = d + "nan"  # a value cell; frames start a line and labels have no "nan"
            text = text.replace(gap + d, d + d).replace(gap + d, d + d).replace(gap + "\n", d + "\n")
        yield text


def _data_lines_per_cell(frame_text, values, delimiter, labels):
    for i, (f, row) in enumerate(zip(frame_text, values)):
        cells = ["" if np.isnan(v) else f"{v:.9g}" for v in row]
        if labels is not None:
            cells.append(labels[i])
        yield f + delimiter + delimiter.join(cells) + "\n"


__all__ = ["AXES", "formula_safe", "segment_labels", "text_of_cell", "write_markers_csv", "write_weights_csv"]
