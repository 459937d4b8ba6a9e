"""How a solve compares with the truth, per face region: weights RMSE, mean per-shape correlation (a shape the
solve holds at rest counts as 0; ``r_moved`` leaves those out), the share of weights at the upper bound, and
jitter (RMS second difference), each beside the truth's own."""

import numpy as np

#: Face regions by ARKit name prefix (first match wins).
REGIONS = (
    ("brows", ("brow",)),
    ("gaze", ("eyeLook",)),
    ("lids", ("eyeBlink", "eyeSquint", "eyeWide")),
    ("cheeks/nose", ("cheek", "noseSneer")),
    ("jaw", ("jaw",)),
    ("mouth", ("mouth", "tongue")),
)
#: A shape whose truth varies less than this (standard deviation) has no meaningful correlation.
MIN_STD = 0.02


def region_of(name):
    for region, prefixes in REGIONS:
        if name.startswith(prefixes):
            return region
    return "other"


def _stats(w, t, upper):
    """Metrics of solved ``w`` against truth ``t`` (F, K); ``upper`` (K,) the solve's upper bounds."""
    err = np.nan_to_num(w, nan=0.0) - t
    rs, moved = [], []
    for k in range(t.shape[1]):
        if t[:, k].std() >= MIN_STD:
            wk = np.nan_to_num(w[:, k])
            rs.append(0.0 if wk.std() < 1e-9 else float(np.corrcoef(wk, t[:, k])[0, 1]))
            if wk.std() >= 1e-9:
                moved.append(rs[-1])
    jitter = float(np.sqrt(np.mean(np.diff(np.nan_to_num(w), 2, axis=0) ** 2))) if len(w) > 2 else 0.0
    return {
        "rmse": float(np.sqrt(np.mean(err**2))),
        "r": float(np.mean(rs)) if rs else float("nan"),  # a shape held at rest counts as r = 0
        "r_moved": float(np.mean(moved)) if moved else float("nan"),  # over the shapes the solve moves
        "at_upper": float(np.mean(np.nan_to_num(w) >= upper[None] - 1e-3)),
        "jitter": jitter,
        "truth_jitter": float(np.sqrt(np.mean(np.diff(t, 2, axis=0) ** 2))) if len(t) > 2 else 0.0,
    }


def compare(weights, names, truth, truth_names, *, upper=None, frames=None):
    """Per-region and overall metrics of ``weights`` (F, K) named ``names`` against ``truth`` (F, S) named
    ``truth_names``, over the truth's shapes (a shape the solve lacks counts as 0) and ``frames`` (bool (F,)).

    Returns {"all": {...}, "<region>": {...}, ...}."""
    index = {n: i for i, n in enumerate(names)}
    F = truth.shape[0]
    w = np.zeros((F, len(truth_names)))
    up = np.ones(len(truth_names))
    for s, n in enumerate(truth_names):
        if n in index:
            w[:, s] = weights[:, index[n]]
            if upper is not None:
                up[s] = upper[index[n]]
    sel = np.ones(F, dtype=bool) if frames is None else np.asarray(frames, dtype=bool)
    w, t = w[sel], truth[sel]
    out = {"all": _stats(w, t, up)}
    regions = np.array([region_of(n) for n in truth_names])
    for region, _ in REGIONS:
        cols = regions == region
        if cols.any():
            out[region] = _stats(w[:, cols], t[:, cols], up[cols])
    out["all"]["truth_at_upper"] = float(np.mean(t >= 1.0 - 1e-3))
    return out
