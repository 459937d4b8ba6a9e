"""``python -m facecap bench --clean``: spike removal and spline gap filling on long takes full of spikes.

The take: ``markers`` markers moving smoothly (a few mm, up to 1.5 Hz) with 0.1 mm noise, and a share of
samples (5 %) thrown off by 2-6 mm, as a marker swap or a reflection does. ``[clean] spike_mad = 3`` removes
them and ``fill_spline = 10`` fills the gaps left. Timed at 3,600 and 36,000 frames (the work must grow
with the take: about 10x), against the way the fill worked before: one scipy ``make_smoothing_spline``
per gap and axis (given the same smoothing weight, so without its per-gap GCV, which made it slower
still); that baseline is timed on ``BASELINE_MARKERS`` markers and scaled to all of them. Both fills are
compared with the truth (RMS error in mm).
"""

import time

import numpy as np

from ...capture.cleaning import CleanSettings, clean, gap_runs, remove_spikes
from ...markers import MarkerSet

FPS = 60.0
BASELINE_MARKERS = 1
#: The smoothing weight the baseline's splines are given (the middle of those the fill chooses from)
BASELINE_LAMBDA = 10.0


def spiky_take(frames, markers=20, spike_share=0.05, seed=0):
    """(MarkerSet with spikes, truth (F, M, 3), spike mask (F, M)) in mm."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / FPS
    latent = np.stack([np.sin(2 * np.pi * f * t + p) for f, p in zip(rng.uniform(0.2, 1.5, 5), rng.uniform(0, 6, 5))],
                      axis=1)
    truth = (latent @ (rng.normal(size=(5, markers * 3)) * 3)).reshape(frames, markers, 3)
    truth += rng.normal(size=(1, markers, 3)) * 30
    pos = truth + rng.normal(size=truth.shape) * 0.1
    spikes = rng.random((frames, markers)) < spike_share
    spikes[:3] = spikes[-3:] = False
    direction = rng.normal(size=(frames, markers, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    pos[spikes] += (direction * rng.uniform(2, 6, (frames, markers, 1)))[spikes]
    names = tuple(f"m{i}" for i in range(markers))
    return MarkerSet(names, np.arange(1, frames + 1), pos, fps=FPS, units="mm"), truth, spikes


def _rms(a, b):
    return float(np.sqrt(np.nanmean((a - b) ** 2)))


def per_gap_baseline(markers, lam, max_gap, count):
    """The former fill on the first ``count`` markers: a scipy spline per gap and axis. Returns
    (seconds, filled positions of those markers)."""
    from scipy.interpolate import make_smoothing_spline  # scipy: the baseline's own spline

    pos = markers.positions[:, :count].copy()
    t = markers.frames.astype(float)
    start = time.perf_counter()
    for m in range(count):
        vis = ~np.isnan(pos[:, m, 0])
        for a, b, interior in gap_runs(vis):
            if not interior or b - a > max_gap:
                continue
            context = max(3 * (b - a), 12)
            idx = np.concatenate([np.flatnonzero(vis[:a])[-context:], b + np.flatnonzero(vis[b:])[:context]])
            pos[a:b, m] = np.stack([make_smoothing_spline(t[idx], pos[idx, m, d], lam=lam)(t[a:b]) for d in range(3)],
                                   axis=1)
    return time.perf_counter() - start, pos


def bench_clean(frame_counts=(3600, 36000), markers=20, spike_share=0.05, repeat=3):
    """One row per take length (median of ``repeat`` runs): {"name", "seconds", "baseline_seconds",
    "ratio", "goal", "note"}."""
    rows = []
    settings = CleanSettings(spike_mad=3.0, fill_spline=10)
    first = None
    for frames in frame_counts:
        take, truth, spikes = spiky_take(frames, markers, spike_share)
        times = []
        for _ in range(repeat):
            start = time.perf_counter()
            cleaned = clean(take, settings).markers
            times.append(time.perf_counter() - start)
        seconds = float(np.median(times))
        first = first or (frames, seconds)
        despiked, _ = remove_spikes(take, mad=settings.spike_mad)
        base_seconds, base = per_gap_baseline(despiked, BASELINE_LAMBDA, settings.fill_spline, BASELINE_MARKERS)
        base_seconds *= markers / BASELINE_MARKERS
        caught = np.isnan(despiked.positions[:, :, 0]) & spikes
        ours = _rms(cleaned.positions[:, :BASELINE_MARKERS][caught[:, :BASELINE_MARKERS]],
                    truth[:, :BASELINE_MARKERS][caught[:, :BASELINE_MARKERS]])
        theirs = _rms(base[caught[:, :BASELINE_MARKERS]], truth[:, :BASELINE_MARKERS][caught[:, :BASELINE_MARKERS]])
        growth = seconds / first[1] if frames != first[0] else 1.0
        rows.append({
            "name": f"clean: spikes + spline fill, {frames:,} frames x {markers} markers, {spike_share:.0%} spikes",
            "seconds": seconds, "baseline_seconds": base_seconds, "ratio": base_seconds / seconds,
            "goal": "work grows with the take (10x the frames: about 10x the time), not with the gaps",
            "note": (f"{int(caught.sum())} spikes removed and filled; fill RMS error {ours:.3f} mm (per-gap splines "
                     f"{theirs:.3f} mm); {growth:.1f}x the time of {first[0]:,} frames; baseline timed on "
                     f"{BASELINE_MARKERS} marker, scaled"),
        })
    return rows
