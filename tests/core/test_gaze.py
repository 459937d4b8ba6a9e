"""Gaze from eye angles: a Live Link Face take's eye rotations give ARKit's gaze weights (measured on the real
recordings, which carry both), and a weights take without gaze channels is keyed with them."""

from dataclasses import replace

import numpy as np
import pytest
from shared_data import REALDATA, require

from facecap.solvers.io.weights import read_weights
from facecap.solvers.pipeline import RetargetSettings, retarget
from facecap.solvers.strategies.gaze import GAZE, gaze_from_eye_angles
from facecap.solvers.strategies.options import StrategyInputs


@pytest.fixture(scope="module", params=["llf_alex_rom_3.csv", "llf_alex_rom_4.csv"])
def track(request):
    return read_weights(require(REALDATA / "llf" / request.param))


def test_eye_angles_give_the_recorded_gaze(track):
    derived = gaze_from_eye_angles(track.eyes)
    recorded = track.values[:, [track.names.index(n) for n in GAZE]]
    ok = np.isfinite(recorded).all(axis=1) & np.isfinite(derived).all(axis=1)
    err = np.sqrt(np.mean((derived[ok] - recorded[ok]) ** 2, axis=0))
    r = [np.corrcoef(derived[ok, k], recorded[ok, k])[0, 1] for k in range(8) if recorded[ok, k].std() > 0.02]
    assert err.max() < 0.03 and np.median(err) < 0.015, dict(zip(GAZE, err.round(3)))  # measured: 0.003-0.017
    assert min(r) > 0.9, r


def test_a_weights_take_without_gaze_channels_is_keyed_from_its_eye_angles(track):
    keep = [i for i, n in enumerate(track.names) if not n.startswith("eyeLook")]
    no_gaze = replace(track, names=tuple(track.names[i] for i in keep), values=track.values[:, keep])
    names = tuple(track.names) + ("tongueOut",)
    settings = RetargetSettings((), (1, 1), strategy="parallel")
    res = retarget(None, sorted(set(names)), settings, inputs=StrategyInputs(weights=no_gaze))
    assert any("gaze (eyeLook*) from the take's eye angles" in w for w in res.warnings)
    k = res.shape_names.index("eyeLookDownLeft")
    recorded = track.values[:, track.names.index("eyeLookDownLeft")]
    ok = np.isfinite(recorded)
    assert np.corrcoef(res.weights[ok, k], recorded[ok])[0, 1] > 0.95
