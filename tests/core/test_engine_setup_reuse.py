"""``reuse_pattern_setup``: solves of one take that share each gap pattern's Hessian, inverse and
condition flag give bit-identical weights to solves that compute them afresh."""

import numpy as np
import pytest

from facecap.solvers.engine import frames as engine_frames, temporal as engine_temporal
from facecap.solvers.engine import solve_bounded
from facecap.solvers.engine.frames import PatternSetup, reuse_pattern_setup
from test_engine_refs import localised_basis

KW = dict(regularisation=1e-4, sparsity=0.01, relative=True, chunk=64)


def gappy_take(A, F=400, seed=1, dims=3):
    """Weights, deltas and a refit's deltas (a small drift) with per-marker gaps in runs: patterns
    repeat within and across chunks, as in a capture."""
    rng = np.random.default_rng(seed)
    K = A.shape[1]
    M = A.shape[0] // dims
    W = np.clip(rng.normal(0.1, 0.45, size=(F, K)), -0.2, 1.0)
    D = W @ A.T + rng.normal(0, 2e-4, size=(F, A.shape[0]))
    gone = np.zeros((F, M), bool)
    for m in rng.choice(M, size=6, replace=False):
        for start in rng.integers(0, F, size=4):
            gone[start : start + rng.integers(3, 40), m] = True
    D[np.repeat(gone, dims, axis=1)] = np.nan
    drift = 3e-4 * np.sin(np.linspace(0, 3, F))[:, None] * rng.normal(size=A.shape[0])
    return D, D + drift


def identical(a, b):
    assert a.weights.shape == b.weights.shape
    assert np.array_equal(a.weights, b.weights, equal_nan=True)
    assert a.iterations == b.iterations and a.fallback_frames == b.fallback_frames


def pipeline_like(A, D1, D2, smoothing=(0.0, 0.3), **kw):
    """Two quick refits and a final solve, each starting from the one before (as the pipeline)."""
    r1 = solve_bounded(A, D1, max_iter=2, exact=False, **kw)
    r2 = solve_bounded(A, D2, max_iter=2, exact=False, start=r1.weights, **kw)
    r3 = solve_bounded(A, D2, smoothing=smoothing, start=r2.weights, **kw)
    return r1, r2, r3


@pytest.mark.parametrize("lower", [0.0, -1.0])  # -1: L1 kinks at 0
def test_per_frame_solves_with_other_data_are_bit_identical(lower):
    A = localised_basis(K=12, seed=2)
    D1, D2 = gappy_take(A)
    kw = dict(KW, lower=lower)
    outside = [solve_bounded(A, D, **kw) for D in (D1, D2, D1)]
    with reuse_pattern_setup() as setup:
        inside = [solve_bounded(A, D, **kw) for D in (D1, D2, D1)]
        (products,) = setup.problems.values()
        n_pat = engine_frames.patterns(np.isfinite(D1))[0].shape[0]
        assert len(products.index) == n_pat  # each pattern once, whatever the chunks
    for a, b in zip(outside, inside):
        identical(a, b)


def test_quick_refits_and_temporal_solve_are_bit_identical(monkeypatch):
    A = localised_basis(K=12, seed=3)
    D1, D2 = gappy_take(A, F=600, seed=4)
    outside = pipeline_like(A, D1, D2, **KW)
    made = []

    def counted(real):
        def f(*a, **k):
            made.append(k.get("products"))
            return real(*a, **k)

        return f

    for name in ("pattern_hessians", "pattern_inverses"):  # count the products computed
        monkeypatch.setattr(engine_frames, name, counted(getattr(engine_frames, name)))
    with reuse_pattern_setup():
        first = solve_bounded(A, D1, max_iter=2, exact=False, **KW)
        n_made = sum(p is None for p in made)
        assert n_made > 0
        inside = (first,) + pipeline_like(A, D1, D2, **KW)[1:]
        assert sum(p is None for p in made) == n_made  # the later solves computed none
    for a, b in zip(outside, inside):
        identical(a, b)
    # the long-take path: halves in a forked child and here, then the seam
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 200)
    split_out = solve_bounded(A, D2, smoothing=(0.0, 0.3), **KW)
    with reuse_pattern_setup():
        solve_bounded(A, D1, **KW)
        split_in = solve_bounded(A, D2, smoothing=(0.0, 0.3), **KW)
    identical(split_out, split_in)


def test_temporal_solve_first_then_per_frame():
    """A temporal solve keeps only Hessians; a per-frame one after it adds the inverses."""
    A = localised_basis(K=10, seed=5)
    D1, D2 = gappy_take(A, F=300, seed=6)
    kw = dict(KW, lower=-1.0)
    out = [solve_bounded(A, D1, smoothing=(0.1, 0.3), **kw), solve_bounded(A, D2, **kw)]
    with reuse_pattern_setup():
        inside = [solve_bounded(A, D1, smoothing=(0.1, 0.3), **kw), solve_bounded(A, D2, **kw)]
    for a, b in zip(out, inside):
        identical(a, b)


def test_regions_symmetry_and_locks_key_on_the_kernel_problem():
    """Regions give each region its own A and R (and symmetry changes R): each is kept apart."""
    A = localised_basis(P_markers=40, K=12, seed=7)
    D1, D2 = gappy_take(A, F=300, seed=8)
    P = A.shape[0]
    regions = [(np.arange(0, 6), np.arange(0, P // 2)), (np.arange(6, 11), np.arange(P // 3, P))]  # shape 11 held
    locks = np.full((D1.shape[0], 12), np.nan)
    locks[100:140, 2] = 0.3
    kw = dict(KW, regions=regions, symmetry=[(0, 1)], symmetry_weight=0.05, locks=locks, lower=-0.5)
    outside = pipeline_like(A, D1, D2, **kw)
    with reuse_pattern_setup() as setup:
        inside = pipeline_like(A, D1, D2, **kw)
        assert len(setup.problems) == 2
        # another symmetry weight changes R of the region holding the pair only: one more problem
        solve_bounded(A, D1, **dict(kw, symmetry_weight=0.5))
        assert len(setup.problems) == 3
    for a, b in zip(outside, inside):
        identical(a, b)


def test_scope_nesting_and_a_shared_setup():
    A = localised_basis(K=8, seed=9)
    D1, D2 = gappy_take(A, F=200, seed=10)
    ref = solve_bounded(A, D2, **KW)
    assert engine_frames.reusable(A, np.eye(8), np.zeros((1, 1), bool)) is None  # outside: nothing
    setup = PatternSetup()
    with reuse_pattern_setup(setup):
        solve_bounded(A, D1, **KW)
        with reuse_pattern_setup() as inner:  # nested: the outer one
            assert inner is setup
    assert engine_frames._REUSE.get() is None
    kept = next(iter(setup.problems.values()))
    n = len(kept.index)
    with reuse_pattern_setup(setup):  # a later block with the same setup reuses it
        identical(ref, solve_bounded(A, D2, **KW))
    assert len(kept.index) == n


def test_threads_share_one_setup():
    """Chunks on worker threads read the products the solving thread prepared."""
    A = localised_basis(K=10, seed=11)
    D1, D2 = gappy_take(A, F=500, seed=12)
    C = np.isfinite(D1)
    R = 1e-3 * np.eye(10)
    G = np.where(C, D1, 0.0) @ A
    lo, hi, lam = np.zeros((500, 10)), np.ones((500, 10)), np.full(10, 1e-4)
    ref = engine_frames.solve_frames(A, C, G, R, lo, hi, lam, chunk=50, workers=4)
    with reuse_pattern_setup():
        for workers in (4, 1, 2):
            got = engine_frames.solve_frames(A, C, G, R, lo, hi, lam, chunk=50, workers=workers)
            assert np.array_equal(ref[0], got[0]) and ref[1:] == got[1:]


@pytest.mark.parametrize("room", [0, 10, 10**9])  # patterns that fit: none, some, all
def test_a_bounded_setup_keeps_what_fits_and_gives_the_same_bits(monkeypatch, room):
    """``PatternSetup(max_bytes)`` keeps at most that many bytes of products (Hessian and inverse
    per pattern): all of a take's patterns, or none when they do not all fit (the per-frame solve
    sees the whole take first); the others are computed where needed: the same bits in every case."""
    A = localised_basis(K=12, seed=13)
    D1, D2 = gappy_take(A, F=600, seed=14)
    K = A.shape[1]
    outside = pipeline_like(A, D1, D2, **KW)
    setup = PatternSetup(max_bytes=room * 2 * K * K * 8)
    with reuse_pattern_setup(setup):
        inside = pipeline_like(A, D1, D2, **KW)
    monkeypatch.setattr(engine_temporal, "SPLIT_FRAMES", 200)  # and the windowed temporal solve
    split_out = solve_bounded(A, D2, smoothing=(0.0, 0.3), **KW)
    with reuse_pattern_setup(setup):
        split_in = solve_bounded(A, D2, smoothing=(0.0, 0.3), **KW)
    n_pat = engine_frames.patterns(np.isfinite(D1))[0].shape[0]
    (products,) = setup.problems.values()
    assert len(products.index) == (n_pat if room >= n_pat else 0) and n_pat > 10
    for a, b in zip(outside + (split_out,), inside + (split_in,)):
        identical(a, b)


def test_products_asked_for_piecewise_are_kept_while_they_fit():
    """Patterns asked for a piece at a time (the windows of a temporal solve) are kept until the
    room runs out; the rest are computed, the same bits as kept ones."""
    A = localised_basis(K=12, seed=15)
    D1, _ = gappy_take(A, F=600, seed=16)
    K = A.shape[1]
    pats = engine_frames.patterns(np.isfinite(D1))[0]
    R = 1e-3 * np.eye(K)
    setup = PatternSetup(max_bytes=7 * 2 * K * K * 8)
    with reuse_pattern_setup(setup):
        products = engine_frames.reusable(A, R, pats)
        first = products.hessians(A, pats[:5], R)
        every = products.hessians(A, pats, R)
    assert len(products.index) == 7
    assert np.array_equal(every, engine_frames.pattern_hessians(A, pats, R)) and np.array_equal(first, every[:5])
