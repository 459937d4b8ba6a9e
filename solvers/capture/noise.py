"""The markers' own noise, estimated from a take: what a fit residual is judged against."""

import numpy as np


def marker_noise(deltas):
    """The markers' noise (metres RMS per coordinate) of stabilised deltas (F, M, D), robustly: the median over
    markers of the RMS second difference divided by sqrt(6) (white noise's second difference has 6 times its
    variance, and a face moves little from one frame to the next at 60 fps); NaN when the take is too short."""
    if deltas is None or deltas.shape[0] < 5:
        return float("nan")
    d2 = np.diff(deltas, 2, axis=0)
    with np.errstate(invalid="ignore"), np.testing.suppress_warnings() as sup:
        sup.filter(RuntimeWarning)
        per = np.sqrt(np.nanmean(d2**2, axis=(0, 2)) / 6.0)
    per = per[np.isfinite(per)]
    return float(np.median(per)) if per.size else float("nan")
