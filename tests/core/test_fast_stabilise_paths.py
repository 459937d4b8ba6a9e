"""The fast code paths of head stabilisation agree with the straightforward ones they replace.

Closed-form (quaternion) rotation fit vs the batched SVD, the cheap collinearity test vs eigvalsh,
the one-right-hand-side local polynomial vs a per-frame least-squares fit, grouped alignment
products vs per-marker ones, and MarkerSet's one-pass validation.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecap.solvers import FacecapError, MarkerSet, fit_rigid_batch
from facecap.solvers.capture.align import align_actor, region_patterns
from facecap.solvers.capture.smoothing import local_polynomial
from facecap.solvers.transforms import _rotation_svd, _spread_ok, best_rotation

RNG = np.random.default_rng(11)


def _matrices(singular_values, flip=0.3):
    """H = U diag(s) V with random rotations U, V; a fraction ``flip`` of them reflections (det < 0)."""
    F = len(singular_values)
    U = Rotation.random(F, random_state=1).as_matrix()
    V = Rotation.random(F, random_state=2).as_matrix()
    s = np.array(singular_values, dtype=float)
    s[:, 2] *= np.where(RNG.uniform(size=F) < flip, -1.0, 1.0)
    scale = np.exp(RNG.uniform(-6, 6, F))[:, None, None]  # the fit must not care about units
    return scale * (U * s[:, None, :]) @ V


@pytest.mark.parametrize("kind", ["generic", "wide spread", "near rotation", "coplanar"])
def test_closed_form_rotation_matches_svd(kind):
    F = 4000
    sv = {
        "generic": RNG.uniform(0, 1, (F, 3)),
        "wide spread": np.exp(RNG.uniform(-12, 0, (F, 3))),  # sigma ratios down to 1e-5
        "near rotation": 1 + 0.01 * RNG.normal(size=(F, 3)),  # the smoothing's projection
        "coplanar": np.c_[RNG.uniform(0.1, 1, (F, 2)), np.zeros(F)],  # three stable markers
    }[kind]
    H = _matrices(np.sort(sv, axis=1)[:, ::-1])
    R = best_rotation(H)
    np.testing.assert_allclose(R, _rotation_svd(H), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_undetermined_rotations_take_the_svd_exactly():
    # Collinear points (sigma_2 = sigma_3 = 0), a reflection with sigma_2 = sigma_3, no points at all.
    H = np.concatenate([
        _matrices(np.c_[RNG.uniform(0.1, 1, 50), np.zeros((50, 2))]),
        _matrices(np.c_[np.ones(50), 0.5 * np.ones((50, 2))], flip=1.0),
        np.zeros((3, 3, 3)),
    ])
    np.testing.assert_array_equal(best_rotation(H), _rotation_svd(H))


def _kabsch_loop(src, tgt, w):
    """Reference: one frame at a time, valid points only, SVD."""
    R, t, ok = np.tile(np.eye(3), (len(src), 1, 1)), np.zeros((len(src), 3)), np.zeros(len(src), bool)
    for f in range(len(src)):
        y = tgt if tgt.ndim == 2 else tgt[f]
        use = (w[f] > 0) & np.isfinite(src[f]).all(axis=1) & np.isfinite(y).all(axis=1)
        if not use.any():
            continue
        x, y, ww = src[f, use], y[use], w[f, use]
        cx, cy = ww @ x / ww.sum(), ww @ y / ww.sum()
        H = ((x - cx) * ww[:, None]).T @ (y - cy)
        R[f] = _rotation_svd(H[None])[0]
        t[f] = cy - R[f] @ cx
        sv = np.linalg.svd(((x - cx) * ww[:, None]).T @ (x - cx) / ww.sum(), compute_uv=False)
        ok[f] = use.sum() >= 3 and np.sqrt(sv[1]) > 1e-3 * np.sqrt(sv[0])
    return R, t, ok


@pytest.mark.parametrize("shared_target", [True, False])
def test_rigid_fit_with_gaps_and_weights_matches_a_per_frame_svd(shared_target):
    F, N = 300, 7
    ref = RNG.normal(scale=0.05, size=(N, 3))
    R_true = Rotation.random(F, random_state=3).as_matrix()
    src = (ref @ R_true.transpose(0, 2, 1)) + RNG.normal(size=(F, 1, 3)) + RNG.normal(scale=1e-3, size=(F, N, 3))
    w = RNG.uniform(0.2, 2.0, (F, N))
    w[RNG.uniform(size=(F, N)) < 0.1] = 0.0  # zero weights with valid coordinates
    src[RNG.uniform(size=(F, N)) < 0.1] = np.nan  # gaps: whole points ...
    src[5, 2, 1] = np.nan  # ... and a single coordinate
    src[7, :5] = np.nan  # only 2 points left
    src[9] = ref[0] + np.linspace(0, 1, N)[:, None] * [1.0, 2.0, 0.5]  # collinear
    tgt = ref if shared_target else ref + RNG.normal(scale=1e-3, size=(F, N, 3))
    if not shared_target:
        tgt[RNG.uniform(size=(F, N)) < 0.05] = np.nan
    R, t, ok = fit_rigid_batch(src, tgt, w)
    R0, t0, ok0 = _kabsch_loop(src, tgt, w)
    np.testing.assert_array_equal(ok, ok0)
    assert not ok[7] and not ok[9]
    np.testing.assert_allclose(R[ok], R0[ok], atol=1e-9)
    np.testing.assert_allclose(t[ok], t0[ok], atol=1e-9)
    assert np.isfinite(R).all() and np.isfinite(t).all()


def test_collinearity_test_agrees_with_eigenvalues_around_the_threshold():
    # Points on a line plus a sideways spread of 1e-4 .. 1e-2 of the length: the threshold
    # (singular value ratio 1e-3) lies inside, and near it the exact eigen-solve decides.
    F, N = 3000, 6
    side = np.exp(RNG.uniform(np.log(1e-4), np.log(1e-2), F))
    pts = np.linspace(-1, 1, N)[None, :, None] * RNG.normal(size=(F, 1, 3))
    pts = pts + side[:, None, None] * RNG.normal(size=(F, N, 3))
    pts -= pts.mean(axis=1, keepdims=True)
    cov = pts.transpose(0, 2, 1) @ pts / N
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0.0, None))
    expected = sv[:, 1] > 1e-3 * np.maximum(sv[:, 2], 1e-300)
    assert 0.2 < expected.mean() < 0.8
    np.testing.assert_array_equal(_spread_ok(cov), expected)
    assert not _spread_ok(np.zeros((2, 3, 3))).any()


def _local_polynomial_loop(values, half_window, order, weights):
    """Reference: a weighted least-squares polynomial per frame."""
    F = len(values)
    flat = values.reshape(F, -1)
    out = np.full(flat.shape, np.nan)
    for f in range(F):
        j = np.arange(max(0, f - half_window), min(F, f + half_window + 1))
        w = np.where(np.isnan(flat[j]).any(axis=1), 0.0, weights[j])
        if (w > 0).sum() < order + 1:
            continue
        A = np.vander(j - f, order + 1, increasing=True) * np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(A, np.nan_to_num(flat[j]) * np.sqrt(w)[:, None], rcond=None)[0]
        out[f] = coef[0]
    return out.reshape(values.shape)


@pytest.mark.parametrize("half_window,order", [(6, 3), (2, 1), (4, 2)])
def test_local_polynomial_matches_a_per_frame_fit(half_window, order):
    F = 400
    values = np.cumsum(RNG.normal(size=(F, 4, 3)), axis=0)
    values[50:53, 1] = np.nan  # a gap in one column
    weights = RNG.uniform(0.5, 2.0, F)
    weights[100:140] = 0.0  # flagged frames: windows inside lose their samples
    got = local_polynomial(values, half_window=half_window, order=order, weights=weights)
    ref = _local_polynomial_loop(values, half_window, order, weights)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got[119]).all()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(values[~np.isnan(values)]).max())


@pytest.mark.parametrize("regions", [(), region_patterns(True)])
def test_alignment_vectors_match_per_marker_products(regions):
    names = ("brow_L", "brow_R", "eye_L", "nose", "lip_L", "lip_R", "chin", "jaw_L", "jaw_R", "cheek_L")
    M = len(names)
    neutral = RNG.normal(size=(M, 3))
    bound = 1.3 * neutral @ Rotation.random(random_state=4).as_matrix().T + RNG.normal(scale=0.01, size=(M, 3))
    align = align_actor(neutral, bound, names, regions=regions)
    assert len(align.regions) == (2 if regions else 0)
    v = RNG.normal(size=(6, 5, M, 3))
    v[1, 2, 3] = np.nan
    expected = align.scales[:, None] * np.einsum("mij,...mj->...mi", align.rotations, v)
    np.testing.assert_allclose(align.apply_vectors(v), expected, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(align.apply_vectors(v[0, 0]), expected[0, 0], rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(align.inverse_vectors(expected), v, rtol=1e-13, atol=1e-13)


def test_marker_set_validation_in_one_pass():
    pos = RNG.normal(size=(5, 3, 3))
    pos[1, 0] = np.nan
    pos[2, 1, 2] = np.nan  # half-missing: becomes a whole gap, and the caller's array is untouched
    m = MarkerSet(("a", "b", "c"), np.arange(5), pos)
    assert np.isnan(m.positions[2, 1]).all() and np.isnan(m.positions[1, 0]).all()
    assert np.isfinite(pos[2, 1, :2]).all()
    assert np.isfinite(m.positions[[0, 3, 4]]).all()
    big = np.full((2, 1, 3), 1e308)  # finite, only their sum overflows
    np.testing.assert_array_equal(MarkerSet(("a",), [1, 2], big).positions, big)
    for bad in (np.inf, -np.inf):
        pos = np.zeros((2, 1, 3))
        pos[1, 0, 1] = bad
        with pytest.raises(FacecapError, match="infinite"):
            MarkerSet(("a",), [1, 2], pos)
    pos = np.zeros((2, 1, 3))
    pos[1, 0] = [np.nan, np.inf, 0.0]
    with pytest.raises(FacecapError, match="infinite"):
        MarkerSet(("a",), [1, 2], pos)
