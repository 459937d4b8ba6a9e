"""Stabilisation in bounded memory: the head refit in blocks of frames gives the whole-take refit
(to rounding: the rotation's Newton steps run until a block's slowest frame settles), and released
stabilised markers come back bit for bit."""

import numpy as np
import pytest

from facecap.solvers.capture import stabilise
from facecap.solvers.capture.stabilise import refine_rigid, smooth_head_motion, stabilise_rigid
from test_stabilise_speed_paths import STABLE, _take


@pytest.mark.parametrize("mode", ["rigid", "similarity"])
def test_refit_in_blocks_is_the_whole_take_refit(monkeypatch, mode):
    markers = _take(F=500)
    stab = stabilise_rigid(markers, STABLE, mode=mode)
    names = markers.names
    predicted = stab.markers.positions + np.random.default_rng(1).normal(0, 0.1, stab.markers.positions.shape)
    predicted[:7] = np.nan  # frames the solve could not predict
    weights = np.linspace(1.0, 0.5, len(names))
    whole = refine_rigid(markers, stab, names, predicted, weights=weights)
    monkeypatch.setattr(stabilise, "REFIT_BLOCK", 64)  # 8 blocks, the last one short
    blocks = refine_rigid(markers, stab, names, predicted, weights=weights)
    assert np.array_equal(whole.flagged, blocks.flagged)
    np.testing.assert_allclose(blocks.rotations, whole.rotations, atol=1e-14, rtol=0)
    np.testing.assert_allclose(blocks.translations, whole.translations, atol=1e-12, rtol=0)  # mm
    np.testing.assert_allclose(blocks.rms, whole.rms, atol=1e-12, rtol=0)
    np.testing.assert_allclose(blocks.markers.positions, whole.markers.positions, atol=1e-11, rtol=0)


@pytest.mark.parametrize("mode", ["rigid", "similarity"])
def test_smoothed_head_motion_in_blocks_is_the_whole_take_one(monkeypatch, mode):
    markers = _take(F=500)
    stab = stabilise_rigid(markers, STABLE, mode=mode)
    whole = smooth_head_motion(markers, stab, half_window=6)
    monkeypatch.setattr(stabilise, "REFIT_BLOCK", 64)  # the residual RMS in 8 blocks, the last one short
    blocks = smooth_head_motion(markers, stab, half_window=6)
    assert np.array_equal(blocks.rms, whole.rms, equal_nan=True)  # rows are independent: bit for bit
    assert np.isfinite(whole.rms[~whole.flagged]).all()


def test_released_markers_come_back_the_same():
    markers = _take(F=300)
    for stab in (stabilise_rigid(markers, STABLE), smooth_head_motion(markers, stabilise_rigid(markers, STABLE),
                                                                      half_window=4)):
        kept = stab.markers.positions.copy()
        first = stab.markers
        stab.release_markers()
        assert not hasattr(stab.__dict__["_markers"], "positions")  # only how to compute them is kept
        again = stab.markers
        assert again is not first and np.array_equal(again.positions, kept, equal_nan=True)
    gone = stab.without_markers()
    assert np.array_equal(gone.rotations, stab.rotations) and gone.rms is stab.rms
    with pytest.raises(RuntimeError, match="released"):
        gone.markers
