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


def _trapezoid(p, t):
    """A * rise * fall: ramps (smoothstep) starting at p[1] over p[2] frames and at p[3] over p[4] frames."""
    amp, r0, ru, f0, fd = p
    return amp * _smoothstep((t - r0) / ru) * (1.0 - _smoothstep((t - f0) / fd))


def _trapezoid_jacobian(p, t):
    """(T, 5) derivatives of ``_trapezoid`` by its parameters."""
    amp, r0, ru, f0, fd = p
    xr, xf = (t - r0) / ru, (t - f0) / fd
    rise, fall = _smoothstep(xr), 1.0 - _smoothstep(xf)
    dr = np.where((xr > 0) & (xr < 1), 6.0 * xr * (1.0 - xr), 0.0)  # the smoothstep's slope
    df = np.where((xf > 0) & (xf < 1), 6.0 * xf * (1.0 - xf), 0.0)
    return np.stack([rise * fall, -amp * fall * dr / ru, -amp * fall * dr * xr / ru,
                     amp * rise * df / fd, amp * rise * df * xf / fd], axis=1)


def _plateau(amp):
    """(first, last) fractional indices of the held plateau of an excursion's amplitude curve ``amp``: a
    trapezoid with smooth ramps fitted by least squares to every frame (its top is the hold; a threshold on a
    subtle pose's noisy curve would cut it anywhere), started from the curve's half-maximum crossings."""
    from scipy.optimize import least_squares  # scipy: loaded when a ROM take is read

    t = np.arange(len(amp), dtype=np.float64)
    top = float(np.percentile(amp, 95))
    above = np.flatnonzero(_moving_mean(amp, 3) >= 0.5 * top)
    if top <= 0 or above.size == 0:
        return 0.0, float(len(amp) - 1)
    ramp = max(2.0, 0.1 * (above[-1] - above[0]))
    # the ramps' lengths as logarithms (always positive); Levenberg-Marquardt with the analytic Jacobian
    start = np.array([top, above[0] - 0.5 * ramp, np.log(ramp), above[-1] - 0.5 * ramp, np.log(ramp)])
    unlog = lambda q: np.array([q[0], q[1], np.exp(q[2]), q[3], np.exp(q[4])])  # noqa: E731
    scale = lambda q: np.array([1.0, 1.0, np.exp(q[2]), 1.0, np.exp(q[4])])  # noqa: E731
    fit = least_squares(lambda q: _trapezoid(unlog(q), t) - amp, start, method="lm",
                        jac=lambda q: _trapezoid_jacobian(unlog(q), t) * scale(q))
    _, r0, ru, f0, _ = unlog(fit.x)
    first, last = r0 + ru, f0
    if not (fit.success and 0.0 <= first <= last <= len(amp) - 1):
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
