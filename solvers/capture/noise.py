"""The markers' own noise, estimated from a take: what a fit residual is judged against."""

import warnings

import numpy as np

#: The estimate reads at most this many blocks of ``BLOCK`` frames, spread over the take (a long take's
#: noise is the same everywhere, and its whole second difference would be a copy of the take).
BLOCKS, BLOCK = 10, 2000


def marker_noise(deltas):
    """The markers' noise (metres RMS per coordinate) of stabilised deltas (F, M, D), robustly: the median over
    markers of the RMS second difference divided by sqrt(6) (white noise's second difference has 6 times its
    variance, and a face moves little from one frame to the next at 60 fps); NaN when the take is too short."""
    if deltas is None or deltas.shape[0] < 5:
        return float("nan")
    F = deltas.shape[0]
    starts = np.unique(np.linspace(0, max(F - BLOCK, 0), min(BLOCKS, -(-F // BLOCK))).astype(int))
    total = np.zeros(deltas.shape[1])
    count = np.zeros(deltas.shape[1])
    for a in starts:
        d2 = np.diff(deltas[a : a + BLOCK], 2, axis=0) ** 2
        ok = np.isfinite(d2)
        total += np.where(ok, d2, 0.0).sum(axis=(0, 2))
        count += ok.sum(axis=(0, 2))
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        per = np.sqrt(total / count / 6.0)
    per = per[np.isfinite(per)]
    return float(np.median(per)) if per.size else float("nan")
