"""Per-shape solve options given by name patterns: bounds, locks and regions.

Patterns are shell-style globs (``mouth*``, ``eyeBlink?eft``) matched against shape or marker
names; the first matching entry wins, so specific patterns go before general ones.
"""

from dataclasses import dataclass
from fnmatch import fnmatchcase

import numpy as np

from ..errors import FacecapError


@dataclass(frozen=True)
class Region:
    """Shapes solved only from the markers of this region (e.g. upper face from upper-face markers)."""

    name: str
    shapes: tuple  # glob patterns
    markers: tuple  # glob patterns


def _first_match(name, entries):
    for pattern, value in entries:
        if fnmatchcase(name, pattern):
            return value
    return None


def resolve_bounds(shape_names, lower, upper, bounds):
    """Per-shape (lower, upper): the basis' slider range, overridden by ``bounds`` ((pattern, lo, hi), ...)."""
    lo, hi = np.array(lower, dtype=np.float64), np.array(upper, dtype=np.float64)
    entries = [(p, (a, b)) for p, a, b in bounds]
    _check_patterns("bounds", [p for p, _ in entries], shape_names)
    for k, name in enumerate(shape_names):
        match = _first_match(name, entries)
        if match is not None:
            lo[k], hi[k] = match
    bad = [shape_names[k] for k in np.flatnonzero(lo > hi)]
    if bad:
        raise FacecapError(f"bounds: lower exceeds upper for {bad}")
    return lo, hi


def resolve_locks(shape_names, locks, *, n_frames=None):
    """Lock values, NaN for free shapes, from ((pattern, value), ...).

    A value is a number, or an array of one value per frame (NaN = free on that frame; needs
    ``n_frames``): then the result is (F, K), else (K,).
    """
    _check_patterns("locks", [p for p, _ in locks], shape_names)
    per_frame = any(np.ndim(v) > 0 for _, v in locks)
    if per_frame and n_frames is None:
        raise FacecapError("locks: per-frame lock values need the number of frames")
    values = np.full((n_frames, len(shape_names)) if per_frame else len(shape_names), np.nan)
    for k, name in enumerate(shape_names):
        match = _first_match(name, locks)
        if match is None:
            continue
        if per_frame:
            column = np.asarray(match, dtype=np.float64)
            if column.ndim > 0 and column.shape != (n_frames,):
                raise FacecapError(f"locks: '{name}' has {column.size} per-frame values for {n_frames} frames")
            values[:, k] = column
        else:
            values[k] = match
    return values


def resolve_regions(shape_names, marker_names, regions, dims):
    """Engine regions [(shape indices, coordinate indices), ...] plus the names of shapes left out.

    Each shape belongs to the first region whose shape patterns match it; shapes matching no region
    are held (they never move).
    """
    if not regions:
        return None, ()
    owner = {}
    out = []
    for region in regions:
        shapes = [k for k, n in enumerate(shape_names) if k not in owner and any(fnmatchcase(n, p) for p in region.shapes)]
        markers = [m for m, n in enumerate(marker_names) if any(fnmatchcase(n, p) for p in region.markers)]
        if not markers:
            raise FacecapError(f"region '{region.name}': no marker matches {list(region.markers)}")
        if not shapes:
            raise FacecapError(f"region '{region.name}': no shape matches {list(region.shapes)} (or all are taken by earlier regions)")
        for k in shapes:
            owner[k] = region.name
        coords = (np.asarray(markers)[:, None] * dims + np.arange(dims)[None]).ravel()
        out.append((np.asarray(shapes), coords))
    held = tuple(n for k, n in enumerate(shape_names) if k not in owner)
    return out, held


def _check_patterns(what, patterns, names):
    unused = [p for p in patterns if not any(fnmatchcase(n, p) for n in names)]
    if unused:
        raise FacecapError(f"{what}: pattern(s) {unused} match no shape; shapes are {', '.join(names[:8])}...")
