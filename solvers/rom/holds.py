"""Where a range-of-motion take holds its poses: excursions from the neutral and the plateau of each.

The face's activity at a frame is how far its most-moved markers are from the neutral, in units of what the
capture's noise would move them (``activity``: the mean of the ``TOP`` largest per-marker distances of the
deltas smoothed over ``SMOOTH_S``, over the noise of such a mean). A pose as subtle as a look down (three
lid markers, 2 mm) stands 10x above the noise; a face at rest stays within 2-3x. An excursion is a run of frames
above ``ENTER`` that began and ends below ``LEAVE`` (hysteresis), short dips merged and blips dropped; its hold
is the top of a trapezoid with smooth ramps fitted to how much of the pose's own pattern (the deltas where the
activity peaks) each frame shows (every visible marker counts, so a gap in one does not cut a hold; every frame
counts, so a subtle pose's noise does not move it much), and the hold's middle is where the pose is measured.
"""

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import FacecapError

#: Markers whose distances make up the activity; the smoothing (s).
TOP, SMOOTH_S = 3, 0.2
#: Activity (noise units) above which a frame is in an excursion, and below which one ends (a face at rest: 2-3;
#: the subtlest poses on dense markers, a look in or eyes wide: 6-8).
ENTER, LEAVE = 5.0, 3.2
#: Dips shorter than this (s) do not end an excursion; excursions shorter than this (s) are not poses (a hold
#: of 0.5 s with its ramps lasts 0.9 s or more).
MERGE_S, MIN_S = 0.15, 0.5
#: Seconds of the neutral on each side of an excursion that its hold's fit also sees.
PAD_S = 0.2
#: The frames measured for a pose: this share of its hold, about its middle.
MEASURED = 0.6
#: The plateau fit's pattern search: its first step (a share of the starting ramp's length), its last (frames), and
#: the moves at most per step length.
PLATEAU_START, PLATEAU_STEP, PLATEAU_CLIMB = 0.5, 1.0 / 32, 50


@dataclass(frozen=True)
class Hold:
    """An excursion from the neutral (``start``, ``end``: frame numbers) and its held plateau (``first``,
    ``last``; ``middle``), with the activity's ``peak`` there (noise units)."""

    start: float
    end: float
    first: float
    last: float
    peak: float

    @property
    def middle(self):
        return 0.5 * (self.first + self.last)

    def measured(self):
        """(first, last) frame numbers a pose is measured over: ``MEASURED`` of the hold about its middle."""
        half = 0.5 * MEASURED * (self.last - self.first)
        return (int(np.floor(self.middle - half)), int(np.ceil(self.middle + half)))


def _moving_mean(x, half):
    """NaN-aware moving mean over the first axis (window 2 * half + 1)."""
    if half <= 0:
        return x
    ok = np.isfinite(x)
    v = np.where(ok, x, 0.0)
    pad = [(half, half)] + [(0, 0)] * (x.ndim - 1)
    cs = np.cumsum(np.pad(v, pad), axis=0)
    cn = np.cumsum(np.pad(ok.astype(np.float64), pad), axis=0)
    w = 2 * half + 1
    s = cs[w - 1:] - np.concatenate([np.zeros_like(cs[:1]), cs[:-w]])
    n = cn[w - 1:] - np.concatenate([np.zeros_like(cn[:1]), cn[:-w]])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def activity(deltas, noise, fps):
    """(F,) the face's activity (noise units) of stabilised deltas (F, M, 3) from the neutral, with ``noise`` the
    capture's (metres RMS per coordinate, ``capture.noise.marker_noise``) at ``fps``."""
    half = half_window(fps)
    smooth = _moving_mean(deltas, half)
    dist = np.linalg.norm(smooth, axis=2)
    dist = np.where(np.isfinite(dist), dist, -np.inf)
    top = np.sort(dist, axis=1)[:, -TOP:]
    top = np.where(np.isfinite(top), top, np.nan)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frame the head fit flagged: no marker, activity 0
        level = np.nanmean(top, axis=1) if top.size else np.zeros(len(deltas))
    return np.nan_to_num(level / activity_unit(noise, fps))


def half_window(fps):
    """Frames on each side of a frame that the activity is smoothed over (``SMOOTH_S``)."""
    return max(1, int(round(0.5 * SMOOTH_S * fps)))


def activity_unit(noise, fps):
    """The size (metres) of one unit of ``activity``: a smoothed 3D noise vector's."""
    return noise * np.sqrt(3.0 / (2 * half_window(fps) + 1))


def _runs(mask):
    """(start, stop) index pairs of the True runs of a boolean array (stop exclusive)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def find_holds(deltas, frames, fps, noise):
    """The holds of a ROM take, in the order performed (a tuple of Hold).

    Parameters
    ----------
    deltas : (F, M, 3) stabilised marker deltas from the take's neutral (NaN for gaps)
    frames : (F,) frame numbers
    fps : frames per second
    noise : the capture's noise (metres RMS per coordinate)
    """
    if not (np.isfinite(noise) and noise > 0):
        raise FacecapError("finding the ROM's poses needs the capture's noise, and this take shows none (a "
                           "take shorter than 5 frames, or markers that never move)")
    a = activity(deltas, noise, fps)
    frames = np.asarray(frames, dtype=np.float64)
    merge, shortest = int(round(MERGE_S * fps)), int(round(MIN_S * fps))
    runs = []
    for start, stop in _runs(a > LEAVE):
        if a[start:stop].max() < ENTER:
            continue
        if runs and start - runs[-1][1] <= merge:
            runs[-1] = (runs[-1][0], stop)
        else:
            runs.append((start, stop))
    holds = []
    pad = int(round(PAD_S * fps))
    for start, stop in runs:
        if stop - start < shortest:
            continue
        lo, hi = max(0, start - pad), min(len(a), stop + pad)
        amp = _amplitude(deltas[lo:hi], a[lo:hi])
        first, last = _plateau(amp)
        step = lambda i: np.interp(lo + i, np.arange(len(frames)), frames)  # noqa: E731  (fractional frames)
        holds.append(Hold(frames[start], frames[stop - 1], float(step(first)), float(step(last)),
                          float(np.percentile(a[start:stop], 95))))
    return tuple(holds)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _ramp_sums(amp, t, ramps, rising):
    """(p, q) per ramp (rows of ``ramps``: start, end): sum(r^2 - 1) and sum((r - 1) * amp) of the ramp r over
    ``t`` (rising 0 -> 1, else falling 1 -> 0). A trapezoid whose rise ends before its fall starts is min(rise,
    fall), so its sum of squares is ``len(t) + p_rise + p_fall`` and its product with ``amp`` is ``sum(amp) +
    q_rise + q_fall``: every pair of a rise and a fall is scored from its two rows."""
    x = _smoothstep((t[None] - ramps[:, :1]) / (ramps[:, 1:] - ramps[:, :1]))
    r = x if rising else 1.0 - x
    return (r * r - 1.0).sum(axis=1), (r - 1.0) @ amp


def _ramps(starts, ends, bounds):
    """(G, 2) every (start, end) of ``starts`` x ``ends`` at least a frame long, within ``bounds``."""
    s, e = (g.ravel() for g in np.meshgrid(starts, ends, indexing="ij"))
    keep = (e - s >= 1.0) & (s >= bounds[0]) & (e <= bounds[1])
    return np.stack([s[keep], e[keep]], axis=1)


def _best_pair(amp, t, rises, falls):
    """The (rise, fall) rows of the trapezoid A * min(rise, fall) (A > 0 by least squares; the rise ending before
    the fall starts) that explains most of ``amp``: the largest <m, amp>^2 / <m, m>. None when no pair fits;
    ties go to the first."""
    if len(rises) == 0 or len(falls) == 0:
        return None
    p_r, q_r = _ramp_sums(amp, t, rises, True)
    p_f, q_f = _ramp_sums(amp, t, falls, False)
    n, total = float(len(t)), float(amp.sum())
    best, where = -np.inf, None
    for lo in range(0, len(rises), 256):  # a block of rises against every fall
        num = total + q_r[lo:lo + 256, None] + q_f[None]
        den = n + p_r[lo:lo + 256, None] + p_f[None]
        ok = (rises[lo:lo + 256, 1:2] <= falls[None, :, 0]) & (num > 0) & (den > 0)
        explained = np.where(ok, num * num / np.where(ok, den, 1.0), -np.inf)
        i = int(np.argmax(explained))
        if explained.flat[i] > best:
            best, where = explained.flat[i], (lo + i // len(falls), i % len(falls))
    return None if where is None else (rises[where[0]], falls[where[1]])


def _plateau(amp):
    """(first, last) fractional indices of the held plateau of an excursion's amplitude curve ``amp``: the top of
    a trapezoid with smooth ramps, A * rise * fall, fitted by least squares to every frame (a threshold on a
    subtle pose's noisy curve would cut it anywhere), from ramps about the curve's half-maximum crossings.

    The fit is a pattern search on grids, not a local optimiser's steps: from the start, the best of 9 steps of
    each of the four ramp ends (every rise against every fall) until none is better, then steps a quarter as long,
    from ``PLATEAU_START`` of the start's ramp down to ``PLATEAU_STEP`` frames. It climbs to the optimum nearest
    the crossings, not the global one: on a noisy curve that is often a ramp as long as the excursion. Levenberg-
    Marquardt here moved the hold by up to 7 frames when the curve changed in its 13th digit, or when only its
    memory alignment did (its steps differ in the last bit), so a ROM's calibration was not reproducible from run
    to run; a grid's best changes only on an exact tie."""
    amp = np.asarray(amp, dtype=np.float64)
    n = len(amp)
    t = np.arange(n, dtype=np.float64)
    top = float(np.percentile(amp, 95))
    above = np.flatnonzero(_moving_mean(amp, 3) >= 0.5 * top)
    if top <= 0 or above.size == 0:
        return 0.0, float(n - 1)
    ramp = max(2.0, 0.1 * (above[-1] - above[0]))
    bounds = (-0.25 * n, 1.25 * (n - 1))  # a ramp may begin or end outside the excursion's frames
    best = (np.array([above[0] - 0.5 * ramp, above[0] + 0.5 * ramp]),
            np.array([above[-1] - 0.5 * ramp, above[-1] + 0.5 * ramp]))
    if best[0][1] > best[1][0]:  # an excursion too short for a plateau
        return float(above[0]), float(above[-1])
    k = np.arange(-4, 5)
    step = PLATEAU_START * ramp
    while step > PLATEAU_STEP:
        for _ in range(PLATEAU_CLIMB):
            (rs, re), (fs, fe) = best
            found = _best_pair(amp, t, _ramps(rs + k * step, re + k * step, bounds),
                               _ramps(fs + k * step, fe + k * step, bounds))
            if found is None or all(np.array_equal(a, b) for a, b in zip(found, best)):
                break
            best = found
        step /= 4.0
    first, last = float(best[0][1]), float(best[1][0])
    if not 0.0 <= first <= last <= n - 1:
        return float(above[0]), float(above[-1])
    return first, last


def _amplitude(deltas, level):
    """(F,) how much of the excursion's pattern each frame of ``deltas`` (F, M, 3) shows: the least-squares
    amplitude of the mean deltas over the frames of highest ``level`` (F,), over each frame's visible markers."""
    top = level >= np.percentile(level, 90)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        pattern = np.nan_to_num(np.nanmean(deltas[top], axis=0))
    seen = np.isfinite(deltas[:, :, 0])
    d = np.where(seen[:, :, None], deltas, 0.0)
    num = np.einsum("fmd,md->f", d, pattern)
    den = (seen * np.sum(pattern**2, axis=1)[None]).sum(axis=1)
    return np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)
