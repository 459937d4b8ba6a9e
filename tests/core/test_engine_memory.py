"""The solve's diagnostics in bounded memory: per-marker residual norms computed in blocks of
frames equal those of the full residual array, which is then never built."""

import numpy as np

from facecap.solvers.engine import solve_bounded
from test_engine_refs import localised_basis, take


def test_residual_norms_in_blocks_are_the_full_residuals_norms():
    A = localised_basis(K=10, seed=2)
    W, D = take(A, F=700, seed=3)
    D[50:60] = np.nan
    mask = np.where(np.isfinite(D), np.random.default_rng(1).uniform(0.0, 1.5, size=D.shape), 0.0)
    mask[:, :3] = 0.0  # coordinates never trusted: residual 0 there
    for kw in (dict(), dict(mask=mask), dict(smoothing=(0.0, 0.3), relative=True)):
        res = solve_bounded(A, D, regularisation=1e-4, **kw)
        norms = res.residual_norms(3, block=64)
        assert callable(res._residuals)  # the (F, P) array was not built
        full = (res.residuals.reshape(700, -1, 3) ** 2).sum(axis=2)
        np.testing.assert_allclose(norms, full, rtol=1e-12, atol=1e-30)
        assert np.array_equal(res.residual_norms(3), full)  # once built, the same array's
