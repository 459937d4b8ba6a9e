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
    # Channel-major (C, F) layout throughout: a per-frame factor broadcast over a short channel
    # axis runs numpy's inner loop over a handful of elements per frame, ~3x slower than over
    # the frames. The arithmetic is the same, term for term.
    y = np.array(flat.T, order="C")
    if not np.isfinite(y).all():
        np.nan_to_num(y, copy=False)
    x, ok = _kernels(w, half_window, order)
    offsets = np.arange(-half_window, half_window + 1)
    pad_w = np.concatenate([np.zeros(half_window), w, np.zeros(half_window)])
    pad_y = np.concatenate([np.zeros((y.shape[0], half_window)), y, np.zeros((y.shape[0], half_window))], axis=1)
    out = np.zeros_like(y)
    term = np.empty_like(y)
    for j in offsets:
        kj = x[order].copy()
        for p in range(order - 1, -1, -1):  # Horner: sum_p x_p j^p
            kj *= j
            kj += x[p]
        kj *= pad_w[half_window + j : half_window + j + F]
        out += np.multiply(kj, pad_y[:, half_window + j : half_window + j + F], out=term)
    out[:, ~ok] = np.nan
    return np.ascontiguousarray(out.T).reshape(values.shape)


#: The last kernels computed (half_window, order, weights, kernels, ok): they depend on the weights
#: only, and the head smoothing runs once per refit with the same weights (the solve is ~half the cost).
_last = None


def _kernels(w, half_window, order):
    """Per-frame polynomial coefficients x (order + 1, F) of the smoothing kernel, and where the
    window holds enough weighted samples."""
    global _last
    last = _last
    if (last is not None and last[:2] == (half_window, order) and last[2].shape == w.shape
            and np.array_equal(last[2], w)):
        return last[3], last[4]
    F = w.size
    offsets = np.arange(-half_window, half_window + 1)
    powers = np.arange(2 * order + 1)
    # Moments sum_j w_{f+j} j^p for every frame, via shifted sums.
    pad_w = np.concatenate([np.zeros(half_window), w, np.zeros(half_window)])
    S = np.zeros((powers.size, F))
    count = np.zeros(F)
    for j in offsets:
        wj = pad_w[half_window + j : half_window + j + F]
        S += (float(j) ** powers)[:, None] * wj
        count += wj > 0
    M = S[np.add.outer(np.arange(order + 1), np.arange(order + 1))].transpose(2, 0, 1)  # (F, p+1, p+1) Hankel
    ok = count >= order + 1
    # The fit's value at offset 0 is e0' M^-1 T with T_p = sum_j w_{f+j} j^p y_{f+j}, i.e. a
    # per-frame kernel k_f(j) = w_{f+j} sum_p (M^-1 e0)_p j^p applied to the window: one
    # right-hand side per frame instead of one per column (M is symmetric).
    e0 = np.zeros((int(ok.sum()), order + 1, 1))
    e0[:, 0] = 1.0
    x = np.zeros((order + 1, F))
    if ok.any():
        x[:, ok] = np.linalg.solve(M[ok] + 1e-12 * np.eye(order + 1), e0)[:, :, 0].T
    x.flags.writeable = ok.flags.writeable = False
    _last = (half_window, order, w.copy(), x, ok)
    return x, ok


def penalised_fit(t, values, weights, lam):
    """The discrete cubic smoothing spline through weighted samples, at every ``t``: ``f`` minimising
    ``sum_i weights_i (values_i - f_i)^2 + lam * sum_j h_j (second divided difference of f at j)^2``.

    It is the penalty of a cubic smoothing spline (``lam`` times the integral of f''^2, as
    ``scipy.interpolate.make_smoothing_spline``'s ``lam``) on the grid ``t``: where weights are 0 (gaps)
    f is the cubic that joins its neighbours. One pentadiagonal solve (``scipy.linalg.solveh_banded``)
    for every column: the work grows linearly with ``len(t)``.

    Parameters
    ----------
    t : ndarray (N,), increasing
    values : ndarray (N, D); rows of weight 0 may hold anything (NaN)
    weights : ndarray (N,) of 0 or more; at least two rows of positive weight
    lam : float > 0

    Returns
    -------
    ndarray (N, D)
    """
    from scipy.linalg import solveh_banded  # scipy: loaded on first use (Clean Markers needs it anyway)

    t = np.asarray(t, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    y = np.where(w[:, None] > 0, np.asarray(values, dtype=np.float64).reshape(len(t), -1), 0.0)
    n = t.size
    h = np.diff(t)
    # second divided difference at interior node j+1: a f_j + b f_(j+1) + c f_(j+2), weight (h_j + h_(j+1)) / 2
    span = h[:-1] + h[1:]
    a, c = 2.0 / (h[:-1] * span), 2.0 / (h[1:] * span)
    b = -(a + c)
    s = lam * span / 2.0
    band = np.zeros((3, n))  # upper form: band[2] the diagonal, band[1] the first, band[0] the second superdiagonal
    band[2] = w
    for k, coef in enumerate((a, b, c)):
        band[2, k:k + n - 2] += s * coef * coef
    for k, (p, q) in enumerate(((a, b), (b, c))):
        band[1, k + 1:k + n - 1] += s * p * q
    band[0, 2:] = s * a * c
    return solveh_banded(band, w[:, None] * y, lower=False, check_finite=False)
