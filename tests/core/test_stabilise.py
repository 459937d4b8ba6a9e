"""Rigid stabilisation: exact without noise, flags what it cannot fit, never silently wrong."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facecap.solvers import FacecapError, MarkerSet, fit_rigid_batch, fit_similarity, stabilise_rigid
from facecap.solvers.transforms import matrix_to_euler_xyz, rotation_angle_deg


def moving_head(n_frames=50, seed=0):
    rng = np.random.default_rng(seed)
    ref = rng.normal(scale=0.05, size=(10, 3))
    R = Rotation.from_rotvec(rng.normal(scale=0.3, size=(n_frames, 3))).as_matrix()
    R[0] = np.eye(3)
    t = rng.normal(scale=0.03, size=(n_frames, 3))
    t[0] = 0
    pos = np.einsum("fij,mj->fmi", R, ref) + t[:, None]
    names = tuple(f"h{i}" for i in range(4)) + tuple(f"f{i}" for i in range(6))
    return MarkerSet(names, np.arange(1, n_frames + 1), pos), R, ref


def test_rigid_recovery_is_exact_without_noise():
    markers, R, ref = moving_head()
    res = stabilise_rigid(markers, ["h0", "h1", "h2", "h3"], reference_frames=(1, 1))
    np.testing.assert_allclose(res.markers.positions, np.broadcast_to(ref, markers.positions.shape), atol=1e-12)
    assert rotation_angle_deg(res.head_rotations() @ R.transpose(0, 2, 1)).max() < 1e-6
    assert not res.flagged.any()
    np.testing.assert_allclose(np.linalg.det(res.rotations), 1.0)


def test_reflection_is_never_returned():
    # A mirrored target: the best proper rotation, not a reflection.
    rng = np.random.default_rng(1)
    src = rng.normal(size=(1, 6, 3))
    tgt = src * np.array([-1, 1, 1])
    R, _, ok = fit_rigid_batch(src, tgt[0], np.ones((1, 6)))
    assert ok[0] and np.linalg.det(R[0]) == pytest.approx(1.0)


def test_frames_with_too_few_or_collinear_stable_markers_are_flagged():
    markers, _, _ = moving_head()
    pos = markers.positions.copy()
    pos[5, [0, 1]] = np.nan  # only 2 stable markers left
    line = np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0]])
    pos[7, :4] = line  # collinear stable markers
    res = stabilise_rigid(markers.with_positions(pos), ["h0", "h1", "h2", "h3"], reference_frames=(1, 1))
    assert res.flagged.tolist().count(True) == 2
    assert "only 2 of 4" in res.flag_reasons[6] and "collinear" in res.flag_reasons[8]
    assert np.isnan(res.markers.positions[[5, 7]]).all()  # unsolvable frames become gaps
    assert np.isfinite(res.markers.positions[[4, 6]]).all()


def test_stable_set_errors_name_the_problem():
    markers, _, _ = moving_head()
    with pytest.raises(FacecapError, match="at least 3 stable markers"):
        stabilise_rigid(markers, ["h0", "h1"])
    with pytest.raises(FacecapError, match=r"unknown stable marker\(s\) \['nose'\]"):
        stabilise_rigid(markers, ["h0", "h1", "nose"])
    with pytest.raises(FacecapError, match="outside the take"):
        stabilise_rigid(markers, ["h0", "h1", "h2"], reference_frames=(900, 910))


def test_similarity_recovers_scale_rotation_translation():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(30, 3))
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    dst = 1.17 * src @ R.T + [0.1, 2.0, -0.4]
    sim = fit_similarity(src, dst)
    assert sim.scale == pytest.approx(1.17, rel=1e-12)
    np.testing.assert_allclose(sim.rotation, R, atol=1e-12)
    np.testing.assert_allclose(sim.apply(src), dst, atol=1e-12)


def test_euler_matches_blender_xyz_convention():
    angles = np.array([[0.3, -0.7, 2.5], [-1.0, 0.2, -3.0]])
    R = Rotation.from_euler("xyz", angles).as_matrix()  # extrinsic xyz == Blender 'XYZ'
    np.testing.assert_allclose(matrix_to_euler_xyz(R), angles, atol=1e-12)


def _head_with_deforming_stable_markers(seed=0, n_frames=600):
    """10 'stable' markers on a head (sample layout), 3 of which actually move (brows, a sliding temple dot)."""
    from pathlib import Path

    from facecap.solvers import Basis

    basis = Basis.load_npz(Path(__file__).resolve().parents[2] / "sample_blends" / "character_basis.npz")
    names = [n for n in basis.marker_names if n.startswith("head_")] + ["brow_inner_L", "brow_outer_R"]
    ref = basis.subset_markers(names).neutral
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 60
    ramp = np.clip((t - 1.0) / 0.8, 0, 1)  # still during the neutral hold, then a smooth start
    rv = (ramp * ramp * (3 - 2 * ramp))[:, None] * np.stack(
        [0.3 * np.sin(0.5 * t), 0.2 * np.sin(0.7 * t + 1), 0.4 * np.sin(0.3 * t + 2)], 1
    )
    R = Rotation.from_rotvec(rv).as_matrix()
    local = np.repeat(ref[None], n_frames, 0)
    moving = [names.index("brow_inner_L"), names.index("brow_outer_R"), names.index("head_temple_L")]
    for i, k in enumerate(moving):
        act = np.clip(np.sin(2 * np.pi * (0.4 + 0.1 * i) * t + i), 0, 1)
        act[:60] = 0
        local[:, k, 2] += 0.006 * act
        local[:, k, 1] -= 0.002 * act
    pos = np.einsum("fij,fmj->fmi", R, local) + rng.normal(0, 0.0003, local.shape)
    return MarkerSet(tuple(names), np.arange(1, n_frames + 1), pos, fps=60), R, [names[k] for k in moving]


def test_robust_fit_survives_deforming_markers_in_the_stable_set():
    from facecap.solvers.capture.stabilise import smooth_head_motion

    markers, R, moving = _head_with_deforming_stable_markers()
    errors = {}
    for robust in (False, True):
        st = stabilise_rigid(markers, markers.names, reference_frames=(1, 50), robust=robust)
        st = smooth_head_motion(markers, st, half_window=6)
        errors[robust] = rotation_angle_deg(st.head_rotations() @ R.transpose(0, 2, 1)).max()
    print(f"max rotation error: plain {errors[False]:.3f} deg, robust {errors[True]:.3f} deg")
    assert errors[True] <= 0.3
    assert errors[False] > 2 * errors[True]  # the plain fit is dragged by the moving markers
    st = stabilise_rigid(markers, markers.names, reference_frames=(1, 50))
    assert sorted(n for n, w in st.marker_trust.items() if w < 0.5) == sorted(moving)


def test_rotation_error_with_noise_after_smoothing():
    from facecap.solvers.capture.stabilise import smooth_head_motion

    markers, R, moving = _head_with_deforming_stable_markers(seed=1)
    rigid = [n for n in markers.names if n not in moving]
    st = smooth_head_motion(markers, stabilise_rigid(markers, rigid, reference_frames=(1, 50)), half_window=6)
    err = rotation_angle_deg(st.head_rotations() @ R.transpose(0, 2, 1))
    rms = np.sqrt(np.mean(err**2))
    print(f"7 rigid markers, sigma 0.3 mm: rotation error RMS {rms:.3f} deg, max {err.max():.3f} deg")
    assert rms <= 0.1
