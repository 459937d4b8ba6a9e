"""Cleaning: gap fills against synthetic ground truth, spikes, swaps, filters, and reports."""

import numpy as np
import pytest

from facecap.solvers import FacecapError, MarkerSet
from facecap.solvers.capture.cleaning import (CleanSettings, clean, fill_gaps_model, fill_gaps_spline, fix_swaps,
                                      lowpass, one_euro, remove_spikes)

SIGMA = 0.1  # mm of marker noise
FPS = 60.0


def face_take(frames=1200, markers=20, rank=5, seed=1):
    """Low-rank 'expressions' (smooth latent signals up to 1.5 Hz, ~5 mm) on a 30 mm layout, plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / FPS
    latent = np.stack([np.sin(2 * np.pi * f * t + p)
                       for f, p in zip(rng.uniform(0.2, 1.5, rank), rng.uniform(0, 6, rank))], axis=1)
    truth = (latent @ (rng.normal(size=(rank, markers * 3)) * 3)).reshape(frames, markers, 3)
    truth += rng.normal(size=(1, markers, 3)) * 30
    noisy = truth + rng.normal(size=truth.shape) * SIGMA
    return truth, noisy, rng


def as_set(pos):
    return MarkerSet(tuple(f"m{i}" for i in range(pos.shape[1])), np.arange(1, pos.shape[0] + 1), pos,
                     fps=FPS, units="mm")


def test_short_gaps_filled_by_spline_within_two_sigma():
    truth, noisy, rng = face_take()
    pos = noisy.copy()
    gaps = []
    for length in range(1, 11):
        for _ in range(4):
            m, a = int(rng.integers(20)), int(rng.integers(40, 1140))
            while np.isnan(pos[a - 30:a + length + 30, m]).any():
                m, a = int(rng.integers(20)), int(rng.integers(40, 1140))
            pos[a:a + length, m] = np.nan
            gaps.append((m, a, length))
    out, report = fill_gaps_spline(as_set(pos), max_gap=10)
    assert report.total == sum(g[2] for g in gaps)
    assert not np.isnan(out.positions).any()
    for length in range(1, 11):
        err = np.concatenate([(out.positions[a:a + n, m] - truth[a:a + n, m]).ravel()
                              for m, a, n in gaps if n == length])
        assert np.sqrt(np.mean(err ** 2)) < 2 * SIGMA, length


def test_spline_fill_matches_scipys_smoothing_spline_on_a_lone_gap():
    """The fill is the cubic smoothing spline (discrete, on the take's frames): on a lone gap it agrees
    with scipy's make_smoothing_spline through the same context frames with the same weight, to well
    under the marker noise."""
    from scipy.interpolate import make_smoothing_spline

    from facecap.solvers.capture.cleaning import _choose_smoothing  # noqa: the weight both fits use

    _, noisy, _ = face_take(frames=600, markers=3)
    pos = noisy.copy()
    pos[300:306, 1] = np.nan
    out, report = fill_gaps_spline(as_set(pos), max_gap=8)
    assert report.total == 6
    t = np.arange(1, 601, dtype=float)
    vis = ~np.isnan(pos[:, 1, 0])
    lam = _choose_smoothing(t, pos[:, 1], vis)
    context = np.r_[np.arange(300 - 18, 300), np.arange(306, 306 + 18)]
    reference = np.stack([make_smoothing_spline(t[context], pos[context, 1, d], lam=lam)(t[300:306])
                          for d in range(3)], axis=1)
    np.testing.assert_allclose(out.positions[300:306, 1], reference, atol=0.2 * SIGMA)


def test_spline_fill_of_many_gaps_grows_with_the_take_not_the_gaps():
    """Spikes removed every few frames (thousands of one-frame gaps) are filled through shared fits:
    the result stays within two sigma of the truth (the regression: one spline with GCV per gap took
    280 s on a 600-frame take)."""
    truth, noisy, rng = face_take(frames=1200, markers=4)
    pos = noisy.copy()
    hit = rng.random(pos.shape[:2]) < 0.15
    hit[:5] = hit[-5:] = False
    pos[hit] = np.nan
    out, report = fill_gaps_spline(as_set(pos), max_gap=10)
    assert report.total == int(hit.sum()) and not np.isnan(out.positions).any()
    err = out.positions[hit] - truth[hit]
    assert np.sqrt(np.mean(err ** 2)) < 2 * SIGMA


def test_long_gaps_reconstructed_from_other_markers_within_three_sigma():
    truth, noisy, rng = face_take()
    pos = noisy.copy()
    gaps = [(3, 100, 60), (7, 400, 120), (11, 700, 200), (3, 1000, 150)]
    for m, a, n in gaps:
        pos[a:a + n, m] = np.nan
    out, report = fill_gaps_model(as_set(pos), max_gap=200)
    assert report.counts["m3"] == 210 and report.counts["m7"] == 120 and report.counts["m11"] == 200
    for m, a, n in gaps:
        rms = np.sqrt(np.mean((out.positions[a:a + n, m] - truth[a:a + n, m]) ** 2))
        assert rms < 3 * SIGMA, (m, a, n, rms / SIGMA)


def test_gaps_longer_than_the_limit_and_edge_gaps_stay():
    _, noisy, _ = face_take(frames=300)
    pos = noisy.copy()
    pos[100:150, 0] = np.nan  # longer than the limits
    pos[:5, 1] = np.nan  # leading: never extrapolated
    result = clean(as_set(pos), CleanSettings(fill_spline=10, fill_model=40))
    assert np.isnan(result.markers.positions[100:150, 0]).all()
    assert np.isnan(result.markers.positions[:5, 1]).all()
    assert [s.total for s in result.report.steps] == [0, 0]


def test_spikes_removed_by_speed_and_mad_then_filled():
    truth, noisy, _ = face_take(frames=600)
    pos = noisy.copy()
    pos[200, 4] += [30.0, 0, 0]  # 30 mm in one frame = 1.8 m/s, faster than any face moves
    pos[300, 9] += [0, 1.5, 0]   # small, only the MAD test sees it
    settings = CleanSettings(spike_speed=1000.0, spike_mad=8.0, fill_spline=5)
    result = clean(as_set(pos), settings)
    spikes = result.report.steps[0]
    assert spikes.counts["m4"] >= 1 and spikes.counts["m9"] >= 1
    assert spikes.total <= 4
    assert np.abs(result.markers.positions[200, 4] - truth[200, 4]).max() < 3 * SIGMA
    assert np.abs(result.markers.positions[300, 9] - truth[300, 9]).max() < 3 * SIGMA


def test_label_swap_between_neighbours_is_undone():
    _, noisy, _ = face_take(frames=300)
    pos = noisy.copy()
    pos[:, 6] = pos[:, 5] + [4.0, 0.0, 0.0] + 0.1 * (pos[:, 6] - pos[:, 6].mean(axis=0))  # a close neighbour
    swapped = pos.copy()
    swapped[120:180, [5, 6]] = swapped[120:180, [6, 5]]
    out, report = fix_swaps(as_set(swapped))
    np.testing.assert_allclose(out.positions, pos)
    assert report.counts["m5"] == 60 and report.counts["m6"] == 60
    assert fix_swaps(as_set(pos))[1].total == 0


def test_lowpass_returns_what_it_removed():
    truth, noisy, _ = face_take(frames=600)
    out, removed, report = lowpass(as_set(noisy), cutoff_hz=6.0)
    np.testing.assert_allclose(out.positions + removed, noisy)
    assert np.sqrt(np.mean((out.positions - truth) ** 2)) < 0.6 * SIGMA
    assert np.std(removed) == pytest.approx(SIGMA, rel=0.2)
    with pytest.raises(FacecapError, match="cutoff_hz"):
        lowpass(as_set(noisy), cutoff_hz=40.0)


def test_lowpass_keeps_gaps_and_filters_runs_separately():
    _, noisy, _ = face_take(frames=400)
    pos = noisy.copy()
    pos[200:210, 2] = np.nan
    pos[5:8, 3] = np.nan  # leaves a 5-frame run too short to filter
    result = clean(as_set(pos), CleanSettings(lowpass_hz=8.0))
    assert np.isnan(result.markers.positions[200:210, 2]).all()
    assert "1 run(s) shorter than 16 frames left unfiltered" in result.report.steps[0].message
    assert result.removed.shape == pos.shape


def test_one_euro_smooths_a_still_marker_and_follows_motion():
    rng = np.random.default_rng(0)
    pos = np.zeros((600, 1, 3))
    pos[300:, 0, 0] = np.linspace(0, 50, 300)
    noisy = pos + rng.normal(size=pos.shape) * SIGMA
    out, removed, _ = one_euro(as_set(noisy), 1.0, 0.05, 1.0)
    still = out.positions[50:300, 0] - pos[50:300, 0]
    assert np.std(still) < 0.5 * SIGMA
    assert np.abs(out.positions[-1, 0, 0] - 50) < 2.0
    np.testing.assert_allclose(out.positions + removed, noisy)


def test_report_summary_and_settings_validation():
    _, noisy, _ = face_take(frames=200)
    pos = noisy.copy()
    pos[50:53, 1] = np.nan
    result = clean(as_set(pos), CleanSettings(fill_spline=5))
    assert result.report.summary().startswith("fill_spline: 3 sample(s) (m1 3)")
    for bad in ({"lowpass_hz": -1}, {"fill_spline": 2.5}, {"lowpass_hz": 5, "one_euro": (1, 0, 1)},
                {"swap_ratio": 2}, {"one_euro": (0, 0, 1)}):
        with pytest.raises(FacecapError):
            CleanSettings(**bad)
    assert remove_spikes(as_set(noisy))[1].total == 0
