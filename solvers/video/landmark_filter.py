"""Temporal filtering of detected landmarks: the detector's frame-to-frame jitter out, fast lip motion in.

A face detector places each frame's points independently, so a still face jitters by a fraction of
a pixel; smoothing it with a fixed low-pass also blunts a lip closure that takes 50 ms. The whole
take is known, so the filter is zero-lag and adapts per point and frame:

* local quadratic regression with Gaussian weights (peaks and turning points are kept, a plain
  moving average would flatten them) at a few widths, from ``min_width`` to ``max_width`` seconds;
* each point's noise from its own residual at the narrowest width (median absolute deviation);
* per point and frame, the width falls as the point's speed rises above its noise
  (``width = max_width / (1 + speed / (knee * noise))``): still points are smoothed hard, moving
  lips barely.

Frames without a face (NaN) split the take: no point is smoothed across a gap.
"""

import numpy as np

#: Default widths (Gaussian sigma, seconds) and the speed knee (noise units per frame).
MIN_WIDTH, MAX_WIDTH, KNEE = 0.02, 0.12, 1.0


def _fits(x, valid, sigma):
    """Local quadratic fits at every frame with Gaussian weights of ``sigma`` frames over the valid
    frames of ``x`` (F, N) (fewer neighbours near the ends): (value (F, N), slope per frame (F, N))."""
    from scipy.ndimage import correlate1d  # scipy: loaded with the filter only

    half = max(1, int(np.ceil(3 * sigma)))
    k = np.arange(-half, half + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / sigma) ** 2)
    v = valid.astype(np.float64)
    xv = np.where(valid[:, None], x, 0.0)
    # weight moments S_j = sum w k^j over valid neighbours, data moments T_j = sum w k^j x
    S = [correlate1d(v, w * k**j, mode="constant") for j in range(5)]
    T = [correlate1d(xv, w * k**j, axis=0, mode="constant") for j in range(3)]
    A = np.stack([np.stack([S[i + j] for j in range(3)], -1) for i in range(3)], -2)  # (F, 3, 3)
    A = A + np.eye(3) * 1e-9 * np.maximum(S[0], 1.0)[:, None, None]
    inv = np.linalg.pinv(A)  # a frame with few neighbours (an edge, beside a gap) stays solvable
    value = inv[:, 0, 0, None] * T[0] + inv[:, 0, 1, None] * T[1] + inv[:, 0, 2, None] * T[2]
    slope = inv[:, 1, 0, None] * T[0] + inv[:, 1, 1, None] * T[1] + inv[:, 1, 2, None] * T[2]
    return value, slope


def smooth_landmarks(positions, fps, *, min_width=MIN_WIDTH, max_width=MAX_WIDTH, knee=KNEE, levels=5):
    """Zero-lag, speed-adaptive smoothing of landmark tracks.

    Parameters
    ----------
    positions : array (F, M, D), NaN for frames without a face
    fps : float, frames per second (widths are in seconds)
    min_width, max_width : float
        The narrowest and widest Gaussian sigma, seconds.
    knee : float
        Speed (in units of the point's own noise per frame) at which the width has halved.
    levels : int
        Widths computed between the two (geometric steps); each sample interpolates between two.

    Returns
    -------
    array (F, M, D), the same gaps
    """
    positions = np.asarray(positions, dtype=np.float64)
    F, M, D = positions.shape
    out = np.full_like(positions, np.nan)
    valid = np.isfinite(positions).all(axis=(1, 2))
    edges = np.flatnonzero(np.diff(np.r_[0, valid.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):  # each run of frames with a face on its own
        out[a:b] = _smooth_run(positions[a:b].reshape(b - a, M * D), fps, min_width, max_width, knee,
                               levels).reshape(b - a, M, D)
    return out


def _smooth_run(x, fps, min_width, max_width, knee, levels):
    """:func:`smooth_landmarks` on (F, N) frames that all have a face."""
    F = len(x)
    if F < 3:
        return x.copy()
    valid = np.ones(F, bool)
    sigmas = np.geomspace(max(min_width * fps, 0.5), max(max_width * fps, 0.5), int(levels))
    fits = [_fits(x, valid, s) for s in sigmas]
    base = fits[0][0]
    noise = 1.4826 * np.median(np.abs(x - base), axis=0) * np.sqrt(3.0)  # the fit absorbs part of it
    noise = np.maximum(noise, 1e-6 * max(float(np.max(noise)), 1e-6))
    slope = fits[len(fits) // 2][1]  # speed from a middle width: the narrowest one's slope is mostly noise
    speed = np.abs(slope) / (knee * noise)
    want = np.clip(sigmas[-1] / (1.0 + speed), sigmas[0], sigmas[-1])
    pos = np.interp(np.log(want), np.log(sigmas), np.arange(len(sigmas)))  # fractional level
    lo = np.minimum(pos.astype(int), len(sigmas) - 2)
    frac = pos - lo
    values = np.stack([v for v, _ in fits])  # (L, F, N)
    rows, cols = np.indices(lo.shape)
    return (1 - frac) * values[lo, rows, cols] + frac * values[lo + 1, rows, cols]
