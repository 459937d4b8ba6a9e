"""Build and fit a strategy from the pipeline's settings and inputs.

``retarget`` (``solvers.pipeline``) prepares the take (stabilised, neutral-normalised actor
deltas), then calls ``fit_strategy`` here for every strategy, ``geometric`` included; the strategy
classes themselves know nothing about configs or the sidebar. ``require_inputs`` raises the one
readable error a user gets when a strategy's inputs are missing.
"""

import numpy as np

from ..character.aliases import name_key
from ..character.shape_options import resolve_bounds
from ..errors import FacecapError
from . import make_strategy
from .base import Target, as_target
from .lowrank import fill_gaps, gap_subspace
from .options import ExamplePairs
from .semantic_wiring import fit_semantic
from .sources import flat

#: what each strategy needs besides the take, in the words of the take config
NEEDS = {
    "calibrated": "[calibration] markers and poses (or a stored [calibration] basis)",
    "refine": "[calibration] markers and poses (or a stored [calibration] basis)",
    "linear": "[examples] weights (character weights posed for frames of the take)",
    "rbf": "[examples] weights (character weights posed for frames of the take)",
    "pca": "[examples] weights (character weights posed for frames of the take)",
    "parallel": "[source] weights (a Live Link Face / ARKit / MediaPipe CSV of solved weights)",
}


def shape_target(character, settings):
    """The character's shape names with ``settings.bounds`` applied (a ``Target``)."""
    target = as_target(character)
    lower, upper = resolve_bounds(target.names, target.lower, target.upper, settings.bounds)
    return Target(target.names, np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64))


def require_inputs(strategy, inputs, settings):
    """Raise a FacecapError naming what ``strategy`` lacks."""
    missing = False
    if strategy in ("calibrated", "refine"):
        missing = inputs.actor_basis is None and (inputs.calibration is None or not settings.calibration.poses)
    elif strategy in ("linear", "rbf", "pca"):
        missing = inputs.examples is None
    elif strategy == "parallel":
        missing = inputs.weights is None
    if missing:
        raise FacecapError(f"strategy '{strategy}' needs {NEEDS[strategy]}")


def _calibration_kwargs(settings, inputs):
    if inputs.actor_basis is not None:
        return {"actor_basis": inputs.actor_basis}
    cal = settings.calibration
    return {
        "calibration": inputs.calibration,
        "poses": cal.pose_table(),
        "neutral": tuple(cal.neutral_frames or settings.neutral_frames),
        "stable_markers": tuple(cal.stable_markers or settings.stable_markers),
        "split": tuple(cal.split),
    }


def _mapping_kwargs(settings):
    m = settings.mapping
    return {"mapping": m.table_dict(), "keyed_by": "source", "aliases": m.aliases}


def _per_shape(value):
    """A scalar stays; ((shape, value), ...) becomes {shape: value}."""
    if isinstance(value, (tuple, list)) and value and isinstance(value[0], (tuple, list)) and isinstance(value[0][0], str):
        return {k: (tuple(v) if isinstance(v, (tuple, list)) else v) for k, v in value}
    return value


def example_weights(names, values, target, notes):
    """Posed weights ``values`` (N, len(names)) in ``target``'s shape order (names matched exactly or
    by alias key; shapes not posed are 0, with a note in ``notes``); (N, K)."""
    lookup = {n: j for j, n in enumerate(names)}
    keyed = {name_key(n): j for j, n in enumerate(names)}
    cols = [lookup.get(n, keyed.get(name_key(n))) for n in target.names]
    unknown = sorted(set(names) - {names[c] for c in cols if c is not None})
    if unknown:
        raise FacecapError(f"examples: weights name shape(s) the character does not have: {unknown}")
    unposed = [n for n, c in zip(target.names, cols) if c is None]
    if unposed:
        notes.append(f"examples: {len(unposed)} character shape(s) are not in the example weights and are 0 in "
                     f"every example: {unposed[:8]}{' ...' if len(unposed) > 8 else ''}")
    W = np.stack([values[:, c] if c is not None else np.zeros(len(values)) for c in cols], axis=1)
    if not np.isfinite(W).all():
        raise FacecapError("examples: weights must be finite (a posed frame keys every shape it uses)")
    return W


def example_pairs(examples, target, take):
    """(indices into ``take``, example deltas (N, M, 3) gap-filled, weights (N, K), notes)."""
    notes = []
    frames = np.asarray(examples.frames, dtype=np.float64)
    values = np.asarray(examples.weights, dtype=np.float64)
    if values.ndim != 2 or values.shape != (frames.size, len(examples.names)) or frames.size == 0:
        raise FacecapError(f"examples: weights must have shape (N, {len(examples.names)}) for N > 0 frames; got {values.shape}")
    W = example_weights(examples.names, values, target, notes)
    idx = np.searchsorted(take.frames, frames)
    idx = np.clip(idx, 0, take.frames.size - 1)
    absent = frames[np.abs(take.frames[idx] - frames) > 1e-6]
    if absent.size:
        raise FacecapError(
            f"examples: frame(s) {absent[:8].tolist()} are not in the example take "
            f"({take.frames[0]:g}-{take.frames[-1]:g})"
        )
    ex, gappy = filled_frames(take.deltas, idx)
    if gappy.any():
        if not np.isfinite(ex).all():
            bad = frames[~np.isfinite(ex).all(axis=1)]
            raise FacecapError(f"examples: frame(s) {bad[:8].tolist()} have no visible marker (or could not be stabilised)")
        notes.append(f"examples: {int(gappy.sum())} example frame(s) had marker gaps, filled through the take's principal subspace")
    return idx, ex.reshape(len(idx), *take.deltas.shape[1:]), W, notes


def filled_frames(deltas, idx):
    """The frames ``idx`` of a take's deltas (F, M, D), flattened, their gaps filled through the
    take's principal subspace (``gap_subspace``); returns (rows (N, M * D), which had gaps (N,))."""
    X = flat(deltas)
    ex = X[idx]
    gappy = ~np.isfinite(ex).all(axis=1)
    if gappy.any():
        ex, _ = fill_gaps(ex, *gap_subspace(X))
    return ex, gappy


def fit_strategy(settings, character, inputs, take, *, prepare):
    """A fitted marker strategy for ``settings.strategy`` (any but ``parallel``).

    Parameters
    ----------
    settings : RetargetSettings
    character : Basis (geometric: the shapes at the bound points), or a Target / shape names
    inputs : StrategyInputs
    take : PreparedTake, the take being solved
    prepare : callable MarkerSet -> PreparedTake for another take (training, example take)

    Returns
    -------
    (strategy, notes)
    """
    name = settings.strategy
    notes = []
    if name == "semantic":
        return fit_semantic(settings, character, inputs, take, priors=_priors(settings))
    if name == "geometric":
        s = make_strategy(name, **_priors(settings), align_regions=settings.align_regions,
                          align_flag_mm=settings.align_flag_mm)
        return s.fit(character, names=take.names, bounds=settings.bounds, locks=settings.locks,
                     regions=settings.regions), notes
    require_inputs(name, inputs, settings)
    target = shape_target(character, settings)
    if name == "calibrated":
        s = make_strategy(name, **_mapping_kwargs(settings), **_priors(settings), align=settings.calibration.align)
        return s.fit(target, **_calibration_kwargs(settings, inputs)), notes
    if name == "refine":
        r = settings.refine
        s = make_strategy(name, **_mapping_kwargs(settings), **_priors(settings), align=settings.calibration.align,
                          max_iterations=r.max_iterations, tol=r.tol, stiffness=r.stiffness)
        training = take if inputs.training is None else prepare(inputs.training)
        kwargs = _calibration_kwargs(settings, inputs)
        if "neutral" in kwargs:
            kwargs["calibration_neutral"] = kwargs.pop("neutral")
        s.fit(target, training=training.deltas, names=training.names, neutral=training.neutral, **kwargs)
        return s, notes
    ex_take = take if inputs.examples.markers is None else prepare(inputs.examples.markers)
    idx, ex, W, ex_notes = example_pairs(_selected(inputs.examples, settings.examples.frames), target, ex_take)
    notes += ex_notes
    e = settings.examples
    common = dict(names=ex_take.names, neutral=ex_take.neutral)
    if name == "linear":
        s = make_strategy(name, ridge=e.ridge)
        return s.fit(target, examples=ex, weights=W, training=ex_take.deltas, **common), notes
    if name == "rbf":
        extra = {} if e.n_components is None else {"n_components": e.n_components}
        s = make_strategy(name, kernel=e.kernel, smoothing=e.rbf_smoothing, degree=e.degree, far=e.far, **extra)
        return s.fit(target, examples=ex, weights=W, training=ex_take.deltas, **common), notes
    if name == "pca":
        p = settings.pca
        s = make_strategy(name, mode=p.mode, ica=p.ica, n_basis=p.n_basis, variance=p.variance,
                          n_components=e.n_components, smoothing=tuple(settings.smoothing))
        return s.fit(target, training=ex_take.deltas, example_frames=idx, example_weights=W, **common), notes
    raise FacecapError(f"strategy '{name}' is not a fitted marker strategy")


def _priors(settings):
    return {"regularisation": settings.regularisation, "sparsity": settings.sparsity, "symmetry": settings.symmetry,
            "smoothing": tuple(settings.smoothing)}


def _selected(examples, frames):
    """Only the example rows at ``frames`` (all when empty)."""
    if not frames:
        return examples
    have = np.asarray(examples.frames, dtype=np.float64)
    want = np.asarray(frames, dtype=np.float64)
    rows = [int(np.flatnonzero(np.abs(have - f) < 1e-6)[0]) for f in want if np.any(np.abs(have - f) < 1e-6)]
    missing = [f for f in want.tolist() if not np.any(np.abs(have - f) < 1e-6)]
    if missing:
        raise FacecapError(f"examples: frame(s) {missing[:8]} have no posed weights")

    return ExamplePairs(have[rows], np.asarray(examples.weights)[rows], examples.names, examples.markers)


def fit_parallel(settings, target, track):
    """A fitted ``parallel`` strategy for a WeightTrack (frames, names, values)."""
    m = settings.mapping
    s = make_strategy("parallel", **_mapping_kwargs(settings), gain=_per_shape(m.gain), offset=_per_shape(m.offset),
                      clamp=_per_shape(m.clamp), curve=_per_shape(m.curve), mirror=m.mirror)
    neutral = None
    if m.neutral_frames is not None:
        first, last = m.neutral_frames
        sel = (track.frames >= first) & (track.frames <= last)
        if not sel.any():
            raise FacecapError(
                f"parallel: neutral frames {first}-{last} are outside the weights "
                f"({track.frames[0]:g}-{track.frames[-1]:g})"
            )
        neutral = track.values[sel]
    return s.fit(target, source_names=track.names, neutral=neutral)
