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
    # Moments sum_j w_{f+j} j^p for every frame, via shifted sums.
    pad_w = np.concatenate([np.zeros(half_window), w, np.zeros(half_window)])
    S = np.zeros((F, powers.size))
    count = np.zeros(F)
    for j in offsets:
        wj = pad_w[half_window + j : half_window + j + F]
        S += wj[:, None] * (float(j) ** powers)[None]
        count += wj > 0
    M = S[:, np.add.outer(np.arange(order + 1), np.arange(order + 1))]  # (F, p+1, p+1) Hankel
    ok = count >= order + 1
    # The fit's value at offset 0 is e0' M^-1 T with T_p = sum_j w_{f+j} j^p y_{f+j}, i.e. a
    # per-frame kernel k_f(j) = w_{f+j} sum_p (M^-1 e0)_p j^p applied to the window: one
    # right-hand side per frame instead of one per column (M is symmetric).
    e0 = np.zeros((int(ok.sum()), order + 1, 1))
    e0[:, 0] = 1.0
    x = np.zeros((F, order + 1))
    if ok.any():
        x[ok] = np.linalg.solve(M[ok] + 1e-12 * np.eye(order + 1), e0)[:, :, 0]
    pad_y = np.concatenate([np.zeros((half_window, y.shape[1])), y, np.zeros((half_window, y.shape[1]))])
    out = np.zeros_like(y)
    for j in offsets:
        kj = x[:, order].copy()
        for p in range(order - 1, -1, -1):  # Horner: sum_p x_p j^p
            kj *= j
            kj += x[:, p]
        kj *= pad_w[half_window + j : half_window + j + F]
        out += kj[:, None] * pad_y[half_window + j : half_window + j + F]
    out[~ok] = np.nan
    return out.reshape(values.shape)
