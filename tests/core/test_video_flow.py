"""Dense flow: accuracy per backend, flow algebra, drift control, markers from flow, flow PCA."""

import numpy as np
import pytest

pytest.importorskip("cv2")

from facecap.solvers import FacecapError  # noqa: E402
from facecap.solvers.video.flow import (  # noqa: E402
    FlowEstimator, ReferenceFlow, compose, dense_flow, endpoint_error, reverse, sample_flow, track_with_flow, warp,
)
from facecap.solvers.video.pca import flow_pca  # noqa: E402
from facecap.solvers.video.synthetic import face_texture, make_motion, render, write_synthetic_clip  # noqa: E402

W, H = 240, 180


@pytest.fixture(scope="module")
def scene():
    tex = face_texture(W, H, seed=4)
    motion = make_motion(40, W, H, seed=4)
    interior = np.zeros((H, W), bool)
    interior[25:-25, 30:-30] = True
    return tex, motion, interior


@pytest.mark.parametrize("method,size", [("dis", 1.0), ("farneback", 1.0), ("tvl1", 0.5)])
def test_flow_endpoint_error_in_the_interior(scene, method, size):
    tex, motion, interior = scene
    if size != 1.0:  # TV-L1 is slow: test it on a smaller face
        w, h = int(W * size), int(H * size)
        tex, motion = face_texture(w, h, seed=4), make_motion(40, w, h, seed=4, shift=3.0, amplitude=2.0)
        interior = np.zeros((h, w), bool)
        interior[15:-15, 20:-20] = True
    ref, img = render(tex, motion, 0), render(tex, motion, 12)
    flow = FlowEstimator(method).calc(ref, img)
    epe = endpoint_error(flow, motion.flow(12), interior)
    print(f"{method}: EPE mean {epe.mean():.3f} px, median {np.median(epe):.3f} px")
    assert np.median(epe) <= 0.3 and epe.mean() <= 0.3
    assert np.abs(warp(img, flow) - ref.astype(np.float32))[interior].mean() < 3.0  # ref(x) ~ img(x + f(x))


def test_composition_beats_addition(scene):
    tex, motion, interior = scene
    f01, f12 = motion.flow(10), motion.flow_between(10, 20)  # exact fields
    truth = motion.flow(20)
    exact_comp = endpoint_error(compose(f01, f12), truth, interior).mean()
    exact_add = endpoint_error(f01 + f12, truth, interior).mean()
    imgs = [render(tex, motion, t) for t in (0, 10, 20)]
    est = FlowEstimator("dis")
    g01, g12 = est.calc(imgs[0], imgs[1]), est.calc(imgs[1], imgs[2])
    est_comp = endpoint_error(compose(g01, g12), truth, interior).mean()
    est_add = endpoint_error(g01 + g12, truth, interior).mean()
    print(f"compose {exact_comp:.4f} vs add {exact_add:.4f} (exact fields); {est_comp:.3f} vs {est_add:.3f} (DIS)")
    assert exact_comp <= 0.02 and exact_add >= 5 * exact_comp
    assert est_comp < est_add


def test_reverse_composed_with_the_field_is_zero(scene):
    _, motion, interior = scene
    f = motion.flow(15)
    r = reverse(f)
    there_and_back = np.linalg.norm(compose(f, r), axis=-1)[interior]
    negated = np.linalg.norm(compose(f, -f), axis=-1)[interior]
    truth = motion.flow_between(15, 0)
    print(f"|f o reverse(f)| mean {there_and_back.mean():.4f} px; with negation {negated.mean():.3f} px")
    assert there_and_back.mean() <= 0.01 and there_and_back.max() <= 0.1
    assert negated.mean() >= 10 * there_and_back.mean()
    inner_b = np.zeros_like(interior)
    inner_b[40:-40, 50:-50] = True
    assert endpoint_error(r, truth, inner_b).max() <= 0.05
    assert np.isfinite(reverse(np.full((20, 20, 2), 30.0, np.float32))).all()  # everything off-grid: filled


def test_drift_control_fused_is_no_worse_than_either(scene):
    tex, motion, interior = scene
    imgs = [render(tex, motion, t, noise=6.0) for t in range(40)]
    drift = {}
    for mode in ("none", "direct", "fuse"):
        rf = ReferenceFlow(imgs[0], drift=mode)
        for img in imgs[1:]:
            F = rf.step(img)
        drift[mode] = endpoint_error(F, motion.flow(39), interior).mean()
    print("flow error at frame 39:", {k: round(v, 3) for k, v in drift.items()})
    assert drift["fuse"] <= 0.3
    assert drift["fuse"] <= 1.1 * min(drift["none"], drift["direct"])
    assert drift["none"] > drift["fuse"]


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_synthetic_clip(tmp_path_factory.mktemp("flow") / "face.avi", 30, W, H, seed=5)


def test_dense_flow_of_a_video_and_markers_from_flow(clip):
    res = dense_flow(clip.path, region=[40, 30, 160, 120], grid_step=4)
    assert res.flows.shape == (30, 30, 40, 2) and res.points[0, 0].tolist() == [40, 30]
    assert np.abs(res.flows[0]).max() == 0  # the reference itself
    truth = np.stack([clip.motion.forward(t, res.points.astype(float)) - res.points for t in range(30)])
    epe = np.linalg.norm(res.flows - truth, axis=-1)
    print(f"dense_flow video EPE mean {epe.mean():.3f} px")
    assert np.median(epe) <= 0.3
    tr = track_with_flow(clip.path, region=[60, 40, 120, 130], max_points=40)
    ref_pts = tr.markers.positions[0]
    truth_pts = np.stack([clip.motion.forward(t, ref_pts) for t in range(30)])
    err = np.linalg.norm(tr.markers.positions - truth_pts, axis=2)
    print(f"markers from DIS flow: median error {np.median(err):.3f} px")
    assert tr.method == "dis" and np.median(err) <= 0.5 and (tr.confidence[tr.markers.visible] > 0.5).mean() > 0.9
    pts = np.array([[120.0, 90.0]])
    assert sample_flow(np.dstack([np.full((H, W), 2.0), np.full((H, W), -1.0)]), pts).tolist() == [[2.0, -1.0]]


def test_flow_pca_basis(clip):
    rng = np.random.default_rng(0)
    basis = rng.normal(size=(3, 10, 12, 2))
    coeff = rng.normal(size=(50, 3)) * [5, 2, 1]
    flows = np.einsum("fk,khwd->fhwd", coeff, basis) + 0.3
    pca = flow_pca(flows, n_components=5)
    assert pca.n_components == 3  # rank-limited
    np.testing.assert_allclose(pca.components @ pca.components.T, np.eye(3), atol=1e-10)
    np.testing.assert_allclose(pca.reconstruct(pca.coefficients), flows, atol=1e-9)
    np.testing.assert_allclose(pca.project(flows), pca.coefficients, atol=1e-9)
    assert abs(pca.explained_variance_ratio.sum() - 1) < 1e-9
    X = (flows.reshape(50, -1) - flows.reshape(50, -1).mean(0))
    evals = np.linalg.eigvalsh(X @ X.T)[::-1][:3] / 49  # snapshot method
    np.testing.assert_allclose(pca.explained_variance, evals, rtol=1e-8)
    neutral = flow_pca(flows, n_components=3, center="reference")
    assert np.all(neutral.mean == 0) and np.allclose(neutral.project(np.zeros((1, 10, 12, 2))), 0)
    assert flow_pca(flows, variance=0.5).n_components == 1
    with pytest.raises(FacecapError, match="shape"):
        flow_pca(np.zeros((5, 4, 4)))


def test_bad_method_is_named():
    with pytest.raises(FacecapError, match="`method` must be one of dis, farneback, tvl1"):
        FlowEstimator("horn")
