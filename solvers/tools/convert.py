"""``python -m facecap convert IN OUT [--units U] [--fps N] ...``: convert a capture file to another format.

* Markers (C3D, TRC, CSV wide or long, JSON) -> ``OUT``'s format by its extension: ``.csv`` (wide),
  ``.c3d``, ``.trc`` or ``.json``. ``--units``/``--unit-scale``/``--up-axis``/``--fps`` say how to
  read ``IN`` (as in a take config's ``[source]``); ``--out-units`` converts the positions
  (m, cm, mm) before writing.
* Solved weights (Live Link Face, ARKit, MediaPipe, ``frame,<shape>,...``) -> the weights CSV
  ``frame,<shape>,...`` at ``--fps`` (default: the file's rate; timestamped files are resampled).
  Head and eye angles are not shapes and are left out (the summary says so).

The output is written atomically and never over ``IN`` (compared after resolving links, ``..``
and case). Ends with one line: what was written, or ``facecap convert: <why>`` and exit status 1.
Warnings about the input (repeated labels renamed, a truncated file) go to stderr first.
"""

import os
import sys
import warnings
from pathlib import Path

from ..errors import FacecapError
from ..io import write_markers
from ..io.csv_write import write_weights_csv
from .inspect import parser as reading_parser
from .inspect import read_capture

MARKER_OUTPUTS = (".csv", ".c3d", ".trc", ".json")


def same_file(a, b):
    """Whether paths ``a`` and ``b`` name one file (after ``~``, ``..``, symlinks; hard links and
    case-insensitive file systems caught by comparing the existing files)."""
    a, b = Path(a).expanduser(), Path(b).expanduser()
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist yet
        return False


def check_output(src, out, allowed):
    """FacecapError unless ``out`` is a new or replaceable file of an ``allowed`` extension, not ``src``."""
    out = Path(out)
    if out.suffix.lower() not in allowed:
        raise FacecapError(f"{out}: cannot write '{out.suffix or 'no extension'}'; use {', '.join(allowed)}")
    if same_file(src, out):
        raise FacecapError(f"{out}: is the input file; choose another output path (the input is never overwritten)")
    if out.is_dir():
        raise FacecapError(f"{out}: is a directory; give a file name")
    parent = out.expanduser().resolve().parent
    if not parent.is_dir():
        raise FacecapError(f"{out}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FacecapError(f"{out}: folder {parent} is not writable")


def convert(src, out, *, kind, got, out_units=None):
    """Write ``got`` (an ImportResult for "markers", a WeightTrack for "weights") to ``out``; returns the summary line."""

    if kind == "weights":
        check_output(src, out, (".csv",))
        write_weights_csv(out, got.frames, got.names, got.values)
        left = [w for w, v in (("head angles", got.head), ("eye angles", got.eyes)) if v is not None]
        return (f"wrote {out} (weights CSV): {len(got.frames)} frames x {len(got.names)} shapes at {got.fps:g} fps"
                f" from {got.format}" + (f"; {' and '.join(left)} left out" if left else ""))
    check_output(src, out, MARKER_OUTPUTS)
    markers = got.markers if out_units is None else got.markers.to_units(out_units)
    write_markers(out, markers)
    return (f"wrote {out} ({Path(out).suffix.lower()[1:]}): {markers.n_frames} frames x {markers.n_markers} markers, "
            f"{markers.fps:g} fps, {markers.units} (from {got.format}; units {got.decided.get('units')}, "
            f"fps {got.decided.get('fps')})")


DESCRIPTION = ("Convert a capture file to another format: markers to CSV, C3D, TRC or JSON (by OUT's extension), "
               "solved weights to a weights CSV.")


def main(argv=None, *, parents=()):
    """Entry point for ``facecap convert``; returns the exit code (0 ok, 1 bad input, 2 usage)."""
    p = reading_parser(prog="facecap convert", description=DESCRIPTION, parents=parents)
    p.add_argument("file", metavar="IN")
    p.add_argument("out", metavar="OUT", help="output file: .csv, .c3d, .trc or .json (weights: .csv)")
    p.add_argument("--out-units", choices=("m", "cm", "mm"), default=None, help="convert positions before writing")
    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the notes carry them
            if same_file(args.file, args.out):  # before reading: the cheapest refusal first
                raise FacecapError(f"{args.out}: is the input file; choose another output path "
                                   "(the input is never overwritten)")
            kind, got = read_capture(args)
            if kind == "weights" and args.out_units:
                raise FacecapError(f"{args.file}: a weights file has no units; drop --out-units")
            notes = got.notes
            for note in notes:
                if note.startswith("warning:"):
                    print(f"facecap convert: {note}", file=sys.stderr)
            line = convert(args.file, args.out, kind=kind, got=got, out_units=args.out_units)
    except FacecapError as exc:
        print(f"facecap convert: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the output could not be written (disk full, permissions changed)
        print(f"facecap convert: {args.out}: cannot write: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"facecap convert: {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
