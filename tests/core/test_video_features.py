"""Flow-PCA features of footage as the source of the linear, rbf and pca strategies (no markers)."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import FacecapError  # noqa: E402
from facecap.solvers.video.features import flow_features, remove_similarity, solve_from_flow  # noqa: E402
from facecap.solvers.video.flow import dense_flow  # noqa: E402
from facecap.solvers.video.synthetic import write_synthetic_clip  # noqa: E402

W, H, AMP, STEP = 320, 240, 4.0, 6
SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "browDownLeft", "browDownRight", "noseSneer")


@pytest.fixture(scope="module")
def footage(tmp_path_factory):
    """A synthetic face whose six bumps are the "shapes" (weight = amplitude / AMP), with head motion."""
    d = tmp_path_factory.mktemp("flowpca")
    clip = write_synthetic_clip(d / "perf.avi", 120, W, H, amplitude=AMP, noise=1.0, seed=11, period=24.0)
    dense = dense_flow(clip.path, grid_step=STEP)
    pts = dense.points.astype(float)
    dist = np.linalg.norm(pts[:, :, None] - clip.motion.centres, axis=-1) / clip.motion.radii
    inside = (pts[..., 0] > 20) & (pts[..., 0] < W - 20) & (pts[..., 1] > 20) & (pts[..., 1] < H - 20)
    stable = inside & (dist.min(axis=-1) > 3.0)  # far from every bump: moves with the head only
    return clip, dense, stable


def examples(clip, n=16):
    """Posed frame numbers (frame 1 = motion time 0) and their weights."""
    rows = np.linspace(0, clip.motion.n_frames - 1, n).round().astype(int)
    return rows + 1, clip.motion.amplitudes[rows] / AMP


def test_removing_the_head_similarity_leaves_the_face_motion(footage):
    clip, dense, stable = footage
    local = remove_similarity(dense.flows, dense.points, stable)
    t = 37
    truth = clip.motion.local(t, dense.points.astype(float))  # D_t on the reference grid
    err = np.linalg.norm(local[t] - truth, axis=-1)
    inner = (dense.points[..., 0] > 30) & (dense.points[..., 0] < W - 30) & \
        (dense.points[..., 1] > 30) & (dense.points[..., 1] < H - 30)
    print(f"face motion after head removal: median error {np.median(err[inner]):.3f} px")
    assert np.median(err[inner]) <= 0.3
    with pytest.raises(FacecapError, match="need at least 3"):
        remove_similarity(dense.flows, dense.points, np.zeros(stable.shape, bool))


@pytest.mark.parametrize("strategy,options", [("linear", {"ridge": 1e-3}), ("rbf", {}), ("pca", {})])
def test_example_strategies_from_flow_features(footage, strategy, options):
    clip, dense, stable = footage
    feats = flow_features(dense, n_components=10, stable=stable)
    frames, weights = examples(clip)
    r = solve_from_flow(feats, SHAPES, strategy=strategy, example_frames=frames, example_weights=weights, **options)
    truth = clip.motion.amplitudes / AMP
    rest = np.setdiff1d(np.arange(len(truth)), frames - 1)  # judged on frames that were not examples
    rmse = float(np.sqrt(np.mean((r.weights[rest] - truth[rest]) ** 2)))
    print(f"flow-PCA -> {strategy}: weights RMSE {rmse:.4f} on {rest.size} unposed frames")
    assert rmse <= 0.06


def test_head_motion_left_in_the_features_hurts(footage):
    clip, dense, stable = footage
    frames, weights = examples(clip)
    truth = clip.motion.amplitudes / AMP
    errors = {}
    for label, mask in (("stabilised", stable), ("raw", None)):
        feats = flow_features(dense, n_components=10, stable=mask)
        r = solve_from_flow(feats, SHAPES, strategy="linear", example_frames=frames, example_weights=weights,
                            ridge=1e-3)
        errors[label] = float(np.sqrt(np.mean((r.weights - truth) ** 2)))
    print(f"linear from flow features: {errors}")
    assert errors["stabilised"] < errors["raw"]
    with pytest.raises(FacecapError, match=r"frame\(s\) \[500.0\] are not in the footage"):
        solve_from_flow(flow_features(dense, n_components=4), SHAPES, example_frames=[1, 500],
                        example_weights=np.zeros((2, 6)))
    with pytest.raises(FacecapError, match="flow features drive linear, rbf, pca"):
        solve_from_flow(flow_features(dense, n_components=4), SHAPES, strategy="calibrated", example_frames=[1],
                        example_weights=np.zeros((1, 6)))
