"""The geometric solve in bounded memory (issue 18): given its deltas (``overwrite=True``, as the
pipeline does), it aligns them in their own memory instead of a second (F, M, D) array, with the
same weights bit for bit; marker deltas are copied only to make a partly missing sample whole; a
solve the priors hold at 0 while the markers move is still refused after the deltas are given up."""

import tracemalloc

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from synthetic_face import make_basis

from facecap.solvers import FacecapError, RetargetSettings, retarget
from facecap.solvers.engine import split as engine_split
from facecap.solvers.strategies import geometric
from facecap.solvers.strategies.geometric import GeometricStrategy
from facecap.solvers.strategies.sources import as_deltas
from facecap.solvers.tools.synthetic.synth import synthesize_take
from facecap.solvers.transforms import Similarity


def _actor_take(F, seed=0, partial=0):
    """(basis, marker names, actor-space deltas (F, M, 3), actor neutral (M, 3)): the take's markers in
    another order than the character's, one of them unbound, the actor 1.2x the character and turned,
    gaps of whole markers and ``partial`` samples with one missing coordinate."""
    basis, _ = make_basis()
    rng = np.random.default_rng(seed)
    K, M, _ = basis.deltas.shape
    W = np.clip(rng.uniform(-0.3, 1.0, size=(F, K)), 0, 1)
    R, s = Rotation.from_rotvec([0.1, -0.25, 0.05]).as_matrix(), 1.2
    char = (W @ basis.deltas.reshape(K, -1)).reshape(F, M, 3)
    order = rng.permutation(M)
    deltas = np.concatenate([s * char @ R.T, rng.normal(0, 1e-3, (F, 1, 3))], axis=1)[:, [*order, M]]
    deltas += rng.normal(0, 2e-4, deltas.shape)
    deltas[rng.random(deltas.shape[:2]) < 0.05] = np.nan
    for _ in range(partial):
        deltas[rng.integers(F), rng.integers(M), rng.integers(3)] = np.nan
    neutral = np.concatenate([s * basis.neutral @ R.T, [[0.0, 0.0, 0.2]]])[[*order, M]]
    names = tuple(np.array(basis.marker_names)[order]) + ("unbound",)
    return basis, names, np.ascontiguousarray(deltas), neutral


@pytest.mark.parametrize("alignment", [None, Similarity(1.3, Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix(),
                                                        np.zeros(3))])
@pytest.mark.parametrize("idx", ["same", "permuted", "fewer"])
def test_deltas_taken_over_their_own_memory_are_the_copy(monkeypatch, alignment, idx):
    rng = np.random.default_rng(4)
    deltas = rng.normal(size=(1000, 12, 3))
    deltas[rng.random((1000, 12)) < 0.1] = np.nan
    cols = {"same": list(range(12)), "permuted": list(rng.permutation(12)), "fewer": [11, 0, 5, 3, 9, 1, 2]}[idx]
    monkeypatch.setattr(geometric, "BLOCK", 64)  # 16 blocks, the last one short
    copied = geometric.taken_markers(deltas, cols, alignment)
    given = deltas.copy()
    taken = geometric.taken_markers(given, cols, alignment, overwrite=True)
    assert np.array_equal(taken, copied, equal_nan=True)
    assert np.shares_memory(taken, given)  # no second array
    assert not np.shares_memory(copied, deltas)  # without overwrite the input is left alone


def test_deltas_are_copied_only_to_make_a_partly_missing_sample_whole():
    _, _, deltas, _ = _actor_take(50)
    assert as_deltas(deltas) is deltas  # gaps of whole markers: nothing to change
    partly = deltas.copy()
    partly[3, 7, 1] = np.nan
    whole = as_deltas(partly)
    assert whole is not partly and np.isnan(whole[3, 7]).all() and not np.isnan(partly[3, 7, 0])  # input untouched
    given = as_deltas(partly, overwrite=True)
    assert given is partly and np.isnan(partly[3, 7]).all()


def _solve(strategy, names, deltas, neutral, overwrite):
    return strategy.solve(deltas, names=names, neutral=neutral, overwrite=overwrite)


def test_a_solve_given_its_deltas_is_the_same_and_needs_no_second_copy(monkeypatch):
    monkeypatch.setattr(engine_split, "fork_available", lambda: False)  # every allocation in this process
    basis, names, deltas, neutral = _actor_take(6000, partial=20)
    strategy = GeometricStrategy().fit(basis, names=names)
    kept = _solve(strategy, names, deltas.copy(), neutral, overwrite=False)
    given = _solve(strategy, names, deltas.copy(), neutral, overwrite=True)
    for field in ("weights", "residual_rms", "solved"):
        assert np.array_equal(getattr(given, field), getattr(kept, field), equal_nan=True), field
    assert np.array_equal(given.solve.residual_norms(3), kept.solve.residual_norms(3), equal_nan=True)

    def peak(overwrite):
        data = deltas.copy()
        tracemalloc.start()
        try:
            _solve(strategy, names, data, neutral, overwrite)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    aligned = deltas.shape[0] * len(basis.marker_names) * 3 * 8  # the (F, U, D) array it no longer makes
    saved = peak(False) - peak(True)
    print(f"peak saved {saved / 2**20:.1f} MiB; an aligned copy is {aligned / 2**20:.1f} MiB")
    assert saved >= 0.9 * aligned


def test_a_solve_the_priors_hold_at_zero_is_refused_only_when_the_markers_move():
    basis, stable = make_basis()
    W = np.clip(np.random.default_rng(3).uniform(-0.5, 1.0, size=(200, basis.n_shapes)), 0, 1)
    W[:60] = 0
    held = RetargetSettings(stable, (1, 50), regularisation=1e12)
    moving = synthesize_take(basis, W, stable=stable, noise_sigma=0.0)
    with pytest.raises(FacecapError, match=r"every solved weight is 0 although the markers move \(\d+\.\d mm RMS"):
        retarget(moving.markers, basis, held)
    still = synthesize_take(basis, np.zeros_like(W), stable=stable, noise_sigma=0.0)  # the face does not move
    r = retarget(still.markers, basis, held)
    assert np.nanmax(np.abs(r.weights)) <= 1e-6
