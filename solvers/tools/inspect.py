"""``python -m facecap inspect FILE [--json]``: what a capture file holds, or one line saying why it cannot be read.

Marker files (C3D, TRC, CSV, JSON) and solved-weights CSVs (Live Link Face, ARKit, MediaPipe,
``frame,<shape>,...``) are told apart from the header (:func:`facecap.solvers.io.capture_kind`);
``--weights`` forces the weights reader. ``--json`` prints :func:`summary` / :func:`summary_weights`.
"""

import argparse
import json
import sys
import warnings

import numpy as np

from ..errors import FacecapError
from ..io import capture_kind, import_markers, read_weights
from ..markers import MarkerSet


def describe(markers, *, notes=(), format=None):
    """Human-readable summary of a MarkerSet: markers, frames, rate, units, gaps per marker, segments."""
    if not isinstance(markers, MarkerSet):
        raise FacecapError("`markers` must be a MarkerSet")
    f = markers.frames
    gaps = markers.gap_counts()
    total = markers.n_frames * markers.n_markers
    lines = [
        f"file:     {markers.source or '-'}" + (f" ({format})" if format else ""),
        f"markers:  {markers.n_markers} ({markers.dim}D)",
        f"frames:   {markers.n_frames} ({f[0]:g}..{f[-1]:g}), {markers.fps:g} fps, "
        f"{(f[-1] - f[0]) / markers.fps:.2f} s",
        f"units:    {markers.units}",
        f"gaps:     {sum(gaps.values())} of {total} samples ({100.0 * sum(gaps.values()) / total:.1f} %)",
    ]
    finite = markers.positions[markers.visible]
    if finite.size:
        lo, hi = finite.min(axis=0), finite.max(axis=0)
        lines.append("extent:   " + ", ".join(f"{a} {l:.4g}..{h:.4g}" for a, l, h in zip("xyz", lo, hi)))
    width = max(len(n) for n in markers.names)
    lines.append("per marker (gap samples, gap runs, longest run):")
    for name, g in gap_table(markers.visible, markers.names).items():
        lines.append(f"  {name:<{width}}  {g['samples']:>7}  {g['runs']:>5}  {g['longest']:>6}")
    if markers.segments:
        lines.append("segments:")
        for label, spans in markers.segments.items():
            text = ", ".join(f"{a:g}..{b:g}" for a, b in spans)
            lines.append(f"  {label}: {text}")
    else:
        lines.append("segments: none")
    for note in notes:
        lines.append(f"note: {note}")
    return "\n".join(lines)


def gap_table(visible, names):
    """{name: {"samples", "runs", "longest"}} of the gaps in a (F, N) visibility table."""
    out = {}
    for j, name in enumerate(names):
        runs = _gap_runs(visible[:, j])
        out[name] = {"samples": int(np.count_nonzero(~visible[:, j])), "runs": len(runs),
                     "longest": int(max((b - a for a, b in runs), default=0))}
    return out


def _gap_runs(visible):
    v = np.concatenate([[True], visible, [True]]).astype(np.int8)
    d = np.diff(v)
    return list(zip(np.flatnonzero(d == -1), np.flatnonzero(d == 1)))


def _frames(frames):
    return {"count": int(frames.size), "first": float(frames[0]), "last": float(frames[-1])}


def summary(result):
    """JSON-ready summary of an ImportResult (``kind`` "markers").

    Keys: file, format, kind, names, dim, frames {count, first, last}, fps, fps_from, units,
    units_from, extent {min, max} (or None), gaps {name: {samples, runs, longest}}, segments, notes.
    """
    m = result.markers
    finite = m.positions[m.visible]
    extent = {"min": finite.min(axis=0).tolist(), "max": finite.max(axis=0).tolist()} if finite.size else None
    return {
        "file": m.source, "format": result.format, "kind": "markers", "names": list(m.names), "dim": m.dim,
        "frames": _frames(m.frames), "fps": float(m.fps), "fps_from": result.decided.get("fps"),
        "units": m.units, "units_from": result.decided.get("units"), "extent": extent,
        "gaps": gap_table(m.visible, m.names),
        "segments": {k: [[float(a), float(b)] for a, b in v] for k, v in m.segments.items()},
        "notes": list(result.notes),
    }


def summary_weights(track, *, fps_given=False):
    """JSON-ready summary of a WeightTrack (``kind`` "weights"); gaps are missing cells per shape."""
    notes = list(track.notes)
    fps_from = ("given" if fps_given else "timecode" if track.timecode
                else "timestamps" if any("timestamps" in n for n in notes)
                else "assumed" if any("assumed" in n for n in notes) else "file")
    return {
        "file": track.source, "format": track.format, "kind": "weights", "names": list(track.names),
        "frames": _frames(track.frames), "fps": float(track.fps), "fps_from": fps_from, "units": None,
        "units_from": None, "timecode": track.timecode or None,
        "head": track.head is not None, "eyes": track.eyes is not None,
        "gaps": gap_table(np.isfinite(track.values), track.names), "segments": {}, "notes": notes,
    }


def describe_weights(track):
    """Summary of a WeightTrack."""
    v = track.values
    lines = [
        f"file:     {track.source} ({track.format}, solved weights)",
        f"channels: {len(track.names)}" + (", head yaw/pitch/roll" if track.head is not None else "")
        + (", eye angles" if track.eyes is not None else ""),
        f"frames:   {len(track.frames)} ({track.frames[0]:g}..{track.frames[-1]:g}), {track.fps:g} fps"
        + (f", timecode {track.timecode}" if track.timecode else ""),
        f"missing:  {int(np.isnan(v).sum())} cells",
    ]
    lines += [f"note: {n}" for n in track.notes]
    return "\n".join(lines)


DESCRIPTION = ("Describe a capture file (markers or solved weights): markers, frames, rate, units, gaps per "
               "marker and segments, or one line saying why it cannot be read.")


def parser(prog="facecap inspect", description=DESCRIPTION, parents=()):
    """The reading options shared by ``inspect`` and ``convert`` (``parents``: the command line's -q / -v)."""
    p = argparse.ArgumentParser(prog=prog, description=description, parents=list(parents))
    p.add_argument("--units", default=None, help="what the file's numbers are: m, cm, mm, bu (with --unit-scale) or px")
    p.add_argument("--unit-scale", type=float, default=None, help="metres per unit for --units bu")
    p.add_argument("--fps", type=float, default=None, help="frame rate (weights: resample to it)")
    p.add_argument("--up-axis", choices=("Y", "Z"), default=None, help="Y converts a Y-up file to Blender's Z-up")
    p.add_argument("--weights", action="store_true", help="read a solved-weights CSV (detected from the header otherwise)")
    p.add_argument("--columns", default=None, metavar="NAMES",
                   help="a marker CSV without a header row: its columns, comma-separated (frame,nose,chin: a marker "
                        "name stands for its x, y, z columns), as [source] columns")
    return p


def read_capture(args):
    """("markers", ImportResult) or ("weights", WeightTrack) for parsed ``args`` (file, units, fps, ...)."""

    if args.weights or capture_kind(args.file) == "weights":
        if args.units is not None or args.unit_scale is not None or args.up_axis is not None:
            raise FacecapError(f"{args.file}: a weights file has no units or axes; drop --units/--unit-scale/--up-axis")
        return "weights", read_weights(args.file, fps=args.fps)
    columns = None if getattr(args, "columns", None) is None else [c.strip() for c in args.columns.split(",")]
    options = {k: v for k, v in (("unit_scale", args.unit_scale), ("up_axis", args.up_axis), ("columns", columns))
               if v is not None}
    return "markers", import_markers(args.file, units=args.units, fps=args.fps, **options)


def main(argv=None, *, parents=()):
    """Entry point for ``facecap inspect``; returns the exit code (0 ok, 1 bad file, 2 usage)."""
    p = parser(parents=parents)
    p.add_argument("file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = p.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the notes carry them
            kind, got = read_capture(args)
    except FacecapError as exc:
        print(f"facecap inspect: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        data = summary(got) if kind == "markers" else summary_weights(got, fps_given=args.fps is not None)
        print(json.dumps(data, indent=1, allow_nan=False, default=_plain))
    elif kind == "markers":
        print(describe(got.markers, notes=got.notes, format=got.format))
    else:
        print(describe_weights(got))
    return 0


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(type(value).__name__)


if __name__ == "__main__":
    sys.exit(main())
