"""``python -m facecap inspect FILE``: what a capture file holds, or one line saying why it cannot be read."""

import argparse
import sys
import warnings

import numpy as np

from ..errors import FacecapError
from ..io import import_markers, read_weights
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
    vis = markers.visible
    for m, name in enumerate(markers.names):
        runs = _gap_runs(vis[:, m])
        longest = max((b - a for a, b in runs), default=0)
        lines.append(f"  {name:<{width}}  {gaps[name]:>7}  {len(runs):>5}  {longest:>6}")
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


def _gap_runs(visible):
    v = np.concatenate([[True], visible, [True]]).astype(np.int8)
    d = np.diff(v)
    return list(zip(np.flatnonzero(d == -1), np.flatnonzero(d == 1)))


def main(argv=None):
    """Entry point for ``facecap inspect``; returns the exit code (0 ok, 1 bad file, 2 usage)."""
    parser = argparse.ArgumentParser(prog="facecap inspect", description="Describe a capture file.")
    parser.add_argument("file")
    parser.add_argument("--units", default=None, help="m, cm, mm, bu (with --unit-scale) or px")
    parser.add_argument("--unit-scale", type=float, default=None, help="metres per unit for --units bu")
    parser.add_argument("--fps", type=float, default=None)
    parser.add_argument("--up-axis", choices=("Y", "Z"), default=None)
    parser.add_argument("--weights", action="store_true", help="read a solved-weights CSV (Live Link Face, MediaPipe)")
    args = parser.parse_args(argv)

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if args.weights:
                track = read_weights(args.file, fps=args.fps)
                print(describe_weights(track))
                return 0
            options = {k: v for k, v in (("unit_scale", args.unit_scale), ("up_axis", args.up_axis)) if v is not None}
            result = import_markers(args.file, units=args.units, fps=args.fps, **options)
    except FacecapError as exc:
        print(f"facecap inspect: {exc}", file=sys.stderr)
        return 1
    print(describe(result.markers, notes=result.notes, format=result.format))
    return 0


def describe_weights(track):
    """Summary of a WeightTrack."""
    v = track.values
    lines = [
        f"file:     {track.source} ({track.format})",
        f"channels: {len(track.names)}" + (", head yaw/pitch/roll" if track.head is not None else "")
        + (", eye angles" if track.eyes is not None else ""),
        f"frames:   {len(track.frames)} ({track.frames[0]:g}..{track.frames[-1]:g}), {track.fps:g} fps"
        + (f", timecode {track.timecode}" if track.timecode else ""),
        f"missing:  {int(np.isnan(v).sum())} cells",
    ]
    lines += [f"note: {n}" for n in track.notes]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
