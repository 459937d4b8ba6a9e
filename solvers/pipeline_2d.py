"""The geometric solve for 2D image tracks (video takes), against the character seen from the front."""

import time
import warnings

import numpy as np

from .diagnostics import basis_warnings
from .errors import FacecapError
from .neutral import neutral_from_frames
from .pipeline import RetargetResult, _reference_range, _residuals
from .shape_options import resolve_bounds, resolve_locks
from .stabilise import stabilise_2d
from .strategies.geometric import GeometricOptions, solve_geometric
from .transforms import fit_similarity_2d


def retarget_geometric_2d(markers, basis, settings):
    """Geometric solve from 2D image tracks against the character seen from the front (orthographic).

    Stabilised by a per-frame similarity on the stable points (in-plane head motion and distance to
    the camera; out-of-plane head turns are not removed), aligned to the projected bound points by a
    2D similarity on the neutral, solved with the same engine and priors as 3D takes.
    """
    notes = []
    t0 = time.perf_counter()
    used = tuple(n for n in basis.marker_names if n in set(markers.names))
    if len(used) < 3:
        raise FacecapError(
            f"{markers.source or 'take'}: only {len(used)} of its {markers.n_markers} tracks are bound on the "
            "character (need 3; tracks bind to vertex groups of the same name)"
        )
    stable = settings.stable_markers
    if isinstance(stable, str):
        raise FacecapError("2D takes need an explicit list of stable points ([stabilise] markers)")
    reference = _reference_range(settings)
    stab = stabilise_2d(markers, stable, reference_frames=reference, mode="similarity")
    if stab.flagged.any():
        notes.append(f"{int(stab.flagged.sum())} frame(s) could not be stabilised (too few stable points)")
    first, last = reference if reference else (markers.frames[0], markers.frames[-1])
    used_idx = markers.index(used)
    neutral = neutral_from_frames(stab.markers, first, last)[used_idx]
    sub = basis.subset_markers(used).front_view()
    align = fit_similarity_2d(neutral, sub.neutral)
    align_res = np.linalg.norm(align.apply(neutral) - sub.neutral, axis=1)
    deltas = align.apply_vectors(stab.markers.positions[:, used_idx] - neutral[None])
    timings = {"stabilise": time.perf_counter() - t0}
    lower, upper = resolve_bounds(basis.shape_names, basis.lower, basis.upper, settings.bounds)
    locks = resolve_locks(basis.shape_names, settings.locks)
    notes.extend(dict.fromkeys(basis_warnings(sub.matrix(), sub.shape_names)))
    options = GeometricOptions(
        regularisation=settings.regularisation, sparsity=settings.sparsity,
        symmetry=settings.symmetry, smoothing=tuple(settings.smoothing),
    )
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        solved = solve_geometric(sub, deltas, options=options, lower=lower, upper=upper,
                                 locks=None if np.isnan(locks).all() else locks)
    timings["solve"] = time.perf_counter() - t1
    notes.extend(solved.warnings)
    measured = ~np.isnan(deltas[:, :, 0])
    residual_rms, marker_residual = _residuals(solved.weights, sub.deltas, deltas, measured)
    timings["total"] = time.perf_counter() - t0
    return RetargetResult(
        frames=markers.frames,
        shape_names=basis.shape_names,
        weights=solved.weights,
        marker_names=used,
        residual_rms=residual_rms,
        marker_residual=marker_residual,
        at_bound=solved.at_bound,
        stabilise=stab,
        alignment=align,
        alignment_residual=align_res,
        warnings=tuple(notes) + ("2D take: solved against the character's front view (depth motion is not observed)",),
        timings={k: round(v, 6) for k, v in timings.items()},
    )
