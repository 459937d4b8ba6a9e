"""The speed paths of stabilisation give the same numbers, bit for bit, as the plain code they replace.

Deferred stabilised markers, refine_rigid's in-place fit cleaning, the cached smoothing kernels,
the channel-major smoothing loop, the length-3 norm and unit conversion without re-validation.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecap.solvers import MarkerSet, fit_rigid_batch, stabilise_rigid
from facecap.solvers.capture import smoothing
from facecap.solvers.capture.stabilise import _apply, _norm3, refine_rigid, smooth_head_motion
from facecap.solvers.transforms import zero_rows

RNG = np.random.default_rng(5)
STABLE = ("s0", "s1", "s2", "s3", "s4")


def _take(F=400, M=12, gaps=0.05):
    """Rigid head motion of a face whose last markers deform, with whole-sample gaps."""
    face = RNG.normal(0, 0.05, (M, 3))
    pos = np.broadcast_to(face, (F, M, 3)).copy()
    pos[:, len(STABLE):] += RNG.normal(0, 0.002, (F, M - len(STABLE), 3))
    R = Rotation.from_rotvec(RNG.normal(0, 0.1, (F, 3))).as_matrix()
    pos = pos @ R.transpose(0, 2, 1) + RNG.normal(0, 0.01, (F, 1, 3))
    pos[RNG.uniform(size=(F, M)) < gaps] = np.nan
    names = STABLE + tuple(f"m{i}" for i in range(M - len(STABLE)))
    return MarkerSet(names=names, frames=np.arange(1, F + 1), positions=pos * 1000.0, units="mm")


@pytest.mark.parametrize("mode", ["rigid", "similarity"])
def test_deferred_markers_are_the_applied_head_poses(mode):
    markers = _take()
    stab = stabilise_rigid(markers, STABLE, mode=mode)
    expect = markers.positions @ stab.rotations.transpose(0, 2, 1)
    if stab.scales is not None:
        expect *= stab.scales[:, None, None]
    expect += stab.translations[:, None, :]
    expect[stab.flagged] = np.nan
    assert np.array_equal(stab.markers.positions, expect, equal_nan=True)
    assert stab.markers is stab.markers  # computed once


def _refine_plain(markers, stab, names, predicted, weights):
    """refine_rigid as it was: fit_rigid_batch on the raw columns, then the full product."""
    raw = markers.positions[:, markers.index(names)]
    w = np.where(np.isnan(raw[:, :, 0]) | np.isnan(predicted[:, :, 0]), 0.0, weights[None])
    R, t, ok = fit_rigid_batch(raw, predicted, w)
    flagged = stab.flagged | ~ok
    if stab.scales is not None:
        R, t, _ = fit_rigid_batch(raw * stab.scales[:, None, None], predicted, w)
    R = np.where(flagged[:, None, None], stab.rotations, R)
    t = np.where(flagged[:, None], stab.translations, t)
    moved = _apply(R, t, stab.scales, markers.positions)
    moved[flagged] = np.nan
    fitted = moved[:, markers.index(stab.stable_names)]
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(np.linalg.norm(fitted - stab.reference[None], axis=2) ** 2, axis=1))
    return R, t, flagged, moved, rms


@pytest.mark.parametrize("mode", ["rigid", "similarity"])
@pytest.mark.filterwarnings("ignore:Mean of empty slice")
def test_refine_matches_the_plain_fit(mode):
    markers = _take().to_units("m")
    stab = stabilise_rigid(markers, STABLE, mode=mode)
    names = markers.names[::-1]
    predicted = stab.markers.positions[:, markers.index(names)] + RNG.normal(0, 1e-4, (markers.n_frames, len(names), 3))
    predicted[RNG.uniform(size=markers.n_frames) < 0.05] = np.nan  # unsolved frames
    predicted[:3, :-2] = np.nan  # too few points: flagged by the refit
    weights = RNG.uniform(0.2, 1.0, len(names))
    before = predicted.copy()
    got = refine_rigid(markers, stab, names, predicted, weights=weights)
    assert np.array_equal(predicted, before, equal_nan=True)  # the caller's prediction is left alone
    R, t, flagged, moved, rms = _refine_plain(markers, stab, names, predicted, weights)
    assert flagged[:3].all()
    assert np.array_equal(got.rotations, R) and np.array_equal(got.translations, t)
    assert np.array_equal(got.flagged, flagged)
    assert np.array_equal(got.rms, rms, equal_nan=True)
    assert np.array_equal(got.markers.positions, moved, equal_nan=True)


def _local_polynomial_plain(values, half_window, order, weights):
    """The frame-major loop local_polynomial used before (same arithmetic, other layout)."""
    F = values.shape[0]
    y = np.nan_to_num(values.reshape(F, -1))
    w = np.where(np.isnan(values.reshape(F, -1)).any(axis=1), 0.0, weights)
    offsets, powers = np.arange(-half_window, half_window + 1), np.arange(2 * order + 1)
    pad_w = np.concatenate([np.zeros(half_window), w, np.zeros(half_window)])
    S, count = np.zeros((F, powers.size)), np.zeros(F)
    for j in offsets:
        wj = pad_w[half_window + j : half_window + j + F]
        S += wj[:, None] * (float(j) ** powers)[None]
        count += wj > 0
    M = S[:, np.add.outer(np.arange(order + 1), np.arange(order + 1))]
    ok = count >= order + 1
    e0 = np.zeros((int(ok.sum()), order + 1, 1))
    e0[:, 0] = 1.0
    x = np.zeros((F, order + 1))
    x[ok] = np.linalg.solve(M[ok] + 1e-12 * np.eye(order + 1), e0)[:, :, 0]
    pad_y = np.concatenate([np.zeros((half_window, y.shape[1])), y, np.zeros((half_window, y.shape[1]))])
    out = np.zeros_like(y)
    for j in offsets:
        kj = x[:, order].copy()
        for p in range(order - 1, -1, -1):
            kj *= j
            kj += x[:, p]
        kj *= pad_w[half_window + j : half_window + j + F]
        out += kj[:, None] * pad_y[half_window + j : half_window + j + F]
    out[~ok] = np.nan
    return out.reshape(values.shape)


def test_smoothing_kernels_are_reused_only_for_the_same_weights():
    F = 300
    weights = (RNG.uniform(size=F) > 0.1).astype(float)
    a, b = RNG.normal(size=(F, 13)), RNG.normal(size=(F, 4, 3))
    b[7] = np.nan  # NaN samples change the weights: another kernel
    for values, w in ((a, weights), (b, weights), (a, weights), (a, np.roll(weights, 1)), (a[:, 0], None)):
        got = smoothing.local_polynomial(values, half_window=6, order=3, weights=w)
        ref = _local_polynomial_plain(values, 6, 3, np.ones(F) if w is None else w)
        assert got.shape == values.shape and got.flags.c_contiguous
        assert np.array_equal(got, ref, equal_nan=True)
    x, _ = smoothing._last[3:]
    assert not x.flags.writeable  # shared between calls: read-only


def test_smoothed_head_motion_is_unchanged_by_the_cached_kernels():
    markers = _take().to_units("m")
    stab = stabilise_rigid(markers, STABLE)
    smoothing._last = None
    cold = smooth_head_motion(markers, stab, half_window=6)
    warm = smooth_head_motion(markers, stab, half_window=6)
    assert np.array_equal(cold.rotations, warm.rotations) and np.array_equal(cold.translations, warm.translations)
    assert np.array_equal(cold.markers.positions, warm.markers.positions, equal_nan=True)


def test_norm3_is_the_linalg_norm():
    x = RNG.normal(size=(1000, 7, 3)) * np.exp(RNG.uniform(-20, 20, (1000, 7, 1)))
    x[3, 2] = np.nan
    assert np.array_equal(_norm3(x), np.linalg.norm(x, axis=2), equal_nan=True)


def test_scaling_units_down_skips_nothing_that_matters():
    markers = _take()
    got = markers.to_units("m")
    assert got.units == "m" and markers.units == "mm"
    assert np.array_equal(got.positions, markers.positions * 0.001, equal_nan=True)
    assert got.names == markers.names and got.fps == markers.fps
    up = got.to_units("mm")  # scaling up is validated as before
    assert up.units == "mm" and np.array_equal(up.positions, got.positions * 1000.0, equal_nan=True)


def test_zero_rows_leaves_a_gapless_array_alone():
    x = RNG.normal(size=(5, 4, 3))
    assert zero_rows(x, np.zeros((5, 4), dtype=bool)) is x
