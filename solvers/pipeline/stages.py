"""The take's preparation, shared by every marker strategy: stabilise (head motion removed), then
normalise against the neutral, giving the ``PreparedTake`` a strategy fits and solves.

``prepare_take`` is the one entry point, for the take being solved and for any other take a
strategy learns from (training, example takes: ``for_other_take``), 3D or 2D image tracks.
"""

import warnings
from dataclasses import replace

import numpy as np

from ..capture.neutral import neutral_from_frames
from ..capture.normalise import (
    DEFAULT_LANDMARKS,
    detect_neutral_frames,
    master_offsets,
    neutral_from_file,
    neutral_from_ranges,
)
from ..capture.stabilise import smooth_head_motion, stabilise_2d, stabilise_rigid
from ..capture.stable_markers import suggest_stable_markers
from ..engine.split import release_freed_memory
from ..errors import FacecapError
from ..io import import_markers
from ..strategies.base import PreparedTake


def reference_range(settings):
    """The frames whose pose is the stabilisation reference: the first neutral range (None if detected only)."""
    if settings.neutral_ranges:
        return tuple(settings.neutral_ranges[0])
    if settings.neutral_detect and settings.neutral_frames in ((), None, (1, 1)):
        return None
    return tuple(settings.neutral_frames) if settings.neutral_frames else None


def stabilise_take(markers, settings, notes):
    """Gross stabilisation (auto stable set, rigid or similarity, smoothed head motion) of 3D
    ``markers`` in metres; returns (StabiliseResult, StableSuggestion or None)."""
    suggestion = None
    stable = tuple(settings.stable_markers)
    if settings.auto_stable:
        suggestion = suggest_stable_markers(markers, reference_frames=reference_range(settings))
        if not suggestion.ok:  # never a silent bad set: name the candidates instead
            raise FacecapError(f'[stabilise] markers = "auto": {suggestion.message()}; name the stable markers '
                               "in [stabilise] markers")
        stable = suggestion.names
        notes.append(suggestion.message())
        if "warning" in suggestion.conditioning:
            notes.append(f"suggested stable markers: {suggestion.conditioning['warning']}")
    stab = stabilise_rigid(markers, stable, reference_frames=reference_range(settings), mode=settings.stabilise_mode)
    stab = smooth_head_motion(markers, stab, half_window=head_half_window(settings, markers.fps))
    moving = [n for n, w in stab.marker_trust.items() if w < 0.5]
    if moving:
        notes.append(f"stable marker(s) {moving} move relative to the others and were left out of the head fit")
    if stab.unreliable is not None and stab.unreliable.any():
        notes.append(f"{int(stab.unreliable.sum())} frame(s) have an unreliable head fit (too few stable markers "
                     "agree); see stabilise.unreliable_frames")
    return stab, suggestion


def head_half_window(settings, fps):
    """The head-pose smoothing half-window in frames."""
    return int(round(settings.head_smoothing * fps))


def _load(source):
    if source is None or hasattr(source, "positions"):
        return source

    return import_markers(source).markers.to_units("m")


def normalise_stabilised(stab, settings, notes):
    """The neutral (M, 3) in the stabilised head frame, per-frame master offsets (F, M, 3) or None, and info."""
    sm = stab.markers
    ranges = tuple(tuple(r) for r in settings.neutral_ranges) or (
        (tuple(settings.neutral_frames),) if settings.neutral_frames and not settings.neutral_detect else ())
    if settings.master is not None:
        if not ranges:
            raise FacecapError("master T-pose normalisation needs the take's T-pose frames ([neutral] frames)")
        master = _load(settings.master)
        norm = master_offsets(sm, master, ranges, landmarks=settings.landmarks or DEFAULT_LANDMARKS)
        info = {"source": "master", "ranges": [list(r) for r in ranges], "master": norm.report(sm.names)}
        return norm.master, norm.offsets, info
    if settings.neutral_file is not None:
        fm = _load(settings.neutral_file)
        pose = neutral_from_file(fm, stab, stable_names=stab.stable_names)
        missing = [n for n in sm.names if n not in set(fm.names)]
        if missing:
            raise FacecapError(f"neutral file {fm.source}: has no marker(s) {missing[:8]}")
        return pose[fm.index(sm.names)], None, {"source": "file", "file": str(fm.source)}
    if settings.neutral_detect:
        frames, _ = detect_neutral_frames(sm)
        notes.append(f"neutral detected from {len(frames)} frame(s): {spans(frames)}")
        sel = np.isin(sm.frames, frames)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(sm.positions[sel], axis=0), None, {"source": "detected",
                                                                   "frames": [float(f) for f in frames]}
    return neutral_from_ranges(sm, ranges), None, {"source": "frames", "ranges": [list(r) for r in ranges]}


def spans(frames):
    """'1-30, 571-600' for sorted frame numbers."""
    out, start, prev = [], None, None
    for f in frames:
        if start is None:
            start = prev = f
        elif f == prev + 1:
            prev = f
        else:
            out.append((start, prev))
            start = prev = f
    if start is not None:
        out.append((start, prev))
    return ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in out)


def normalised(stab, settings, notes):
    """The PreparedTake of a stabilised 3D take, and the neutral's info."""
    neutral, offsets, info = normalise_stabilised(stab, settings, notes)
    sm = stab.markers
    pos = sm.positions if offsets is None else sm.positions + offsets
    take = PreparedTake(pos - neutral[None], neutral, sm.names, sm.frames, stab, offsets, fps=sm.fps)
    pos = sm = None
    stab.release_markers()  # their (F, M, 3) floats: computed again if read (issue 18)
    return take, info


def neutral_ranges(settings):
    """The frame ranges the neutral is taken from ((first, last), ...); () when it is detected or read
    from a file (2D takes: the stabilisation reference, else the whole take)."""
    if settings.neutral_detect or settings.neutral_file is not None:
        return ()
    return tuple(tuple(r) for r in settings.neutral_ranges) or (
        (tuple(settings.neutral_frames),) if settings.neutral_frames else ())


def usable_markers(markers, settings, notes, *, bound=None):
    """The take without the markers nothing can use, each left out with a note naming it.

    A marker that is not stable is left out when it has no sample over the neutral frames (it has
    no neutral to measure from) or, given ``bound`` (the markers bound on the character), when it
    is not bound (nothing is solved from it). Stable markers are always kept (they need no
    binding); with ``auto_stable`` every marker with a neutral is a candidate and is kept.
    """
    stable = set() if settings.auto_stable else set(settings.stable_markers)
    ranges = neutral_ranges(settings) if markers.dim == 3 else (reference_range(settings) or (),)
    sel = np.zeros(markers.n_frames, dtype=bool)
    for first, last in (r for r in ranges if r):
        sel |= markers.frame_range_mask(first, last)
    never = []
    if sel.any():  # no frame in range: the neutral says so itself
        seen = ~np.isnan(markers.positions[sel, :, 0]).all(axis=0)
        never = [n for n, ok in zip(markers.names, seen) if not ok and n not in stable]
    unbound = [] if bound is None or settings.auto_stable else \
        [n for n in markers.names if n not in set(bound) and n not in stable and n not in never]
    if never:
        notes.append(f"{len(never)} marker(s) have no sample over the neutral frames and are left out: "
                     f"{', '.join(never)} (to use them, give [neutral] frames where they are seen)")
    if unbound:
        notes.append(f"{len(unbound)} marker(s) are neither bound on the character nor stable and are left out: "
                     f"{', '.join(unbound)} (to use them, bind them: docs/binding.md)")
    drop = set(never) | set(unbound)
    return markers if not drop else markers.subset([n for n in markers.names if n not in drop])


def prepare_take(markers, settings, notes):
    """The take as strategies receive it, every stabilisation and neutral option applied.

    Returns (PreparedTake, StableSuggestion or None, neutral info). 3D markers are stabilised
    rigidly (or by a similarity) and normalised in metres; 2D image tracks (pixels) by a per-frame
    2D similarity on the stable points, their neutral the reference frames' average.
    """
    if markers.dim == 2:
        return _prepare_2d(markers, settings, notes), None, {}
    markers = markers.to_units("m")
    stab, suggestion = stabilise_take(markers, settings, notes)
    take, info = normalised(stab, settings, notes)
    release_freed_memory(take.frames.size)  # long takes: the stabilisation's freed memory (issue 18)
    return take, suggestion, info


def for_other_take(settings, take):
    """A ``prepare`` for the other takes a strategy learns from (a training or example take): the
    solved take's stable set (as chosen), stabilisation mode and neutral frames."""
    if take.dim == 2:
        others = settings
    else:
        stable = take.stabilise.stable_names if settings.auto_stable else settings.stable_markers
        others = replace(settings, auto_stable=False, stable_markers=stable, neutral_ranges=(), neutral_detect=False,
                         neutral_file=None, master=None)

    def prepare(markers):
        prepared, _, _ = prepare_take(markers, others, [])
        return prepared

    return prepare


def _prepare_2d(markers, settings, notes):
    stable = settings.stable_markers
    if isinstance(stable, str) or getattr(settings, "auto_stable", False) or not tuple(stable):
        raise FacecapError("2D takes need an explicit list of stable points ([stabilise] markers)")
    first, last = reference_range(settings) or (markers.frames[0], markers.frames[-1])
    stab = stabilise_2d(markers, tuple(stable), reference_frames=(first, last), mode="similarity")
    if stab.flagged.any():
        notes.append(f"{int(stab.flagged.sum())} frame(s) could not be stabilised (too few stable points)")
    neutral = neutral_from_frames(stab.markers, first, last)
    return PreparedTake(stab.markers.positions - neutral[None], neutral, markers.names, markers.frames, stab)
