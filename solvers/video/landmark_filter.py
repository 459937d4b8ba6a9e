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


def _kernel(sigma, half, before, after):
    """(value, slope) weights over the offsets -half..half of a local quadratic fit with Gaussian
    weights, when only ``before`` frames before and ``after`` after the frame exist."""
    k = np.arange(-half, half + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / sigma) ** 2) * ((k >= -before) & (k <= after))
    basis = np.stack([w, w * k, w * k * k])  # (3, 2h+1)
    inv = np.linalg.pinv(basis @ np.stack([np.ones_like(k), k, k * k]).T)  # a 1-2 frame run stays solvable
    return inv[0] @ basis, inv[1] @ basis


def _fit(x, sigma, want_slope=False):
    """Local quadratic fits of the rows of ``x`` (N, F) (frames along the last axis, all valid):
    (value (N, F), slope per frame (N, F) or None). One correlation for the interior; the frames
    within the kernel's reach of an end (fewer neighbours) are fitted on their own."""
    from scipy.ndimage import correlate1d  # scipy: loaded with the filter only

    n = x.shape[1]
    half = max(1, int(np.ceil(3 * sigma)))
    kinds = (0, 1) if want_slope else (0,)
    inner = _kernel(sigma, half, half, half)
    outs = [correlate1d(x, inner[i], axis=-1, mode="constant") for i in kinds]
    offsets = np.arange(-half, half + 1)
    for t in sorted(set(range(min(half, n))) | set(range(max(n - half, 0), n))):
        kernels = _kernel(sigma, half, t, n - 1 - t)
        idx = t + offsets
        ok = (idx >= 0) & (idx < n)
        for out, i in zip(outs, kinds):
            out[:, t] = x[:, idx[ok]] @ kernels[i][ok]
    return outs[0], (outs[1] if want_slope else None)


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
        tracks = np.ascontiguousarray(positions[a:b].reshape(b - a, M * D).T)  # (N, F): frames contiguous
        out[a:b] = _smooth_run(tracks, fps, min_width, max_width, knee, levels).T.reshape(b - a, M, D)
    return out


def _smooth_run(x, fps, min_width, max_width, knee, levels):
    """:func:`smooth_landmarks` on (N, F) tracks (frames along the last axis) that all have a face."""
    if x.shape[1] < 3:
        return x.copy()
    sigmas = np.geomspace(max(min_width * fps, 0.5), max(max_width * fps, 0.5), int(levels))
    base = _fit(x, sigmas[0])[0]
    noise = 1.4826 * np.median(np.abs(x - base), axis=1, keepdims=True) * np.sqrt(3.0)  # the fit absorbs part
    noise = np.maximum(noise, 1e-6 * max(float(np.max(noise)), 1e-6))
    middle = len(sigmas) // 2  # speed from a middle width: the narrowest one's slope is mostly noise
    slope = _fit(x, sigmas[middle], want_slope=True)[1]
    want = np.clip(sigmas[-1] / (1.0 + np.abs(slope) / (knee * noise)), sigmas[0], sigmas[-1])
    del slope
    level = np.interp(np.log(want), np.log(sigmas), np.arange(len(sigmas)))  # fractional level per sample
    del want
    out = np.zeros_like(x)
    for i, sigma in enumerate(sigmas):  # each sample blends its two nearest levels (hat weights)
        weight = np.clip(1.0 - np.abs(level - i), 0.0, 1.0)
        if weight.any():
            out += weight * (base if i == 0 else _fit(x, sigma)[0])
    return out
