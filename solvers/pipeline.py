"""The retarget pipeline, Blender-free: markers + character basis -> shape-key weights.

source -> units -> stabilise (rigid, stable markers) -> neutral -> align actor to character
(similarity on the neutral) -> strategy solve -> diagnostics.
"""

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .engine import DEFAULT_SMOOTHING
from .errors import FacecapError
from .diagnostics import basis_warnings
from .neutral import neutral_from_frames
from .shape_options import resolve_bounds, resolve_locks, resolve_regions
from .stabilise import refine_rigid, smooth_head_motion, stabilise_rigid
from .strategies.geometric import GeometricOptions, solve_geometric
from .transforms import fit_similarity

STRATEGIES = ("geometric",)


@dataclass(frozen=True)
class RetargetSettings:
    """Everything a retarget needs besides the data; built from the take config or the sidebar."""

    stable_markers: tuple
    neutral_frames: tuple  # (first, last), inclusive
    strategy: str = "geometric"
    regularisation: float = 1e-3
    sparsity: float = 1e-3
    symmetry: float = 0.0
    smoothing: tuple = DEFAULT_SMOOTHING
    fine_iterations: int = 2  # hierarchical stabilisation: refits of the head on all markers
    fine_weight: float = 1.0  # trust of deforming markers in the refit, relative to stable ones
    head_smoothing: float = 0.1  # half-window (s) of the zero-phase head-pose smoothing; 0 = off
    bounds: tuple = ()  # ((shape pattern, lower, upper), ...) overriding the slider ranges
    locks: tuple = ()  # ((shape pattern, value), ...) shapes held fixed (animator-owned)
    regions: tuple = ()  # (Region, ...) shapes solved from their own marker subsets


@dataclass(frozen=True, eq=False)
class RetargetResult:
    """Solved weights plus everything needed to judge them."""

    frames: np.ndarray  # (F,)
    shape_names: tuple
    weights: np.ndarray  # (F, K), NaN where a frame could not be solved
    marker_names: tuple  # markers used in the solve
    residual_rms: np.ndarray  # (F,) RMS marker residual in character space (metres)
    marker_residual: np.ndarray  # (M,) RMS residual per marker over the take (metres)
    at_bound: np.ndarray  # (F,)
    stabilise: object  # StabiliseResult
    alignment: object  # Similarity, actor neutral -> character bound points
    alignment_residual: np.ndarray  # (M,) per-marker distance after alignment (metres)
    warnings: tuple = ()
    timings: dict = field(default_factory=dict)

    def report(self):
        """A JSON-ready summary (lengths in millimetres)."""
        ok = np.isfinite(self.residual_rms)
        return {
            "frames": {"count": int(self.frames.size), "first": float(self.frames[0]), "last": float(self.frames[-1])},
            "shapes": list(self.shape_names),
            "markers_used": list(self.marker_names),
            "stable_markers": list(self.stabilise.stable_names),
            "residual_rms_mm": {
                "mean": float(np.mean(self.residual_rms[ok]) * 1e3) if ok.any() else None,
                "max": float(np.max(self.residual_rms[ok]) * 1e3) if ok.any() else None,
                "per_frame": [None if not np.isfinite(v) else round(float(v) * 1e3, 6) for v in self.residual_rms],
            },
            "marker_residual_mm": {n: round(float(v) * 1e3, 6) for n, v in zip(self.marker_names, self.marker_residual)},
            "stabilise": {
                "rms_mm_mean": float(np.nanmean(self.stabilise.rms) * 1e3) if np.isfinite(self.stabilise.rms).any() else None,
                "flagged_frames": {str(k): v for k, v in self.stabilise.flag_reasons.items()},
                "stable_marker_trust": {k: round(v, 3) for k, v in self.stabilise.marker_trust.items()},
            },
            "alignment": {
                "scale": self.alignment.scale,
                "rotation": self.alignment.rotation,
                "translation_m": self.alignment.translation,
                "residual_mm": {n: round(float(v) * 1e3, 6) for n, v in zip(self.marker_names, self.alignment_residual)},
            },
            "weights_at_bound_mean": float(np.mean(self.at_bound)),
            "timings_s": self.timings,
            "warnings": list(self.warnings),
        }


def retarget(markers, basis, settings):
    """Retarget a marker take onto a character basis.

    Parameters
    ----------
    markers : MarkerSet, 3D, any of m/cm/mm
    basis : Basis, the character's shapes at the bound points (metres)
    settings : RetargetSettings

    Returns
    -------
    RetargetResult
    """
    if settings.strategy not in STRATEGIES:
        raise FacecapError(f"unknown strategy '{settings.strategy}'; available: {', '.join(STRATEGIES)}")
    timings = {}
    notes = []
    t0 = time.perf_counter()
    markers = markers.to_units("m")

    used = tuple(n for n in basis.marker_names if n in set(markers.names))
    unbound = [n for n in markers.names if n not in set(basis.marker_names)]
    absent = [n for n in basis.marker_names if n not in set(markers.names)]
    if unbound:
        notes.append(f"{len(unbound)} marker(s) have no binding on the character and are not solved from: {unbound}")
    if absent:
        notes.append(f"{len(absent)} bound point(s) have no marker in the take: {absent}")
    if len(used) < 3:
        raise FacecapError(
            f"only {len(used)} marker(s) of the take are bound on the character; "
            f"take markers: {list(markers.names)[:10]}..., bound: {list(basis.marker_names)[:10]}..."
        )

    half_window = int(round(settings.head_smoothing * markers.fps))
    options = GeometricOptions(
        regularisation=settings.regularisation,
        sparsity=settings.sparsity,
        symmetry=settings.symmetry,
        smoothing=tuple(settings.smoothing),
    )
    stab = stabilise_rigid(markers, settings.stable_markers, reference_frames=settings.neutral_frames)
    stab = smooth_head_motion(markers, stab, half_window=half_window)
    moving = [n for n, w in stab.marker_trust.items() if w < 0.5]
    if moving:
        notes.append(f"stable marker(s) {moving} move relative to the others and were left out of the head fit")
    if stab.flagged.any():
        bridged = any(settings.smoothing)
        notes.append(
            f"{int(stab.flagged.sum())} frame(s) could not be stabilised; their weights are "
            + ("bridged by the temporal smoothing" if bridged else "left unsolved")
        )
    timings["stabilise"] = time.perf_counter() - t0

    first, last = settings.neutral_frames
    sub = basis.subset_markers(used)
    lower, upper = resolve_bounds(basis.shape_names, basis.lower, basis.upper, settings.bounds)
    locks = resolve_locks(basis.shape_names, settings.locks)
    regions, held = resolve_regions(basis.shape_names, used, settings.regions, dims=3)
    if held:
        notes.append(f"{len(held)} shape(s) are in no region and are held: {list(held)}")
    notes.extend(dict.fromkeys(basis_warnings(sub.matrix(), sub.shape_names)))  # unique, in order
    used_idx = markers.index(used)
    stable_set = set(settings.stable_markers)
    trust = np.array([1.0 if n in stable_set else settings.fine_weight for n in used])
    t_solve = t_align = 0.0
    for iteration in range(settings.fine_iterations + 1):
        t1 = time.perf_counter()
        neutral = neutral_from_frames(stab.markers, first, last)[used_idx]
        align = fit_similarity(neutral, sub.neutral)
        deltas = align.apply_vectors(stab.markers.positions[:, used_idx] - neutral[None])
        t2 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            # The refits only need a prediction of the face: per-frame solves are enough there
            # and much cheaper; the final solve uses the full (temporal) options.
            final = iteration == settings.fine_iterations
            solved = solve_geometric(
                sub, deltas, options=options if final else replace(options, smoothing=(0.0, 0.0)),
                lower=lower, upper=upper,
                locks=None if np.isnan(locks).all() else locks, regions=regions,
            )
        t3 = time.perf_counter()
        t_align += t2 - t1
        t_solve += t3 - t2
        if iteration == settings.fine_iterations:
            break
        # Hierarchical stabilisation: refit the head on all markers against the solve's prediction.
        char_pred = np.einsum("fk,kmd->fmd", np.nan_to_num(solved.weights), sub.deltas)
        predicted = neutral[None] + align.inverse_vectors(char_pred)
        predicted[~solved.solved] = np.nan
        stab = refine_rigid(markers, stab, used, predicted, weights=trust)
        stab = smooth_head_motion(markers, stab, half_window=half_window)
        timings["stabilise"] += time.perf_counter() - t3
    align_res = np.linalg.norm(align.apply(neutral) - sub.neutral, axis=1)
    timings["align"] = t_align
    timings["solve"] = t_solve
    notes.extend(solved.warnings)

    measured = ~np.isnan(deltas[:, :, 0])
    res = np.einsum("fk,kmd->fmd", np.nan_to_num(solved.weights), sub.deltas) - deltas
    sq = np.where(measured, (res**2).sum(axis=2), 0.0)
    vis = measured
    with np.errstate(invalid="ignore", divide="ignore"):
        residual_rms = np.sqrt(sq.sum(axis=1) / vis.sum(axis=1))
        marker_residual = np.sqrt(sq.sum(axis=0) / vis.sum(axis=0))
    residual_rms[~solved.solved] = np.nan
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
        warnings=tuple(notes),
        timings={k: round(v, 6) for k, v in timings.items()},
    )
