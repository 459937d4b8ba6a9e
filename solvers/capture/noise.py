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


#: A measured pose's delta at a marker is shrunk towards 0 below this many times the noise of the estimate
#: (soft: scaled by 1 - (tau/|delta|)^4, which leaves a delta twice tau within 7 %). A pose's median over a hold
#: carries the capture noise into every marker the pose does not move, and those small false motions blur the
#: shapes apart: a pose per shape onto the sample character, realism benchmark, draws 0-4: weights RMSE 0.078 ->
#: 0.057 (2.5: 0.057; 1 - (tau/|delta|)^2 at 1.5/2.5/4: 0.059/0.060/0.073); draws 5-9: 0.099 -> 0.077.
POSE_SHRINK = 2.0
#: The median's standard error over the mean's (for Gaussian noise): sqrt(pi / 2).
MEDIAN_ERROR = 1.2533


def shrink_pose_noise(deltas, pose_counts, neutral_counts, noise, *, factor=POSE_SHRINK):
    """``deltas`` (K, M, D) of poses measured as medians over ``pose_counts`` (K, M) samples minus a neutral
    over ``neutral_counts`` (M,) samples, with ``noise`` (RMS per coordinate and sample): each marker's delta
    shrunk softly towards 0 where it is within ``factor`` times its own standard error (no change when the
    noise is unknown or 0)."""
    if not (np.isfinite(noise) and noise > 0 and factor > 0):
        return deltas
    dims = deltas.shape[2]
    with np.errstate(divide="ignore"):
        var = 1.0 / np.maximum(pose_counts, 1) + 1.0 / np.maximum(np.asarray(neutral_counts)[None], 1)
    tau = factor * MEDIAN_ERROR * noise * np.sqrt(dims * var)
    size = np.linalg.norm(deltas, axis=2)
    ratio = np.minimum(tau / np.maximum(size, 1e-12), 2.0)  # 2: already 0 after the clip, no overflow
    keep = np.clip(1.0 - ratio**4, 0.0, 1.0)
    return deltas * keep[:, :, None]
