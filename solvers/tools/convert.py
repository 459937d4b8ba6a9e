"""``python -m facecap convert IN OUT [--units U] [--fps N] ...``: convert a capture file to another format.

* Markers (C3D, TRC, CSV wide or long, JSON) -> ``OUT``'s format by its extension: ``.csv`` (wide),
  ``.c3d``, ``.trc`` or ``.json``. ``--units``/``--unit-scale``/``--up-axis``/``--fps`` say how to
  read ``IN`` (as in a take config's ``[source]``); ``--out-units`` converts the positions
  (m, cm, mm) before writing.
* Solved weights (Live Link Face, ARKit, MediaPipe, ``frame,<shape>,...``) -> the weights CSV
  ``frame,<shape>,...`` at ``--fps`` (default: the file's rate; timestamped files are resampled).
  Head and eye angles are not shapes and are left out (the summary says so).

The output is written atomically and goes through the output policy (``solvers.io.outputs``): never
over ``IN`` (compared after resolving links, ``..`` and case), a folder or a special file, and over an
existing file only when it is facecap's own output of that kind, or with ``--overwrite``. Ends with one
line: what was written, or ``facecap convert: <why>`` and exit status 1.
Warnings about the input (repeated labels renamed, a truncated file) go to stderr first.
"""

import sys
import warnings
from pathlib import Path

from ..errors import FacecapError
from ..io import write_markers
from ..io.csv_write import write_weights_csv
from ..io.outputs import Output, check_outputs
from .inspect import parser as reading_parser
from .inspect import read_capture

MARKER_OUTPUTS = (".csv", ".c3d", ".trc", ".json")


#: Output extension -> the kind of file it is (``solvers.io.outputs.KINDS``), for markers and weights
MARKER_KINDS = {".csv": "markers_csv", ".c3d": "c3d", ".trc": "trc", ".json": "markers_json"}


def check_output(src, out, allowed, *, kind=None, overwrite=False):
    """FacecapError unless ``out`` has an ``allowed`` extension and the output policy
    (``solvers.io.outputs``) lets it be written: not ``src``, not a folder or special file, and an
    existing file only when it is facecap's own of that kind (or ``overwrite``)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in allowed:
        raise FacecapError(f"{out}: cannot write '{out.suffix or 'no extension'}'; use {', '.join(allowed)}")
    check_outputs([Output("OUT", out, kind or MARKER_KINDS[suffix])], {"IN (the input file)": src},
                  overwrite=overwrite)


def convert(src, out, *, kind, got, out_units=None, overwrite=False):
    """Write ``got`` (an ImportResult for "markers", a WeightTrack for "weights") to ``out``; returns the summary line."""

    if kind == "weights":
        check_output(src, out, (".csv",), kind="weights_csv", overwrite=overwrite)
        write_weights_csv(out, got.frames, got.names, got.values)
        left = [w for w, v in (("head angles", got.head), ("eye angles", got.eyes)) if v is not None]
        return (f"wrote {out} (weights CSV): {len(got.frames)} frames x {len(got.names)} shapes at {got.fps:g} fps"
                f" from {got.format}" + (f"; {' and '.join(left)} left out" if left else ""))
    check_output(src, out, MARKER_OUTPUTS, overwrite=overwrite)
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
    p.add_argument("--overwrite", action="store_true",
                   help="let OUT replace an existing file facecap did not write (default: refused)")
    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the notes carry them
            suffix = Path(args.out).suffix.lower()
            if suffix in MARKER_OUTPUTS:  # before reading: the cheapest refusal first (weights: once known)
                check_outputs([Output("OUT", args.out, MARKER_KINDS[suffix] if suffix != ".csv" else "weights_csv")],
                              {"IN (the input file)": args.file}, overwrite=True)
            kind, got = read_capture(args)
            if kind == "weights" and args.out_units:
                raise FacecapError(f"{args.file}: a weights file has no units; drop --out-units")
            notes = got.notes
            for note in notes:
                if note.startswith("warning:"):
                    print(f"facecap convert: {note}", file=sys.stderr)
            line = convert(args.file, args.out, kind=kind, got=got, out_units=args.out_units, overwrite=args.overwrite)
    except FacecapError as exc:
        print(f"facecap convert: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the output could not be written (disk full, permissions changed)
        print(f"facecap convert: error: {args.out}: cannot write: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"facecap convert: {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
