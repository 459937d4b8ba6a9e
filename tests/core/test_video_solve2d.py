"""Video end to end in the core: footage -> LK tracks -> 2D stabilisation -> bounded solve -> weights.

The synthetic face moves by K known 2D "shapes" (smooth displacement bumps, weights in [0, 1])
plus a global similarity (head motion); the solve must recover the weights from the video file.
"""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import solve_bounded  # noqa: E402
from facecap.solvers.capture.stabilise import stabilise_2d  # noqa: E402
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402
from facecap.solvers.video.tracking import track_points  # noqa: E402

W, H, AMP = 320, 240, 4.0


def basis_2d(motion, pts):
    """(2M, K): shape k moves reference point p by AMP * direction_k * gaussian_k(p) at weight 1."""
    d = pts[:, None, :] - motion.centres
    g = np.exp(-0.5 * np.sum(d * d, axis=-1) / motion.radii**2)  # (M, K)
    return (AMP * g[:, None, :] * motion.directions.T[None]).reshape(-1, len(motion.centres))


def test_weights_from_video_through_tracks_and_a_2d_solve(tmp_path):
    clip = write_synthetic_clip(tmp_path / "perf.avi", 90, W, H, amplitude=AMP, noise=2.0, seed=7, period=30.0)
    xs, ys = np.meshgrid(np.linspace(95, 225, 8), np.linspace(45, 215, 9))
    face = np.column_stack([xs.ravel(), ys.ravel()])
    stable = np.array([[20, 20], [300, 20], [20, 220], [300, 220], [160, 12]], float)  # far from every bump
    names = [f"s{i}" for i in range(len(stable))] + [f"f{i:02d}" for i in range(len(face))]
    res = track_points(clip.path, points=np.vstack([stable, face]), names=names)
    stab = stabilise_2d(res.markers, names[: len(stable)], mode="similarity")
    assert np.nanmax(stab.rms) < 0.5
    pos = stab.markers.positions[:, len(stable):]
    deltas = (pos - pos[0]).reshape(len(pos), -1)
    A = basis_2d(clip.motion, face)
    conf = res.confidence[:, len(stable):]
    solved = solve_bounded(A, deltas, mask=conf, dims=2, regularisation=1e-3).weights
    truth = clip.motion.amplitudes / AMP
    rmse = np.sqrt(np.mean((solved - truth) ** 2))
    print(f"2D solve from video: weights RMSE {rmse:.4f} (range 0..{truth.max():.2f})")
    assert rmse <= 0.06
