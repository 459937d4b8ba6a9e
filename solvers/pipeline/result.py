"""``RetargetResult``, what every retarget returns, and ``assemble``, the one place it is built."""

from dataclasses import dataclass, field

import numpy as np


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
    retune: object = None  # tuning.take.TakeTuneResult when the solve retuned from an animator's corrections

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
        if "actor_model" in self.info:
            out["actor"] = jsonable(self.info["actor_model"])
        if "plausibility" in self.info:
            out["plausibility"] = jsonable(self.info["plausibility"])
        if self.strategy != "geometric":
            out["source_channels"] = list(self.source_names)
            out["strategy_info"] = jsonable(self.info)
        if "fusion" in self.info and "strategy_info" not in out:  # a landmark take onto a rig's weight controls
            out["fusion"] = jsonable(self.info["fusion"])
        if "rig" in self.info:  # a rig's controls were solved: how the rig was seen and solved
            out["rig_solve"] = jsonable(self.info["rig"])
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


def assemble(strategy, res, weights, *, frames, settings, notes, timings, take=None, normalise=None,
             suggestion=None, info=None, source=None):
    """The ``RetargetResult`` of a strategy's solve: every retarget (markers 3D or 2D, solved weights,
    video flow features) ends here.

    strategy : the fitted strategy; res : its StrategyResult; weights : (F, K) with the shape
    options applied; frames : (F,) frame numbers; take : the PreparedTake solved (marker takes);
    normalise : the neutral's info; suggestion : StableSuggestion; info : extra diagnostics
    (merged over the strategy's own ``res.info``); source : (values (F, S), names) of the
    intermediate activations when they are not the strategy's (flow features).
    """
    F = len(frames)
    used, marker_residual, frame_marker = (), np.zeros(0), None
    if take is not None:
        used, marker_residual, frame_marker = marker_residuals(strategy, res, take)
    residual_rms = np.full(F, np.nan) if res.residual_rms is None else np.asarray(res.residual_rms, dtype=np.float64)
    at_bound = res.solve.at_bound if res.solve is not None else res.clamped
    alignment = res.alignment
    geometric = strategy.name == "geometric"
    details = dict(res.info)
    for attr in ("version", "history", "basis_frames", "n_examples"):
        if hasattr(strategy, attr):
            details[attr] = getattr(strategy, attr)
    details.update(info or {})
    return RetargetResult(
        frames=np.asarray(frames, dtype=np.float64), shape_names=tuple(res.shape_names), weights=weights,
        marker_names=used, residual_rms=residual_rms, marker_residual=marker_residual,
        at_bound=np.zeros(F, dtype=int) if at_bound is None else np.asarray(at_bound),
        stabilise=None if take is None else take.stabilise, alignment=alignment,
        alignment_residual=res.alignment_residual,
        warnings=tuple(dict.fromkeys(notes)), timings={k: round(v, 6) for k, v in timings.items()},
        strategy=strategy.name, residual_space="character" if geometric else (
            "actor" if res.residual_rms is not None else None),
        source_weights=res.source_weights if source is None else source[0],
        source_names=tuple(res.source_names if source is None else source[1]), info=details, fitted=strategy,
        normalise=normalise or {}, stable_suggestion=suggestion, head_target=settings.head_target,
        frame_marker_residual=frame_marker,
    )


def marker_residuals(strategy, res, take):
    """(markers used, (M,) RMS residual per marker, (F, M) per frame or None) of a marker strategy's
    fit, in its own space (metres or pixels); a marker is observed where its delta is finite (the
    engine's residuals are 0, not NaN, at gaps)."""
    fitted = res.marker_names or getattr(getattr(strategy, "actor_basis", None), "marker_names", None) or take.names
    used = tuple(n for n in fitted if n in set(take.names))
    F, dims = take.frames.size, take.dim
    if res.solve is None:
        return used, np.full(len(used), np.nan), None
    r2 = res.solve.residual_norms(dims)  # (F, markers), in blocks: no (F, P) residuals (issue 18)
    if r2.shape != (F, len(fitted)):
        return used, np.full(len(used), np.nan), None
    seen = np.isfinite(r2) & (r2 > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.sqrt(np.where(seen, r2, 0.0).sum(axis=0) / seen.sum(axis=0))
    cols = [fitted.index(n) for n in used]
    observed = take.seen()[:, [take.names.index(n) for n in used]]
    frame_marker = np.where(observed, np.sqrt(r2[:, cols]), np.nan)
    frame_marker[~np.asarray(res.solve.solved, dtype=bool)] = np.nan
    return used, per[cols], frame_marker
