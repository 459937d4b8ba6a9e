"""Geometric solve from 2D image tracks against the character's front view (video takes)."""

import json
from pathlib import Path

import numpy as np
import pytest

from facecap.solvers import Basis, FacecapError, MarkerSet, RetargetSettings, retarget
from facecap.solvers.tools.synthetic.synth import performance_weights

SAMPLES = Path(__file__).resolve().parents[2] / "sample_blends"


def tracks_2d(basis, weights, stable, *, noise_px=0.5, gap_fraction=0.03, seed=1):
    """Front-view image tracks (pixels, y down) of the character with in-plane head motion and zoom."""
    rng = np.random.default_rng(seed)
    F = weights.shape[0]
    fv = basis.front_view()
    face = fv.neutral[None] + np.einsum("fk,kmd->fmd", weights, fv.deltas)
    t = np.arange(F) / 60
    ramp = np.clip((t - 1) / 0.8, 0, 1)
    roll = np.radians(8) * np.sin(0.7 * t) * ramp
    scale = 2500 * (1 + 0.05 * np.sin(0.3 * t) * ramp)  # pixels per metre, the head moving to and from the camera
    shift = np.stack([640 + 30 * np.sin(0.5 * t) * ramp, 360 + 20 * np.cos(0.4 * t) * ramp - 20 * ramp], 1)
    c, s = np.cos(roll), np.sin(roll)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    px = scale[:, None, None] * (face @ R.transpose(0, 2, 1)) + shift[:, None]
    px += rng.normal(0, noise_px, px.shape)
    gaps = rng.random(px.shape[:2]) < gap_fraction
    gaps[:, [basis.marker_names.index(n) for n in stable]] = False
    px[gaps] = np.nan
    return MarkerSet(basis.marker_names, np.arange(1, F + 1), px, fps=60, units="px", source="synthetic 2D tracks")


@pytest.fixture(scope="module")
def sample():
    basis = Basis.load_npz(SAMPLES / "character_basis.npz")
    layout = json.loads((SAMPLES / "marker_layout.json").read_text())
    stable = tuple(m["name"] for m in layout["markers"] if m["stable"])
    return basis, stable, performance_weights(basis.shape_names, 720, seed=0)


def test_front_view_basis_uses_image_axes(sample):
    basis, _, _ = sample
    fv = basis.front_view()
    k = basis.shape_names.index("jawOpen")
    chin = basis.marker_names.index("chin_C")
    assert fv.deltas.shape == (basis.n_shapes, basis.n_markers, 2)
    assert fv.deltas[k, chin, 1] > 0.01  # the chin drops: image y grows downwards


def test_2d_tracks_solve_end_to_end(sample):
    basis, stable, W = sample
    markers = tracks_2d(basis, W, stable)
    r = retarget(markers, basis, RetargetSettings(stable, (1, 50)))
    err = r.weights - W
    rmse = np.sqrt(np.mean(err**2))
    print(f"2D take: weights RMSE {rmse:.4f}, max {np.abs(err).max():.3f}")
    assert rmse <= 0.06
    assert r.alignment.scale == pytest.approx(1 / 2500, rel=5e-3)
    assert any("front view" in w for w in r.warnings)


def test_2d_takes_need_explicit_stable_points(sample):
    basis, stable, W = sample
    markers = tracks_2d(basis, W[:80], stable)
    with pytest.raises(FacecapError, match="explicit list of stable points"):
        retarget(markers, basis, RetargetSettings("auto", (1, 50)))


def test_per_frame_locks_on_a_2d_take(sample):
    """An animator's keys held per frame (a locked shape with a solve layer) work on 2D takes too."""
    basis, stable, W = sample
    W = W[:240]
    markers = tracks_2d(basis, W, stable)
    k = basis.shape_names.index("jawOpen")
    held = W[:, k] + 0.1
    r = retarget(markers, basis, RetargetSettings(stable, (1, 50), locks=(("jawOpen", held),)))
    np.testing.assert_allclose(r.weights[:, k], held, atol=1e-12)
