"""parallel: copy solved weights by name/alias with gain, offset, clamp, curve, mirror and a neutral offset."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from facecap.solvers.errors import FacecapError
from facecap.solvers.strategies.parallel import ParallelStrategy

CHAR = ("eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthSmileLeft", "mouthSmileRight")
LLF = ("EyeBlinkLeft", "EyeBlinkRight", "JawOpen", "MouthSmileLeft", "MouthSmileRight", "HeadYaw")


def source(F=5, seed=0):
    return np.random.default_rng(seed).uniform(0, 1, size=(F, len(LLF)))


def test_identity_copy_by_alias_and_unmapped_channel_warning():
    x = source()
    r = ParallelStrategy().fit(CHAR, source_names=LLF).solve(x)
    assert r.shape_names == CHAR
    assert_allclose(r.weights, x[:, :5], atol=0)
    assert any("HeadYaw" in w for w in r.warnings)


def test_gain_offset_clamp_per_channel():
    x = source()
    s = ParallelStrategy(gain={"jawOpen": 2.0, "*": 0.5}, offset={"EyeBlinkLeft": 0.1}, clamp=(0.0, 0.8))
    r = s.fit(CHAR, source_names=LLF).solve(x)
    expect = 0.5 * x[:, :5]
    expect[:, 2] = 2.0 * x[:, 2]
    expect[:, 0] += 0.1
    assert_allclose(r.weights, np.clip(expect, 0.0, 0.8), atol=1e-15)
    assert_allclose(r.clamped, ((expect < 0) | (expect > 0.8)).sum(axis=1))


def test_clamp_defaults_to_the_character_bounds():
    r = ParallelStrategy(gain=3.0).fit(CHAR, source_names=LLF).solve(source())
    assert r.weights.min() >= 0.0 and r.weights.max() <= 1.0 and r.clamped.sum() > 0


def test_curves():
    x = np.linspace(0, 1, 11)[:, None] * np.ones((1, len(LLF)))
    g = ParallelStrategy(curve={"jawOpen": "gamma:0.5", "mouthSmileLeft": "smoothstep"}).fit(CHAR, source_names=LLF)
    w = g.solve(x).weights
    assert_allclose(w[:, 2], np.sqrt(x[:, 2]))
    assert_allclose(w[:, 3], x[:, 3] ** 2 * (3 - 2 * x[:, 3]))
    assert_allclose(w[:, 0], x[:, 0])
    with pytest.raises(FacecapError, match="unknown curve"):
        ParallelStrategy(curve="cubic")
    with pytest.raises(FacecapError, match="positive exponent"):
        ParallelStrategy(curve="gamma:-1")


def test_mirror_swaps_left_and_right():
    x = source()
    w = ParallelStrategy(mirror=True).fit(CHAR, source_names=LLF).solve(x).weights
    assert_allclose(w[:, 0], x[:, 1])
    assert_allclose(w[:, 1], x[:, 0])
    assert_allclose(w[:, 2], x[:, 2])
    assert_allclose(w[:, 3], x[:, 4])


def test_neutral_offset_from_a_neutral_segment():
    rng = np.random.default_rng(1)
    bias = np.array([0.1, 0.05, 0.0, 0.2, 0.2, 0.0])
    x = np.clip(source(20) * 0.5 + bias, 0, 1)
    neutral_segment = bias + rng.normal(0, 0.001, size=(30, len(LLF)))
    w = ParallelStrategy().fit(CHAR, source_names=LLF, neutral=neutral_segment).solve(x).weights
    assert_allclose(w, np.clip(x[:, :5] - np.median(neutral_segment, axis=0)[:5], 0, 1), atol=1e-15)


def test_many_to_many_mapping_table_and_reordered_source():
    x = source()
    table = {"JawOpen": {"jawOpen": 1.0, "mouthSmileLeft": 0.5}}
    s = ParallelStrategy(mapping=table).fit(CHAR, source_names=LLF)
    w = s.solve(x[:, ::-1], names=LLF[::-1]).weights
    assert_allclose(w[:, 3], np.clip(x[:, 3] + 0.5 * x[:, 2], 0, 1))
    assert_allclose(w[:, 2], x[:, 2])


def test_missing_source_values_stay_missing():
    x = source()
    x[2, 0] = np.nan
    r = ParallelStrategy().fit(CHAR, source_names=LLF).solve(x)
    assert np.isnan(r.weights[2, 0]) and np.isfinite(r.weights[2, 1:]).all()


def test_unknown_shape_in_options_is_named():
    with pytest.raises(FacecapError, match="gain.*unknown character shape.*noseWiggle"):
        ParallelStrategy(gain={"noseWiggle": 2.0}).fit(CHAR, source_names=LLF)
