"""The retarget pipeline, Blender-free: a take + a character -> shape-key weights.

Marker takes (3D, or 2D image tracks): prepare (``stages``: stabilise, neutral) -> fit the strategy
(``strategies.wiring.fit_strategy``; every strategy, ``geometric`` included, behind one contract)
-> solve; a strategy that predicts the markers themselves (``PredictsMarkers``: geometric) gets
hierarchical stabilisation, the head refitted on all markers against its prediction before the
final solve -> shape options (locks) -> ``result.assemble``. ``parallel`` maps solved weights and
needs no markers. Each strategy receives the actor-space take and aligns it onto what it was fitted
on (geometric: the character's bound points, by a similarity).
"""

import time
import warnings
from contextlib import nullcontext
from dataclasses import replace

import numpy as np

from ..capture.stabilise import refine_rigid, smooth_head_motion
from ..character.basis import Basis
from ..character.shape_options import resolve_locks
from ..engine.frames import PatternSetup, reuse_pattern_setup
from ..engine.split import release_freed_memory
from ..errors import FacecapError
from ..strategies.base import PredictsMarkers
from ..strategies.gaze import GAZE, gaze_from_eye_angles
from ..strategies.geometric import bound_markers
from ..strategies.options import StrategyInputs
from ..strategies.wiring import fit_parallel, fit_strategy, require_inputs, shape_target
from . import markers_2d, plausibility, stages
from .result import RetargetResult, assemble, jsonable
from .settings import STRATEGIES, RetargetSettings

#: Strategies that sample the character's shapes at the bound points (they need a binding).
SAMPLES_CHARACTER = ("geometric", "semantic")

__all__ = ["RetargetResult", "RetargetSettings", "SAMPLES_CHARACTER", "STRATEGIES", "hold_locks", "jsonable", "refit_head", "retarget",
           "shape_target"]


def retarget(markers, character, settings, *, inputs=None):
    """Retarget a take onto a character with the strategy ``settings.strategy``.

    Parameters
    ----------
    markers : MarkerSet, 3D (any of m/cm/mm) or 2D image tracks (pixels); None for ``parallel``
    character : Basis, the character's shapes at the bound points (metres). Strategies other than
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
    if settings.strategy == "semantic" and markers is not None and markers.dim == 2:
        settings = replace(settings, strategy="geometric")  # image tracks: the projected character's shapes
        inputs = replace(inputs, notes=tuple(inputs.notes) + (
            "2D take: the semantic solve needs 3D markers; solved with the geometric strategy",))
    if settings.strategy in SAMPLES_CHARACTER:
        if not isinstance(character, Basis):
            raise FacecapError(f"strategy '{settings.strategy}' needs the character's shapes at the bound points (a Basis)")
    else:
        require_inputs(settings.strategy, inputs, settings)
    if settings.strategy == "parallel":
        return _retarget_weights(character, settings, inputs)
    if markers is None:
        raise FacecapError(f"strategy '{settings.strategy}' needs a marker take ([source] markers)")
    return _retarget_markers(markers, character, settings, inputs)


def hold_locks(names, weights, settings, notes):
    """Hold locked shapes at their values; note the options that do not apply."""
    locks = resolve_locks(names, settings.locks, n_frames=weights.shape[0])
    held = ~np.isnan(locks)  # (K,) or per frame (F, K)
    if held.any():
        rows = ~np.isnan(weights).all(axis=1)
        weights = np.where(held & rows[:, None], locks, weights)
    if settings.regions and settings.strategy not in SAMPLES_CHARACTER:
        notes.append(f"[solve] regions apply to the semantic and geometric strategies; ignored by "
                     f"'{settings.strategy}'")
    return weights


def _retarget_markers(markers, character, settings, inputs):
    """Every marker strategy, 3D or 2D: prepare, fit, solve (with head refits where it predicts)."""
    notes, timings = list(inputs.notes), {}
    t0 = time.perf_counter()
    if markers.dim == 2:
        markers_2d.check_2d(settings, inputs)
    if settings.strategy in SAMPLES_CHARACTER:  # a binding problem is named before any work
        bound_markers(character, markers.names, source=markers.source or "take")
    markers = stages.usable_markers(markers, settings, notes,
                                    bound=character.marker_names if _needs_binding(settings, inputs) else None)
    take, suggestion, norm_info = stages.prepare_take(markers, settings, notes)
    if take.dim == 3 and take.stabilise.flagged.any():
        bridged = any(settings.smoothing)
        notes.append(f"{int(take.stabilise.flagged.sum())} frame(s) could not be stabilised; their weights are "
                     + ("bridged by the temporal smoothing" if bridged else "left unsolved"))
    timings["stabilise"] = time.perf_counter() - t0
    if settings.strategy == "geometric" and take.dim == 2:
        character, view = markers_2d.projected(character, settings.projection)
        notes.append(view)
    elif take.dim == 2:
        notes.append(markers_2d.NOTE_PIXELS)
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        strategy, fit_notes = fit_strategy(settings, character, inputs, take,
                                           prepare=stages.for_other_take(settings, take))
    notes.extend(fit_notes)
    timings["fit"] = time.perf_counter() - t1
    noise = plausibility.marker_noise(take.deltas) if take.dim == 3 else float("nan")
    handed, take = [take], None  # _solve frees the first take's (F, M, D) deltas at its first head refit
    res, take, motion = _solve(strategy, handed, markers, settings, notes, timings)
    notes.extend(res.warnings)
    weights = hold_locks(res.shape_names, res.weights, settings, notes)
    _refuse_flat(weights, motion, take.dim, settings)
    info = {}
    if take.dim == 3:
        info["plausibility"], warning = plausibility.check(
            weights, res.shape_names, getattr(strategy, "upper", np.ones(len(res.shape_names))), res.residual_rms,
            noise, held=_held(strategy, settings, res.shape_names, weights.shape[0]))
        advice = plausibility.prior_advice(info["plausibility"], getattr(getattr(strategy, "model", None), "tier", None))
        notes.extend(line for line in (advice, warning) if line)
    timings["total"] = time.perf_counter() - t0
    return assemble(strategy, res, weights, frames=take.frames, settings=settings, notes=notes, timings=timings,
                    take=take, normalise=norm_info, suggestion=suggestion, info=info)


def _held(strategy, settings, names, frames):
    """Shapes the solve held (locks, and the semantic solve's unseen shapes): not judged for pinning."""
    locks = np.atleast_2d(resolve_locks(names, settings.locks, n_frames=frames))
    held = {n for n, column in zip(names, locks.T) if np.isfinite(column).all()}  # held over the whole take
    model = getattr(strategy, "model", None)
    return held | set(getattr(model, "unseen", ()))


def _needs_binding(settings, inputs):
    """Whether a marker must be bound on the character to be solved from: geometric, and semantic when
    nothing else is known of the actor (calibration poses, a profile or library, the template know unbound
    markers too)."""
    if settings.strategy == "geometric":
        return True
    knows = (settings.calibration.poses or settings.calibration.sequence or inputs.calibration is not None
             or inputs.profile is not None
             or inputs.actor_basis is not None or inputs.template is not None)
    return settings.strategy == "semantic" and not knows


def _refuse_flat(weights, motion, dim, settings):
    """A solve that holds every shape at 0 while the markers clearly move (``motion``, RMS from the
    neutral, see ``_motion``) is certainly wrong: say so."""
    solved = weights[np.isfinite(weights)]
    if not solved.size or np.max(np.abs(solved)) > 1e-6 or settings.locks:
        return
    if motion > (1e-3 if dim == 3 else 1.0):  # 1 mm, or a pixel: far above marker noise
        unit = f"{motion * 1e3:.1f} mm" if dim == 3 else f"{motion:.1f} px"
        raise FacecapError(f"every solved weight is 0 although the markers move ({unit} RMS from the neutral): the "
                           f"priors hold every shape (regularisation {settings.regularisation:g}, sparsity "
                           f"{settings.sparsity:g}, symmetry {settings.symmetry:g}); lower them")


def _solve(strategy, handed, markers, settings, notes, timings):
    """Solve the PreparedTake in the list ``handed`` (taken from it, so that no caller keeps it); a
    strategy that predicts the markers gets ``settings.fine_iterations`` head refits first
    (hierarchical stabilisation), and each of its solves is given the take's deltas to work in.
    Returns (StrategyResult, the PreparedTake solved, its markers' RMS motion from the neutral)."""
    take = handed.pop()
    predicts = isinstance(strategy, PredictsMarkers)
    refits = settings.fine_iterations if predicts and take.dim == 3 else 0
    # The solves differ only in their data (same basis, priors and gaps): each gap pattern's setup
    # is done once; each solve starts from the one before (the refit moves the head a little).
    setup = PatternSetup() if refits else None
    metres = markers.to_units("m") if refits else None
    previous, t_solve, t_refit = None, 0.0, 0.0
    for iteration in range(refits + 1):
        final = iteration == refits
        t1 = time.perf_counter()
        if final:
            motion = _motion(take.deltas)
        kwargs = {"start": previous, "quick": not final} if refits else {}
        source = take.deltas
        if predicts:  # its solve aligns the deltas in their own memory: no second (F, M, D) array (issue 18)
            kwargs["overwrite"] = True
            take = take.handed_over() if final else replace(take, deltas=None)
        with warnings.catch_warnings(), (reuse_pattern_setup(setup) if setup is not None else nullcontext()):
            warnings.simplefilter("ignore", RuntimeWarning)
            res = strategy.solve(source, names=take.names, neutral=take.neutral, **kwargs)
        source = None
        t2 = time.perf_counter()
        t_solve += t2 - t1
        if final:
            break
        previous, used = res.weights, res.marker_names
        idx = [take.names.index(n) for n in used]
        res = replace(res, solve=None)  # the solve's deltas are not needed to predict: freed first
        predicted = [_predicted(strategy, res, take, idx)]  # handed over: refit_head frees it once read
        gross, res, take = take.stabilise, None, None
        stab = refit_head(gross, used, predicted, metres, settings)
        take, _ = stages.normalised(stab, settings, [])
        release_freed_memory(take.frames.size)  # long takes: the refit's freed memory, before the solve
        t_refit += time.perf_counter() - t2
    timings["solve"] = t_solve
    if refits:
        timings["stabilise"] += t_refit
    return res, take, motion


def _motion(deltas):
    """RMS distance of the measured markers from the neutral over the take (metres or pixels; 0
    when nothing was measured), in blocks of frames."""
    total, count = 0.0, 0
    for a in range(0, deltas.shape[0], BLOCK):
        part = deltas[a : a + BLOCK]
        seen = np.isfinite(part).all(axis=2)
        total += float(np.einsum("ij,ij->", part[seen], part[seen]))
        count += int(seen.sum())
    return float(np.sqrt(total / count)) if count else 0.0


def refit_head(gross, used, predicted, markers, settings):
    """The take's stabilisation ``gross`` refitted on the markers ``used`` against the strategy's
    prediction of them (the array in the list ``predicted``, taken from it: the smoothing does not
    need it, so it is freed once the refit has read it)."""
    stable = set(gross.stable_names)
    trust = np.array([1.0 if n in stable else settings.fine_weight for n in used])
    stab = refine_rigid(markers, gross, used, predicted.pop(), weights=trust)
    return smooth_head_motion(markers, stab, half_window=stages.head_half_window(settings, markers.fps))


#: Frames per block of ``_predicted``: temporaries of a few MB, not (F, M, D) ones (issue 18).
BLOCK = 8192


def _predicted(strategy, res, take, idx):
    """Where ``strategy`` puts the markers ``idx`` of ``take`` in the stabilised head frame (F, U, D)
    (the neutral plus its prediction, less any master offsets), NaN in frames it did not solve;
    predicted in blocks of frames."""
    F = res.weights.shape[0]
    out = np.empty((F, len(idx), take.neutral.shape[1]))
    for a in range(0, F, BLOCK):
        s = slice(a, a + BLOCK)
        part = take.neutral[idx][None] + strategy.predict(replace(res, weights=res.weights[s]))
        if take.offsets is not None:  # back to where the (un-normalised) markers are
            part -= np.take(take.offsets[s], idx, axis=1)
        out[s] = part
    out[~res.solved] = np.nan
    return out


def with_gaze(track):
    """``track`` with the eight gaze channels derived from its eye angles when it has angles but no gaze
    channels (``strategies.gaze``), and the note saying so (a list)."""
    if track.eyes is None or any(n.startswith("eyeLook") for n in track.names) or \
            not np.isfinite(track.eyes[:, [0, 1, 3, 4]]).any():
        return track, []
    values = np.concatenate([track.values, gaze_from_eye_angles(track.eyes)], axis=1)
    return replace(track, names=tuple(track.names) + GAZE, values=values), [
        "gaze (eyeLook*) from the take's eye angles: the take has no gaze channels"]


def _retarget_weights(character, settings, inputs):
    """parallel: map the solved weights of ``inputs.weights`` (a WeightTrack) onto the shapes."""
    t0 = time.perf_counter()
    track, gaze_note = with_gaze(inputs.weights)
    strategy = fit_parallel(settings, shape_target(character, settings), track)
    res = strategy.solve(track.values, names=track.names)
    notes = list(inputs.notes) + list(res.warnings) + gaze_note
    weights = hold_locks(res.shape_names, res.weights, settings, notes)
    elapsed = time.perf_counter() - t0
    return assemble(strategy, res, weights, frames=track.frames, settings=settings, notes=notes,
                    timings={"solve": elapsed, "total": elapsed})
