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
#: The plateau fit's ramp grid: steps across the excursion at first, the finest step (frames), rounds at most.
PLATEAU_GRID, PLATEAU_STEP, PLATEAU_ROUNDS = 60, 1.0 / 32, 6


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


def _ramp(t, ramp, rising):
    """A smooth ramp over ``t`` from ``ramp[0]`` to ``ramp[1]``: 0 -> 1 when ``rising``, else 1 -> 0."""
    x = _smoothstep((t - ramp[0]) / (ramp[1] - ramp[0]))
    return x if rising else 1.0 - x


def _best_ramp(amp, t, other, bounds, rising, step, around=None):
    """The ramp (start, end), on a grid of ``step`` frames within ``bounds`` (or 9 x 9 steps ``around`` a ramp),
    that best fits ``amp`` as A * ramp * ``other`` (A > 0 by least squares): the largest explained share
    <m, amp>^2 / <m, m>. Ramps are at least a frame long; ties go to the first on the grid."""
    lo, hi = bounds
    if around is None:
        s, e = np.meshgrid(np.arange(lo, hi + 0.5 * step, step), np.arange(lo, hi + 0.5 * step, step),
                           indexing="ij")
    else:
        k = np.arange(-4, 5) * step
        s, e = np.meshgrid(around[0] + k, around[1] + k, indexing="ij")
    s, e = s.ravel(), e.ravel()
    keep = (e - s >= 1.0) & (s >= lo) & (e <= hi)
    s, e = s[keep], e[keep]
    if s.size == 0:
        return around
    x = _smoothstep((t[None] - s[:, None]) / (e - s)[:, None])
    m = (x if rising else 1.0 - x) * other[None]
    mm, my = np.einsum("gt,gt->g", m, m), m @ amp
    explained = np.where((mm > 0) & (my > 0), my * my / np.maximum(mm, 1e-300), -np.inf)
    i = int(np.argmax(explained))
    return float(s[i]), float(e[i])


def _fit_ramp(amp, t, other, bounds, rising):
    """``_best_ramp`` coarse to fine: ~``PLATEAU_GRID`` steps across ``bounds``, then each step a quarter of the
    last about the best, down to ``PLATEAU_STEP`` frames."""
    step = max(0.25, (bounds[1] - bounds[0]) / PLATEAU_GRID)
    best = _best_ramp(amp, t, other, bounds, rising, step)
    while best is not None and step > PLATEAU_STEP:
        step /= 4.0
        best = _best_ramp(amp, t, other, bounds, rising, step, around=best)
    return best


def _plateau(amp):
    """(first, last) fractional indices of the held plateau of an excursion's amplitude curve ``amp``: the top of
    a trapezoid with smooth ramps, A * rise * fall, fitted by least squares to every frame (a threshold on a
    subtle pose's noisy curve would cut it anywhere), started from the curve's half-maximum crossings.

    The ramps are searched on grids (each given the other, until neither moves), not by a local optimiser:
    Levenberg-Marquardt here moved the hold by up to 7 frames when the curve changed in its 13th digit, or when
    only its memory alignment did (its steps differ in the last bit), so a ROM's calibration was not
    reproducible from run to run. A grid's best changes only on an exact tie."""
    amp = np.asarray(amp, dtype=np.float64)
    n = len(amp)
    t = np.arange(n, dtype=np.float64)
    top = float(np.percentile(amp, 95))
    above = np.flatnonzero(_moving_mean(amp, 3) >= 0.5 * top)
    if top <= 0 or above.size == 0:
        return 0.0, float(n - 1)
    ramp = max(2.0, 0.1 * (above[-1] - above[0]))
    rise = (above[0] - 0.5 * ramp, above[0] + 0.5 * ramp)
    fall = (above[-1] - 0.5 * ramp, above[-1] + 0.5 * ramp)
    lo, hi = -0.25 * n, 1.25 * (n - 1)  # a ramp may begin or end outside the excursion's frames
    for _ in range(PLATEAU_ROUNDS):
        new_rise = _fit_ramp(amp, t, _ramp(t, fall, False), (lo, fall[0]), True)
        new_fall = None if new_rise is None else _fit_ramp(amp, t, _ramp(t, new_rise, True), (new_rise[1], hi),
                                                           False)
        if new_fall is None or (new_rise, new_fall) == (rise, fall):
            break
        rise, fall = new_rise, new_fall
    first, last = rise[1], fall[0]
    if not 0.0 <= first <= last <= n - 1:
        return float(above[0]), float(above[-1])
    return float(first), float(last)


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
