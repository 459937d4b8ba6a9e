"""The retarget pipeline, Blender-free: markers + character basis -> shape-key weights.

geometric: source -> units -> stabilise (rigid, stable markers, hierarchical refits) -> neutral ->
align actor to character (similarity on the neutral) -> bounded solve -> diagnostics.

Every other marker strategy (calibrated, refine, linear, rbf, pca) shares the stabilisation and
the neutral, then receives the ACTOR-space deltas and the take's neutral (no similarity step: each
strategy aligns onto what it was fitted on) and is fitted from ``StrategyInputs``.
``parallel`` copies already-solved weights (``inputs.weights``) and needs no markers.
"""

import time
import warnings
from contextlib import nullcontext
from dataclasses import dataclass, field, replace

import numpy as np

from ..character.basis import Basis
from ..engine import DEFAULT_SMOOTHING
from ..engine.frames import PatternSetup, reuse_pattern_setup
from ..errors import FacecapError
from ..character.diagnostics import basis_warnings
from ..character.shape_options import resolve_bounds, resolve_locks, resolve_regions
from ..capture.stabilise import refine_rigid, release_markers, smooth_head_motion, stabilise_rigid
from ..strategies import STRATEGY_NAMES
from ..strategies.base import Target, as_target
from ..strategies.geometric import GeometricOptions, solve_geometric
from ..strategies.options import (
    CalibrationSettings,
    ExampleSettings,
    MappingSettings,
    PCASettings,
    RefineSettings,
    StrategyInputs,
)
from ..capture.align import align_actor

STRATEGIES = STRATEGY_NAMES


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
    locks: tuple = ()  # ((shape pattern, value or (F,) values per frame), ...) shapes held fixed (animator-owned)
    regions: tuple = ()  # (Region, ...) shapes solved from their own marker subsets (geometric only)
    calibration: CalibrationSettings = CalibrationSettings()  # calibrated, refine
    mapping: MappingSettings = MappingSettings()  # calibrated, refine, parallel
    examples: ExampleSettings = ExampleSettings()  # linear, rbf, pca
    pca: PCASettings = PCASettings()
    refine: RefineSettings = RefineSettings()
    stabilise_mode: str = "rigid"  # "rigid" | "similarity" (captures from different days)
    auto_stable: bool = False  # [stabilise] markers = "auto": suggest the stable set from the data
    neutral_ranges: tuple = ()  # ((first, last), ...): several T-pose ranges (start, end); overrides neutral_frames
    neutral_detect: bool = False  # the "most neutral" frames, detected
    neutral_file: object = None  # path or MarkerSet: a separately captured neutral
    master: object = None  # path or MarkerSet: the performer's master T-pose
    landmarks: tuple = ()  # glob patterns of the master alignment's landmarks (default: eye/mouth corners)
    align_regions: tuple = ()  # ((region name, (patterns...)), ...) actor->character with separate scales
    align_flag_mm: float = None  # alignment residual (mm) above which a binding is flagged (None: robust)
    head_target: str = ""  # "Object" or "Armature:bone": key the removed head motion there
    projection: object = None  # 2D takes: None / "front" (orthographic front view) or a solvers.camera.Camera


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
    stabilise: object  # StabiliseResult (None for parallel)
    alignment: object  # Similarity, actor neutral -> character bound points (geometric only, else None)
    alignment_residual: np.ndarray  # (M,) per-marker distance after alignment (metres; geometric only)
    warnings: tuple = ()
    timings: dict = field(default_factory=dict)
    strategy: str = "geometric"
    residual_space: str = "character"  # where residual_rms is measured: "character", "actor" or None
    source_weights: np.ndarray = None  # (F, S) intermediate activations (actor poses, components, channels)
    source_names: tuple = ()
    info: dict = field(default_factory=dict)  # strategy diagnostics, JSON-ready
    fitted: object = None  # the fitted strategy object (e.g. its actor_basis / refined_basis), not geometric
    normalise: dict = field(default_factory=dict)  # neutral source, detected frames, master offsets (JSON-ready)
    stable_suggestion: object = None  # StableSuggestion when [stabilise] markers = "auto"
    head_target: str = ""
    # (F, M) per-frame distance of each marker from its fit (metres, same space as residual_rms), NaN where
    # the marker is missing or the frame unsolved; None where the strategy has no marker fit (parallel, 2D)
    frame_marker_residual: np.ndarray = None

    def report(self):
        """A JSON-ready summary (lengths in millimetres)."""
        ok = np.isfinite(self.residual_rms)
        out = {
            "strategy": self.strategy,
            "frames": {"count": int(self.frames.size), "first": float(self.frames[0]), "last": float(self.frames[-1])},
            "shapes": list(self.shape_names),
            "markers_used": list(self.marker_names),
            "stable_markers": [] if self.stabilise is None else list(self.stabilise.stable_names),
            "residual_space": self.residual_space,
            "residual_rms_mm": {
                "mean": float(np.mean(self.residual_rms[ok]) * 1e3) if ok.any() else None,
                "max": float(np.max(self.residual_rms[ok]) * 1e3) if ok.any() else None,
                "per_frame": [None if not np.isfinite(v) else round(float(v) * 1e3, 6) for v in self.residual_rms],
            },
            "marker_residual_mm": {n: None if not np.isfinite(v) else round(float(v) * 1e3, 6)
                                   for n, v in zip(self.marker_names, self.marker_residual)},
            "stabilise": None if self.stabilise is None else {
                "rms_mm_mean": float(np.nanmean(self.stabilise.rms) * 1e3) if np.isfinite(self.stabilise.rms).any() else None,
                "flagged_frames": {str(k): v for k, v in self.stabilise.flag_reasons.items()},
                "stable_marker_trust": {k: round(v, 3) for k, v in self.stabilise.marker_trust.items()},
                "mode": self.stabilise.mode,
                "unreliable_frames": [float(f) for f in self.frames[np.asarray(self.stabilise.unreliable, dtype=bool)]]
                if self.stabilise.unreliable is not None else [],
                "suggested": None if self.stable_suggestion is None else self.stable_suggestion.report(),
            },
            "neutral": jsonable(self.normalise),
            "alignment": None if self.alignment is None else {
                "scale": self.alignment.scale,
                "rotation": self.alignment.rotation,
                "translation_m": self.alignment.translation,
                "residual_mm": {n: round(float(v) * 1e3, 6) for n, v in zip(self.marker_names, self.alignment_residual)},
                **({"regions": self.alignment.report(self.marker_names)["regions"],
                    "flagged": list(self.alignment.flagged)} if hasattr(self.alignment, "flagged") else {}),
            },
            "weights_at_bound_mean": float(np.mean(self.at_bound)),
            "timings_s": self.timings,
            "warnings": list(self.warnings),
        }
        if self.strategy != "geometric":
            out["source_channels"] = list(self.source_names)
            out["strategy_info"] = jsonable(self.info)
        return out


def jsonable(value):
    """``value`` with numpy arrays/scalars turned into lists/floats (NaN -> None) for JSON."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return None if not np.isfinite(value) else round(float(value), 9)
    return value


def retarget(markers, basis, settings, *, inputs=None):
    """Retarget a take onto a character with the strategy ``settings.strategy``.

    Parameters
    ----------
    markers : MarkerSet, 3D, any of m/cm/mm (ignored, may be None, for ``parallel``)
    basis : Basis, the character's shapes at the bound points (metres). Strategies other than
        ``geometric`` only use its shape names and bounds, so a ``Target`` or a sequence of shape
        names is accepted for them.
    settings : RetargetSettings
    inputs : StrategyInputs, optional
        What the strategy learns from (calibration take or actor basis, posed examples, training
        take) or, for ``parallel``, the solved weights themselves.

    Returns
    -------
    RetargetResult

    Raises
    ------
    FacecapError for an unknown strategy or when its inputs are missing
    ("strategy 'calibrated' needs [calibration] markers and poses ...").
    """
    if settings.strategy not in STRATEGIES:
        raise FacecapError(f"unknown strategy '{settings.strategy}'; available: {', '.join(STRATEGIES)}")
    inputs = StrategyInputs() if inputs is None else inputs
    if settings.strategy == "geometric":
        if not isinstance(basis, Basis):
            raise FacecapError("strategy 'geometric' needs the character's shapes at the bound points (a Basis)")
        return _retarget_geometric(markers, basis, settings)
    from ..strategies.wiring import require_inputs

    require_inputs(settings.strategy, inputs, settings)
    if settings.strategy == "parallel":
        return _retarget_parallel(basis, settings, inputs)
    if markers is None:
        raise FacecapError(f"strategy '{settings.strategy}' needs a marker take ([source] markers)")
    if markers.dim == 2:
        from .markers_2d import retarget_markers_2d

        return retarget_markers_2d(markers, basis, settings, inputs)
    return _retarget_markers(markers, basis, settings, inputs)


#: Solve options of the head refits' predictions: active-set iterations per frame, no exact fallback.
REFIT_SOLVE = dict(max_iter=2, exact=False)


def _retarget_geometric(markers, basis, settings):
    if markers.dim == 2:
        from .markers_2d import retarget_geometric_2d

        return retarget_geometric_2d(markers, basis, settings)
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
            f"{markers.source or 'take'}: only {len(used)} of its {markers.n_markers} marker(s) are bound on the "
            f"character (need 3; markers bind to vertex groups of the same name); take markers: "
            f"{list(markers.names)[:10]}..., bound points: {list(basis.marker_names)[:10]}..."
        )

    half_window = int(round(settings.head_smoothing * markers.fps))
    options = GeometricOptions(
        regularisation=settings.regularisation,
        sparsity=settings.sparsity,
        symmetry=settings.symmetry,
        smoothing=tuple(settings.smoothing),
    )
    stab, suggestion = stabilise_take(markers, settings, notes)
    stable_set = set(stab.stable_names)
    if stab.flagged.any():
        bridged = any(settings.smoothing)
        notes.append(
            f"{int(stab.flagged.sum())} frame(s) could not be stabilised; their weights are "
            + ("bridged by the temporal smoothing" if bridged else "left unsolved")
        )
    timings["stabilise"] = time.perf_counter() - t0

    sub = basis.subset_markers(used)
    lower, upper = resolve_bounds(basis.shape_names, basis.lower, basis.upper, settings.bounds)
    locks = resolve_locks(basis.shape_names, settings.locks, n_frames=markers.frames.size)
    regions, held = resolve_regions(basis.shape_names, used, settings.regions, dims=3)
    if held:
        notes.append(f"{len(held)} shape(s) are in no region and are held: {list(held)}")
    notes.extend(dict.fromkeys(basis_warnings(sub.matrix(), sub.shape_names)))  # unique, in order
    used_idx = markers.index(used)
    trust = np.array([1.0 if n in stable_set else settings.fine_weight for n in used])
    t_solve = t_align = 0.0
    previous = None  # the last solve's weights: the next one starts from them
    # The solves differ only in their data (same A, R, gaps): each pattern's setup is done once.
    setup = PatternSetup() if settings.fine_iterations else None
    for iteration in range(settings.fine_iterations + 1):
        t1 = time.perf_counter()
        neutral_all, offsets, norm_info = normalise_stabilised(stab, settings, notes if iteration == 0 else [])
        neutral = neutral_all[used_idx]
        align = align_actor(neutral, sub.neutral, used, regions=settings.align_regions, flag_mm=settings.align_flag_mm)
        deltas = None  # the last iteration's: freed before the next are made
        deltas = _character_deltas(stab.markers.positions, offsets, used_idx, neutral, align)
        stab = release_markers(stab, markers)  # its (F, M, 3) markers: computed again if read
        t2 = time.perf_counter()
        with warnings.catch_warnings(), (reuse_pattern_setup(setup) if setup is not None else nullcontext()):
            warnings.simplefilter("ignore", RuntimeWarning)
            # The refits only need a prediction of the face: a few per-frame active-set iterations
            # are enough there (measured on the 36,000-frame sample take: the same final accuracy as
            # exact per-frame refits, at half their cost); the final solve is exact, with the full
            # (temporal) options.
            final = iteration == settings.fine_iterations
            # Each solve starts from the previous one's weights: the refit moves the head a little,
            # so most frames keep their active set.
            solved = solve_geometric(
                sub, deltas, options=options if final else replace(options, smoothing=(0.0, 0.0)),
                lower=lower, upper=upper,
                locks=None if np.isnan(locks).all() else locks, regions=regions,
                start=previous, **({} if final else REFIT_SOLVE),
            )
            previous = solved.weights
        t3 = time.perf_counter()
        t_align += t2 - t1
        t_solve += t3 - t2
        if iteration == settings.fine_iterations:
            setup = None  # hundreds of MB on long takes: not kept for the residuals
            break
        # Hierarchical stabilisation: refit the head on all markers against the solve's prediction.
        predicted = _predicted_markers(solved, sub.deltas, neutral, align, offsets, used_idx)
        solved = deltas = None  # (F, M, 3) each (a solve keeps its data for residuals on demand)
        stab = refine_rigid(markers, stab, used, predicted, weights=trust)
        predicted = None
        stab = smooth_head_motion(markers, stab, half_window=half_window)
        timings["stabilise"] += time.perf_counter() - t3
    align_res = align.residual
    if align.flagged:
        notes.append(f"binding(s) {list(align.flagged)} are far from their marker after the actor->character "
                     f"alignment ({', '.join(f'{align.residual[used.index(n)] * 1e3:.1f} mm' for n in align.flagged)}); "
                     "check the vertex groups")
    timings["align"] = t_align
    timings["solve"] = t_solve
    notes.extend(solved.warnings)

    measured = ~np.isnan(deltas[:, :, 0])
    residual_rms, marker_residual, frame_marker = _residuals(solved.weights, sub.deltas, deltas, measured)
    residual_rms[~solved.solved] = np.nan
    frame_marker[~solved.solved] = np.nan
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
        warnings=tuple(dict.fromkeys(notes)),
        timings={k: round(v, 6) for k, v in timings.items()},
        normalise=norm_info,
        stable_suggestion=suggestion,
        head_target=settings.head_target,
    )


def _target(character, settings):
    """The character's shape names with ``settings.bounds`` applied."""
    target = as_target(character)
    lower, upper = resolve_bounds(target.names, target.lower, target.upper, settings.bounds)
    return Target(target.names, np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64))


def _finish(target, weights, settings, notes):
    """Hold locked shapes at their values; note the options that do not apply."""
    locks = resolve_locks(target.names, settings.locks, n_frames=weights.shape[0])
    held = ~np.isnan(locks)  # (K,) or per frame (F, K)
    if held.any():
        rows = ~np.isnan(weights).all(axis=1)
        weights = np.where(held & rows[:, None], locks, weights)
    if settings.regions:
        notes.append(f"[solve] regions apply to the geometric strategy only; ignored by '{settings.strategy}'")
    return weights


def _retarget_markers(markers, character, settings, inputs):
    """calibrated, refine, linear, rbf, pca: shared stabilisation and neutral, actor-space deltas."""
    from ..strategies.wiring import prepare_take

    timings = {}
    notes = list(inputs.notes)
    t0 = time.perf_counter()

    def prepare(take_markers):
        return prepare_take(take_markers, settings.stable_markers, settings.neutral_frames,
                            head_smoothing=settings.head_smoothing)

    take, suggestion, norm_info = _prepare_main(markers, settings, notes)
    stab = take.stabilise
    if suggestion is not None:
        settings = replace(settings, stable_markers=stab.stable_names)
    if stab.flagged.any():
        notes.append(f"{int(stab.flagged.sum())} frame(s) could not be stabilised; their weights are left unsolved "
                     "or bridged by the strategy's temporal smoothing")
    timings["stabilise"] = time.perf_counter() - t0
    target = _target(character, settings)
    strategy, res, weights = fit_and_solve(settings, target, inputs, take, prepare, notes, timings)

    used, marker_residual, frame_marker = strategy_marker_residuals(strategy, res, take)
    F = take.frames.size
    residual_rms = np.full(F, np.nan) if res.residual_rms is None else np.asarray(res.residual_rms, dtype=np.float64)
    at_bound = res.solve.at_bound if res.solve is not None else res.clamped
    info = dict(res.info)
    for attr in ("version", "history", "basis_frames", "n_examples"):
        if hasattr(strategy, attr):
            info[attr] = getattr(strategy, attr)
    timings["total"] = time.perf_counter() - t0
    return RetargetResult(
        frames=take.frames, shape_names=target.names, weights=weights, marker_names=used,
        residual_rms=residual_rms, marker_residual=marker_residual,
        at_bound=np.zeros(F, dtype=int) if at_bound is None else np.asarray(at_bound),
        stabilise=stab, alignment=None, alignment_residual=None,
        warnings=tuple(dict.fromkeys(notes)), timings={k: round(v, 6) for k, v in timings.items()},
        strategy=settings.strategy, residual_space="actor" if res.residual_rms is not None else None,
        source_weights=res.source_weights, source_names=tuple(res.source_names), info=info, fitted=strategy,
        normalise=norm_info, stable_suggestion=suggestion, head_target=settings.head_target,
        frame_marker_residual=frame_marker,
    )


def fit_and_solve(settings, target, inputs, take, prepare, notes, timings):
    """Fit ``settings.strategy`` for ``take`` (examples and training prepared by ``prepare``), solve the
    take and apply the shape options; notes go to ``notes``, "fit" and "solve" seconds to ``timings``.
    Returns (strategy, strategy result, weights)."""
    from ..strategies.wiring import fit_strategy

    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        strategy, fit_notes = fit_strategy(settings, target, inputs, take, prepare=prepare)
        t2 = time.perf_counter()
        res = strategy.solve(take.deltas, names=take.names, neutral=take.neutral)
    timings.update(fit=t2 - t1, solve=time.perf_counter() - t2)
    notes += fit_notes
    notes.extend(res.warnings)
    return strategy, res, _finish(target, res.weights, settings, notes)


def strategy_marker_residuals(strategy, res, take):
    """(markers used, (M,) RMS residual per marker, (F, M) per frame or None) of a fitted marker
    strategy's solve, in its own space (metres or pixels); a marker is observed where its delta is
    finite (the engine's residuals are 0, not NaN, at gaps)."""
    fitted = getattr(getattr(strategy, "actor_basis", None), "marker_names", None) or take.names
    used = tuple(n for n in fitted if n in set(take.names))
    F, dims = take.frames.size, take.deltas.shape[2]
    if res.solve is None or res.solve.residuals.shape[1] != dims * len(fitted):
        return used, np.full(len(used), np.nan), None
    r2 = (res.solve.residuals.reshape(F, len(fitted), dims) ** 2).sum(axis=2)
    seen = np.isfinite(r2) & (r2 > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.sqrt(np.where(seen, r2, 0.0).sum(axis=0) / seen.sum(axis=0))
    cols = [fitted.index(n) for n in used]
    observed = np.isfinite(take.deltas[:, [take.names.index(n) for n in used], 0])
    frame_marker = np.where(observed, np.sqrt(r2[:, cols]), np.nan)
    frame_marker[~np.asarray(res.solve.solved, dtype=bool)] = np.nan
    return used, per[cols], frame_marker


def _reference_range(settings):
    """The frames whose pose is the stabilisation reference: the first neutral range (None if detected only)."""
    if settings.neutral_ranges:
        return tuple(settings.neutral_ranges[0])
    if settings.neutral_detect and settings.neutral_frames in ((), None, (1, 1)):
        return None
    return tuple(settings.neutral_frames) if settings.neutral_frames else None


def stabilise_take(markers, settings, notes):
    """Gross stabilisation (auto stable set, rigid or similarity, smoothed head motion); markers in metres."""
    suggestion = None
    stable = tuple(settings.stable_markers)
    if settings.auto_stable:
        from ..capture.stable_markers import suggest_stable_markers

        suggestion = suggest_stable_markers(markers)
        stable = suggestion.names
        notes.append(f"stable markers suggested from the take ({len(stable)}, score gap x{suggestion.gap:.1f}"
                     f"{'' if suggestion.clear else ', NOT a clear split: check them'}): {list(stable)}")
    stab = stabilise_rigid(markers, stable, reference_frames=_reference_range(settings), mode=settings.stabilise_mode)
    stab = smooth_head_motion(markers, stab, half_window=int(round(settings.head_smoothing * markers.fps)))
    moving = [n for n, w in stab.marker_trust.items() if w < 0.5]
    if moving:
        notes.append(f"stable marker(s) {moving} move relative to the others and were left out of the head fit")
    if stab.unreliable is not None and stab.unreliable.any():
        notes.append(f"{int(stab.unreliable.sum())} frame(s) have an unreliable head fit (too few stable markers "
                     "agree); see stabilise.unreliable_frames")
    return stab, suggestion


def _load(source, what):
    if source is None or hasattr(source, "positions"):
        return source
    from ..io import import_markers

    return import_markers(source).markers.to_units("m")


def normalise_stabilised(stab, settings, notes):
    """The neutral (M, 3) in the stabilised head frame, per-frame master offsets (F, M, 3) or None, and info."""
    from ..capture.normalise import DEFAULT_LANDMARKS, detect_neutral_frames, master_offsets, neutral_from_file, neutral_from_ranges

    sm = stab.markers
    ranges = tuple(tuple(r) for r in settings.neutral_ranges) or (
        (tuple(settings.neutral_frames),) if settings.neutral_frames and not settings.neutral_detect else ())
    info = {}
    if settings.master is not None:
        if not ranges:
            raise FacecapError("master T-pose normalisation needs the take's T-pose frames ([neutral] frames)")
        master = _load(settings.master, "master")
        norm = master_offsets(sm, master, ranges, landmarks=settings.landmarks or DEFAULT_LANDMARKS)
        info = {"source": "master", "ranges": [list(r) for r in ranges], "master": norm.report(sm.names)}
        return norm.master, norm.offsets, info
    if settings.neutral_file is not None:
        fm = _load(settings.neutral_file, "neutral file")
        pose = neutral_from_file(fm, stab, stable_names=stab.stable_names)
        missing = [n for n in sm.names if n not in set(fm.names)]
        if missing:
            raise FacecapError(f"neutral file {fm.source}: has no marker(s) {missing[:8]}")
        return pose[fm.index(sm.names)], None, {"source": "file", "file": str(fm.source)}
    if settings.neutral_detect:
        frames, dev = detect_neutral_frames(sm)
        info = {"source": "detected", "frames": [float(f) for f in frames]}
        if notes is not None:
            notes.append(f"neutral detected from {len(frames)} frame(s): {_spans(frames)}")
        sel = np.isin(sm.frames, frames)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(sm.positions[sel], axis=0), None, info
    return neutral_from_ranges(sm, ranges), None, {"source": "frames", "ranges": [list(r) for r in ranges]}


def _spans(frames):
    """'1-30, 571-600' for sorted frame numbers."""
    out, start, prev = [], None, None
    for f in frames:
        if start is None:
            start = prev = f
        elif f == prev + 1:
            prev = f
        else:
            out.append((start, prev))
            start = prev = f
    if start is not None:
        out.append((start, prev))
    return ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in out)


def _prepare_main(markers, settings, notes):
    """The take as marker strategies receive it, with every stabilisation / neutral option applied."""
    from ..strategies.wiring import PreparedTake

    markers = markers.to_units("m")
    stab, suggestion = stabilise_take(markers, settings, notes)
    neutral, offsets, info = normalise_stabilised(stab, settings, notes)
    pos = stab.markers.positions if offsets is None else stab.markers.positions + offsets
    return PreparedTake(pos - neutral[None], neutral, markers.names, markers.frames, stab), suggestion, info


def _retarget_parallel(character, settings, inputs):
    """parallel: copy the solved weights of ``inputs.weights`` (a WeightTrack) onto the shapes."""
    from ..strategies.wiring import fit_parallel

    t0 = time.perf_counter()
    track = inputs.weights
    target = _target(character, settings)
    strategy = fit_parallel(settings, target, track)
    res = strategy.solve(track.values, names=track.names)
    notes = list(inputs.notes) + list(res.warnings)
    weights = _finish(target, res.weights, settings, notes)
    F = len(track.frames)
    return RetargetResult(
        frames=np.asarray(track.frames, dtype=np.float64), shape_names=target.names, weights=weights,
        marker_names=(), residual_rms=np.full(F, np.nan), marker_residual=np.zeros(0), at_bound=res.clamped,
        stabilise=None, alignment=None, alignment_residual=None, warnings=tuple(dict.fromkeys(notes)),
        timings={"solve": round(time.perf_counter() - t0, 6), "total": round(time.perf_counter() - t0, 6)},
        strategy="parallel", residual_space=None, source_weights=res.source_weights,
        source_names=tuple(res.source_names), info=dict(res.info), fitted=strategy,
    )


def _predict(weights, deltas):
    """Marker displacements (F, M, D) of weights (F, K) on deltas (K, M, D); NaN weights count as 0."""
    K, M, D = deltas.shape
    return (np.nan_to_num(weights) @ deltas.reshape(K, M * D)).reshape(-1, M, D)


#: Frames per block of the per-frame array work below: temporaries of a few MB that the allocator
#: reuses, not (F, M, 3) ones (587 MB each on 100 minutes at 60 fps; issue 18).
BLOCK = 8192


def _character_deltas(positions, offsets, used_idx, neutral, align):
    """The used markers' deltas from ``neutral`` in character space (F, U, 3), from the stabilised
    ``positions`` (F, M, 3) (+ master ``offsets``), in blocks of frames."""
    F = positions.shape[0]
    out = np.empty((F, len(used_idx), positions.shape[2]))
    for a in range(0, F, BLOCK):
        s = slice(a, a + BLOCK)
        p = positions[s] if offsets is None else positions[s] + offsets[s]
        # np.take keeps the frame-major layout (positions[:, idx] would be marker-major, 2x slower later)
        out[s] = align.apply_vectors(np.take(p, used_idx, axis=1) - neutral[None])
    return out


def _predicted_markers(solved, basis_deltas, neutral, align, offsets, used_idx):
    """Where ``solved`` puts the used markers in the stabilised head frame (F, U, 3), NaN in frames
    it did not solve; in blocks of frames."""
    F = solved.weights.shape[0]
    out = np.empty((F, len(used_idx), basis_deltas.shape[2]))
    for a in range(0, F, BLOCK):
        s = slice(a, a + BLOCK)
        p = neutral[None] + align.inverse_vectors(_predict(solved.weights[s], basis_deltas))
        if offsets is not None:  # back to where the (un-normalised) markers are
            p -= np.take(offsets[s], used_idx, axis=1)
        out[s] = p
    out[~solved.solved] = np.nan
    return out


def _residuals(weights, basis_deltas, deltas, measured):
    """RMS residual per frame (F,) and per marker (M,) over the measured samples only, and the
    distance per frame and marker (F, M), NaN where not measured (in blocks of frames)."""
    sq = np.empty(measured.shape)
    for a in range(0, sq.shape[0], BLOCK):
        s = slice(a, a + BLOCK)
        res = _predict(weights[s], basis_deltas) - deltas[s]
        sq[s] = np.where(measured[s], (res**2).sum(axis=2), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_frame, per_marker = np.sqrt(sq.sum(axis=1) / measured.sum(axis=1)), np.sqrt(sq.sum(axis=0) / measured.sum(axis=0))
    dist = np.sqrt(sq, out=sq)  # in place: no second (F, M)
    dist[~measured] = np.nan
    return per_frame, per_marker, dist
