"""Bounds, locks and regions by name pattern, through the whole pipeline."""

import numpy as np
import pytest
from synthetic_face import make_basis

from facecap.solvers import FacecapError, RetargetSettings, retarget
from facecap.solvers.character.shape_options import Region, resolve_bounds, resolve_locks, resolve_regions
from facecap.solvers.tools.synthetic.synth import synthesize_take

EXACT = dict(regularisation=0.0, sparsity=0.0, symmetry=0.0, head_smoothing=0.0, smoothing=(0.0, 0.0))


@pytest.fixture(scope="module")
def take():
    basis, stable = make_basis()
    rng = np.random.default_rng(4)
    W = np.clip(rng.uniform(-0.5, 1.0, size=(200, basis.n_shapes)), 0, 1)
    W[:60] = 0
    return basis, stable, W, synthesize_take(basis, W, stable=stable, noise_sigma=0.0, gap_fraction=0.0)


def test_first_matching_pattern_wins():
    names = ("jawOpen", "mouthSmileLeft", "mouthClose")
    lo, hi = resolve_bounds(names, np.zeros(3), np.ones(3), (("mouthSmile*", 0.0, 0.5), ("mouth*", -0.2, 0.8)))
    assert lo.tolist() == [0.0, 0.0, -0.2] and hi.tolist() == [1.0, 0.5, 0.8]
    assert np.isnan(resolve_locks(names, (("jaw*", 0.25),))[1:]).all()
    with pytest.raises(FacecapError, match=r"locks: pattern\(s\) \['nose\*'\] match no shape"):
        resolve_locks(names, (("nose*", 0.0),))


def test_locked_shapes_are_held_and_the_rest_still_fit(take):
    basis, stable, W, synth = take
    settings = RetargetSettings(stable, (1, 50), locks=(("shape3", 0.4),), **EXACT)
    r = retarget(synth.markers, basis, settings)
    assert np.all(r.weights[:, 3] == 0.4)
    others = [k for k in range(basis.n_shapes) if k != 3]
    assert np.abs(r.weights[:, others] - W[:, others]).mean() < 0.2  # still a sensible fit


def test_bounds_are_respected(take):
    basis, stable, W, synth = take
    r = retarget(synth.markers, basis, RetargetSettings(stable, (1, 50), bounds=(("shape1*", 0.0, 0.3),), **EXACT))
    cols = [k for k, n in enumerate(basis.shape_names) if n.startswith("shape1")]
    assert r.weights[:, cols].max() <= 0.3 + 1e-12
    assert r.weights[:, cols].max() == pytest.approx(0.3)


def test_shapes_outside_every_region_never_move(take):
    basis, stable, W, synth = take
    regions = (Region("a", ("shape1*",), ("m1*", "m2*", "m3*")), Region("b", ("shape2", "shape3"), ("*",)))
    r = retarget(synth.markers, basis, RetargetSettings(stable, (1, 50), regions=regions, **EXACT))
    _, held = resolve_regions(basis.shape_names, basis.marker_names, regions, dims=3)
    assert "shape0" in held and any("held" in w for w in r.warnings)
    for name in held:
        assert np.all(r.weights[:, basis.shape_names.index(name)] == 0.0)


def test_per_frame_locks_hold_the_animators_values(take):
    """A shape locked to per-frame values (an animator's keys) is held there on every frame; NaN
    frames are free; the other shapes are solved knowing its contribution."""
    basis, stable, W, synth = take
    name = basis.shape_names[3]
    held = W[:, 3].copy()
    held[150:] = np.nan  # free from frame 150 on
    settings = RetargetSettings(stable_markers=tuple(stable), neutral_frames=(1, 50), locks=((name, held),), **EXACT)
    r = retarget(synth.markers, basis, settings)
    np.testing.assert_allclose(r.weights[:150, 3], W[:150, 3], atol=1e-12)
    np.testing.assert_allclose(r.weights, W, atol=1e-5)
    wrong = W[:, 3] + 0.3  # held off the truth: the free frames still recover, the rest compensate
    settings = RetargetSettings(stable_markers=tuple(stable), neutral_frames=(1, 50), locks=((name, wrong),), **EXACT)
    r = retarget(synth.markers, basis, settings)
    np.testing.assert_allclose(r.weights[:, 3], wrong, atol=1e-12)
    with pytest.raises(FacecapError, match="per-frame values for 200 frames"):
        resolve_locks(basis.shape_names, ((name, held[:10]),), n_frames=200)
