"""The geometric solve for 2D image tracks (video takes), against the character seen from the front
(orthographic) or through the scene camera (perspective, ``solvers.camera``)."""

import time
import warnings

import numpy as np

from ..character.basis import Basis
from ..character.diagnostics import basis_warnings
from ..errors import FacecapError
from ..capture.neutral import neutral_from_frames
from . import RetargetResult, _reference_range, _residuals
from ..character.shape_options import resolve_bounds, resolve_locks
from ..capture.stabilise import stabilise_2d
from ..strategies.geometric import GeometricOptions, solve_geometric
from ..transforms import fit_similarity_2d


def retarget_geometric_2d(markers, basis, settings, *, projection=None):
    """Geometric solve from 2D image tracks against the character's projected bound points.

    Stabilised by a per-frame similarity on the stable points (in-plane head motion and distance to
    the camera; out-of-plane head turns are not removed), aligned to the projected bound points by a
    2D similarity on the neutral, solved with the same engine and priors as 3D takes.

    ``projection`` (default ``settings.projection`` when the settings carry one): ``None`` or
    ``"front"`` - the orthographic front view; a ``solvers.camera.Camera`` seeing the basis'
    coordinates (``Camera.relative_to`` the character's world matrix) - shape deltas projected
    through it linearised at the neutral (``Camera.project_basis``). Camera pixels are scaled by the units a pixel spans at the face so
    residuals read in scene units (metres for a metre-scale rig), as with the front view.
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
    sub, view = _projected(basis.subset_markers(used), getattr(settings, "projection", None)
                           if projection is None else projection)
    align = fit_similarity_2d(neutral, sub.neutral)
    align_res = np.linalg.norm(align.apply(neutral) - sub.neutral, axis=1)
    deltas = align.apply_vectors(stab.markers.positions[:, used_idx] - neutral[None])
    timings = {"stabilise": time.perf_counter() - t0}
    lower, upper = resolve_bounds(basis.shape_names, basis.lower, basis.upper, settings.bounds)
    locks = resolve_locks(basis.shape_names, settings.locks, n_frames=markers.frames.size)
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
    residual_rms, marker_residual, frame_marker = _residuals(solved.weights, sub.deltas, deltas, measured)
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
        frame_marker_residual=frame_marker,
        warnings=tuple(notes) + (view,),
        timings={k: round(v, 6) for k, v in timings.items()},
    )


def _projected(basis, projection):
    """(2D basis, note) for ``projection``: None / "front" or a Camera."""
    from ..character.camera import Camera

    if projection is None or projection == "front":
        return basis.front_view(), "2D take: solved against the character's front view (depth motion is not observed)"
    if not isinstance(projection, Camera):
        raise FacecapError(f"2D takes: projection must be 'front' or a camera; got {projection!r} "
                           "(projection = \"camera\" needs the scene camera read from the .blend)")
    seen = basis.camera_view(projection)
    unit = projection.units_per_pixel(basis.neutral)
    scaled = Basis(seen.shape_names, seen.marker_names, seen.neutral * unit, seen.deltas * unit, seen.lower, seen.upper)
    return scaled, (f"2D take: solved against the character seen through the camera "
                    f"({unit * 1e3:.3f} mm (scene units x 1000) per pixel at the face; depth motion along the view is "
                    "not observed)")


#: marker strategies that solve 2D image tracks natively (their fits are dimension-free)
STRATEGIES_2D = ("calibrated", "linear", "rbf", "pca")


def prepare_take_2d(markers, stable_markers, neutral_frames):
    """2D counterpart of ``strategies.wiring.prepare_take``: image tracks (pixels) stabilised by a
    per-frame similarity on ``stable_markers`` (reference = the neutral frames), minus the neutral."""
    from ..strategies.wiring import PreparedTake

    stable = tuple(stable_markers)
    if not stable:
        raise FacecapError("2D takes need an explicit list of stable points ([stabilise] markers)")
    first, last = neutral_frames
    stab = stabilise_2d(markers, stable, reference_frames=(first, last), mode="similarity")
    neutral = neutral_from_frames(stab.markers, first, last)
    return PreparedTake(stab.markers.positions - neutral[None], neutral, markers.names, markers.frames, stab)


def retarget_markers_2d(markers, character, settings, inputs):
    """``calibrated``, ``linear``, ``rbf`` or ``pca`` from 2D image tracks, natively in pixels.

    The take is stabilised in 2D (similarity on the stable points) and neutral-normalised; the
    strategy is fitted on 2D data of the same kind: a filmed calibration take (poses = frame
    ranges, basis in pixels; ``[calibration] align`` "similarity" absorbs a different zoom), or
    posed example frames of a tracked take. Nothing of the character's geometry is used.
    """
    from . import _target, fit_and_solve, strategy_marker_residuals
    from ..strategies.wiring import require_inputs

    if settings.strategy not in STRATEGIES_2D:
        raise FacecapError(f"strategy '{settings.strategy}' does not solve 2D image tracks; "
                           f"use one of geometric, {', '.join(STRATEGIES_2D)}")
    require_inputs(settings.strategy, inputs, settings)
    for what, take in (("[calibration] markers", inputs.calibration),
                       ("[examples] markers", getattr(inputs.examples, "markers", None))):
        if take is not None and take.dim != 2:
            raise FacecapError(f"{what}: a 2D take needs 2D tracks here too; got {take.dim}D markers")
    if isinstance(settings.stable_markers, str) or getattr(settings, "auto_stable", False):
        raise FacecapError("2D takes need an explicit list of stable points ([stabilise] markers)")
    notes = list(inputs.notes)
    t0 = time.perf_counter()
    neutral_frames = _reference_range(settings) or (markers.frames[0], markers.frames[-1])

    def prepare(take_markers):
        return prepare_take_2d(take_markers, settings.stable_markers, neutral_frames)

    take = prepare(markers)
    stab = take.stabilise
    if stab.flagged.any():
        notes.append(f"{int(stab.flagged.sum())} frame(s) could not be stabilised (too few stable points)")
    target = _target(character, settings)
    timings = {"stabilise": time.perf_counter() - t0}
    strategy, res, weights = fit_and_solve(settings, target, inputs, take, prepare, notes, timings)
    used, marker_residual, frame_marker = strategy_marker_residuals(strategy, res, take)
    F = take.frames.size
    at_bound = res.solve.at_bound if res.solve is not None else res.clamped
    residual = np.full(F, np.nan) if res.residual_rms is None else np.asarray(res.residual_rms, dtype=np.float64)
    timings["total"] = time.perf_counter() - t0
    return RetargetResult(
        frames=take.frames, shape_names=target.names, weights=weights, marker_names=used,
        residual_rms=residual, marker_residual=marker_residual,
        at_bound=np.zeros(F, dtype=int) if at_bound is None else np.asarray(at_bound),
        stabilise=stab, alignment=None, alignment_residual=None,
        warnings=tuple(dict.fromkeys(notes + ["2D take: residuals are in pixels of the footage"])),
        timings={k: round(v, 6) for k, v in timings.items()}, strategy=settings.strategy,
        residual_space="actor" if res.residual_rms is not None else None, source_weights=res.source_weights,
        source_names=tuple(res.source_names), info=dict(res.info), fitted=strategy,
        frame_marker_residual=frame_marker,
    )
