"""Zero-phase local polynomial smoothing (Savitzky-Golay with gaps), numpy only."""

import numpy as np


def local_polynomial(values, *, half_window, order=3, weights=None):
    """Smooth along axis 0 by a weighted least-squares polynomial fit in a sliding window.

    With all weights 1 this is the Savitzky-Golay filter (zero phase, keeps peaks of polynomial
    shape of degree ``order``); weights of 0 (gaps, flagged frames) are ignored, and the
    window shrinks at the ends of the take instead of padding.

    Parameters
    ----------
    values : ndarray, shape (F, ...)
        NaN samples are treated as weight 0.
    half_window : int
        Frames on each side (window = 2 * half_window + 1). 0 returns the input.
    order : int
        Polynomial degree.
    weights : ndarray, shape (F,), optional

    Returns
    -------
    ndarray like ``values``; NaN where a window holds fewer than ``order + 1`` weighted samples.
    """
    values = np.asarray(values, dtype=np.float64)
    if half_window <= 0:
        return values.copy()
    F = values.shape[0]
    flat = values.reshape(F, -1)
    w = np.ones(F) if weights is None else np.asarray(weights, dtype=np.float64).copy()
    w = np.where(np.isnan(flat).any(axis=1), 0.0, w)
    y = np.nan_to_num(flat)
    offsets = np.arange(-half_window, half_window + 1)
    powers = np.arange(2 * order + 1)
    # Moments sum_j w_{f+j} j^p and sum_j w_{f+j} j^p y_{f+j}, for every frame, via shifted sums.
    pad_w = np.concatenate([np.zeros(half_window), w, np.zeros(half_window)])
    pad_y = np.concatenate([np.zeros((half_window, y.shape[1])), y, np.zeros((half_window, y.shape[1]))])
    S = np.zeros((F, powers.size))
    T = np.zeros((F, order + 1, y.shape[1]))
    for j in offsets:
        wj = pad_w[half_window + j : half_window + j + F]
        yj = pad_y[half_window + j : half_window + j + F]
        jp = float(j) ** powers
        S += wj[:, None] * jp[None]
        T += (wj[:, None] * jp[None, : order + 1])[:, :, None] * yj[:, None, :]
    M = S[:, np.add.outer(np.arange(order + 1), np.arange(order + 1))]  # (F, p+1, p+1) Hankel
    count = np.zeros(F)
    for j in offsets:
        count += pad_w[half_window + j : half_window + j + F] > 0
    ok = count >= order + 1
    out = np.full_like(y, np.nan)
    if ok.any():
        coef = np.linalg.solve(M[ok] + 1e-12 * np.eye(order + 1), T[ok])  # (n, p+1, C)
        out[ok] = coef[:, 0, :]  # the polynomial's value at offset 0
    return out.reshape(values.shape)
