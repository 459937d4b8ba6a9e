"""The animator feedback loop at take level (issue 7): corrected frames -> a new library version -> re-solve.

One headless layer for the Blender Retune operator and ``python -m facecap tune``, so both give the
same result. ``retune_take`` re-optimises what the take's strategy learned, from corrections given
as ``{frame number: {character shape: value}}``:

- ``semantic``, ``calibrated`` / ``refine``: the actor library (``strategy.actor_basis``; semantic: its
  actor model, whatever its tier, re-used as a performer profile), by ``tuning.retune``
  on the actor-space deltas exactly as the strategy solves them (reordered, aligned onto the
  calibration neutral) and the actor pose activations. Character corrections go back to pose space
  through the strategy's mapping where a shape has a single pose source (one-to-one by name by
  default); other shapes are skipped with a note.
- ``geometric``: the character's shapes at the bound points, by the same ``retune`` on the
  character-space deltas the geometric path solved (final stabilisation, neutral, similarity).
- ``linear`` / ``rbf`` / ``pca``: the posed examples; the corrected frames become examples
  (replacing examples at the same frames; shapes the animator did not set keep the solve's value).

The take is then re-solved with ``retarget`` and the new version applied (``apply_version``), so
the figures are those of the real pipeline. Nothing given is modified; every version carries a
content-hashed name and its parent's name (``LibraryVersion``), and ``to_arrays`` / ``from_arrays``
store it as plain numpy arrays (an .npz, or ID-property arrays in a .blend).
"""

from dataclasses import dataclass, replace
from datetime import datetime, timezone

import numpy as np

from ..character.aliases import canonical_names, name_key
from ..character.basis import Basis
from ..character.shape_options import resolve_bounds, resolve_locks, resolve_regions
from ..engine import solve_bounded
from ..errors import FacecapError
from ..pipeline import jsonable, retarget
from ..pipeline.stages import normalise_stabilised
from ..strategies.geometric import GeometricOptions, solve_geometric, symmetric_pairs
from ..strategies.options import ExamplePairs, StrategyInputs
from ..strategies.sources import align_to, reorder
from .retune import retune
from .store import LibraryVersion, payload_digest  # noqa: F401 (LibraryVersion: part of this API)

#: strategy -> what a version of it stores
KINDS = {"semantic": "actor_basis", "calibrated": "actor_basis", "refine": "actor_basis",
         "geometric": "character_basis",
         "linear": "examples", "rbf": "examples", "pca": "examples"}
def _now():
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _kind(strategy):
    if strategy not in KINDS:
        raise FacecapError(f"tuning: strategy '{strategy}' learns nothing a retune could change "
                           "(use the shape controls or fit_gain_offset)")
    return KINDS[strategy]


def original_version(result, settings, inputs=None, *, character=None):
    """The version a solve used, before any retune (parent ""): the actor library of a fitted
    semantic/calibrated/refine strategy, the character's shapes at the bound points (geometric; needs
    ``character``), or the examples (linear/rbf/pca)."""
    strategy = settings.strategy
    kind = _kind(strategy)
    if kind == "actor_basis":
        payload = result.fitted.actor_basis
    elif kind == "character_basis":
        if not isinstance(character, Basis):
            raise FacecapError("tuning: the geometric original version needs the character Basis (`character=`)")
        payload = character.subset_markers(result.marker_names)
    else:
        payload = _current_examples(inputs, settings, result.shape_names)
    name = f"{strategy}-{payload_digest(kind, payload)}"
    return LibraryVersion(name, "", strategy, kind, payload, _now(), {"original": True}, tuple(result.shape_names))


# -- applying a version ------------------------------------------------------------------------
def apply_version(version, character, inputs, settings):
    """How a stored version enters a solve: returns (character, inputs, settings) for ``retarget``.

    actor_basis -> ``inputs.actor_basis`` (the calibration take is not read again; ``refine`` does
    not refine it again); character_basis -> the character Basis with the version's shapes at its
    bound points; examples -> ``inputs.examples`` (``[examples] frames`` no longer filters them).

    Raises FacecapError when the version does not fit (other strategy kind, other shapes or markers).
    """
    if not isinstance(version, LibraryVersion):
        raise FacecapError(f"apply_version: expected a LibraryVersion; got {type(version).__name__}")
    inputs = StrategyInputs() if inputs is None else inputs
    strategy = settings.strategy
    if KINDS.get(strategy) != version.kind:
        fits = [s for s, k in KINDS.items() if k == version.kind]
        raise FacecapError(f"library version '{version.name}' ({version.kind}, made for '{version.strategy}') cannot be "
                           f"used by strategy '{strategy}'; it fits {', '.join(fits)}")
    names = _shape_names(character)
    if version.shapes and [name_key(n) for n in version.shapes] != [name_key(n) for n in names]:
        extra = [n for n in version.shapes if name_key(n) not in {name_key(m) for m in names}]
        missing = [n for n in names if name_key(n) not in {name_key(m) for m in version.shapes}]
        raise FacecapError(f"library version '{version.name}' was made for other character shapes "
                           f"(not on this character: {extra[:8]}; not in the version: {missing[:8]})")
    if version.kind == "actor_basis":
        inputs = replace(inputs, actor_basis=version.payload, calibration=None)
        if strategy == "refine":
            settings = replace(settings, refine=replace(settings.refine, max_iterations=0))
        if strategy == "semantic":  # the version holds the measured poses too: they are not measured again
            settings = replace(settings, calibration=replace(settings.calibration, poses=()))
        return character, inputs, settings
    if version.kind == "character_basis":
        return _merge_character(version, character), inputs, settings
    unknown = [n for n in version.payload.names if name_key(n) not in {name_key(m) for m in names}]
    if unknown:
        raise FacecapError(f"library version '{version.name}': example shapes {unknown[:8]} are not on the character")
    inputs = replace(inputs, examples=version.payload)
    return character, inputs, replace(settings, examples=replace(settings.examples, frames=()))


def _shape_names(character):
    if isinstance(character, Basis):
        return character.shape_names
    return tuple(getattr(character, "names", character))


def _merge_character(version, character):
    if not isinstance(character, Basis):
        raise FacecapError(f"library version '{version.name}' replaces the character's shapes at the bound points; "
                           f"the character must be a Basis, got {type(character).__name__}")
    v = version.payload
    if v.shape_names != character.shape_names:
        raise FacecapError(f"library version '{version.name}': shapes differ from the character's")
    missing = [n for n in v.marker_names if n not in set(character.marker_names)]
    if missing:
        raise FacecapError(f"library version '{version.name}': bound point(s) {missing[:8]} are not on the character")
    if v.neutral.shape[1] != character.neutral.shape[1]:
        raise FacecapError(f"library version '{version.name}' is {v.neutral.shape[1]}D; the character is "
                           f"{character.neutral.shape[1]}D")
    idx = [character.marker_names.index(n) for n in v.marker_names]
    deltas = character.deltas.copy()
    deltas[:, idx] = v.deltas
    return Basis(character.shape_names, character.marker_names, character.neutral, deltas, character.lower,
                 character.upper)


# -- corrections --------------------------------------------------------------------------------
def correction_matrix(frames, shape_names, corrections):
    """({frame number: {shape: value}}) -> (indices (T,) into ``frames``, (T, K) values, NaN = not set).

    Shape names match by name, case, separators and alias (``solvers.aliases``).
    """
    frames = np.asarray(frames, dtype=np.float64)
    if not corrections:
        raise FacecapError("tuning: no corrected frames")
    lookup = {}
    for k, n in enumerate(shape_names):
        lookup.setdefault(name_key(n), k)
        canon = canonical_names(n)
        if len(canon) == 1:
            lookup.setdefault(name_key(canon[0]), k)
    rows, idx = [], []
    for f in sorted(corrections, key=float):
        hit = np.flatnonzero(np.abs(frames - float(f)) < 1e-6)
        if hit.size == 0:
            raise FacecapError(f"tuning: corrected frame {f} is not in the take ({frames[0]:g}-{frames[-1]:g})")
        row = np.full(len(shape_names), np.nan)
        for shape, value in corrections[f].items():
            k = lookup.get(name_key(shape))
            if k is None:
                canon = canonical_names(shape)
                k = lookup.get(name_key(canon[0])) if len(canon) == 1 else None
            if k is None:
                raise FacecapError(f"tuning: frame {f}: shape '{shape}' is not on the character")
            if value is None or (isinstance(value, float) and np.isnan(value)):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value):
                raise FacecapError(f"tuning: frame {f}, shape '{shape}': value must be a finite number; got {value!r}")
            row[k] = float(value)
        if np.isfinite(row).any():
            rows.append(row)
            idx.append(int(hit[0]))
    if not rows:
        raise FacecapError("tuning: the corrections set no shape on any frame")
    return np.asarray(idx, dtype=np.int64), np.stack(rows)


def _rms(x):
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else 0.0


@dataclass(frozen=True, eq=False)
class TakeTuneResult:
    """Outcome of ``retune_take``.

    version : LibraryVersion, the new version (``parent_version`` itself when nothing changed)
    result, before : RetargetResult of the re-solve with ``version`` and of the solve before
    corrected_rmse_before, corrected_rmse_after : RMS of (weights - corrections) over the set entries
    others_moved : relative RMS change of the weights on the frames that were not corrected
    notes : tuple of str
    frames : corrected frame numbers; parent_version : the version tuned from
    changed : whether the library changed; tune : the ``tuning.TuneResult`` (library kinds) or None
    """

    version: LibraryVersion
    result: object
    before: object
    corrected_rmse_before: float
    corrected_rmse_after: float
    others_moved: float
    notes: tuple
    frames: np.ndarray = None
    parent_version: LibraryVersion = None
    changed: bool = True
    tune: object = None

    def report(self):
        """JSON-ready summary of the retune."""
        return jsonable({
            "version": self.version.name, "parent": self.version.parent, "strategy": self.version.strategy,
            "kind": self.version.kind, "changed": self.changed, "corrected_frames": list(self.frames),
            "corrected_rmse_before": self.corrected_rmse_before, "corrected_rmse_after": self.corrected_rmse_after,
            "others_moved": self.others_moved, "summary": self.version.summary, "notes": list(self.notes),
        })


# -- the retune ---------------------------------------------------------------------------------
def retune_take(markers, character, settings, inputs, corrections, *, mu=None, base=None, parent=""):
    """Re-optimise what the take's strategy learned from an animator's corrections, then re-solve.

    Parameters
    ----------
    markers, character, settings, inputs : as for ``retarget`` -- what the current solve used (with
        ``parent``'s version already applied, if any)
    corrections : {frame number (as in ``RetargetResult.frames``): {character shape: value}};
        partial rows are fine (only the shapes the animator set)
    mu : None (chosen by leave-one-frame-out), a float or inf; see ``tuning.retune`` (library kinds)
    base : RetargetResult of the current solve (solved here if None)
    parent : name of the version the current solve used; "" = the original (named by its content)

    Returns
    -------
    TakeTuneResult
    """
    kind = _kind(settings.strategy)
    inputs = StrategyInputs() if inputs is None else inputs
    if base is None:
        base = retarget(markers, character, settings, inputs=inputs)
    if base.strategy != settings.strategy:
        raise FacecapError(f"tuning: `base` was solved with '{base.strategy}', settings say '{settings.strategy}'")
    idx, Wc = correction_matrix(base.frames, base.shape_names, corrections)
    source = original_version(base, settings, inputs, character=character)
    if parent:
        source = replace(source, name=parent, parent="", summary={})
    notes = []
    if kind == "actor_basis":
        payload, tune = _tune_actor(markers, base, settings, idx, Wc, mu, source.name, notes)
    elif kind == "character_basis":
        payload, tune = _tune_character(markers, character, base, settings, idx, Wc, mu, source.name, notes)
    else:
        if mu is not None:
            notes.append(f"tuning: mu applies to library retunes; '{settings.strategy}' refits its examples")
        payload, tune = _tune_examples(source.payload, base, idx, Wc), None
    changed = payload_digest(kind, payload) != payload_digest(kind, source.payload)
    root = source.name.split("+")[0]
    name = f"{root}+tune{len(idx)}f-{payload_digest(kind, payload)}" if changed else source.name
    version = LibraryVersion(name, source.name if changed else source.parent, settings.strategy, kind, payload,
                             _now(), {}, tuple(base.shape_names))
    if changed:
        c2, i2, s2 = apply_version(version, character, inputs, settings)
        result = retarget(markers, c2, s2, inputs=i2)
    else:
        notes.append("tuning: library unchanged; the take keeps its solve")
        result = base
    before = _rms(np.where(np.isfinite(Wc), base.weights[idx] - Wc, np.nan))
    after = _rms(np.where(np.isfinite(Wc), result.weights[idx] - Wc, np.nan))
    other = np.ones(len(base.frames), dtype=bool)
    other[idx] = False
    ref = _rms(base.weights[other])
    moved = _rms(result.weights[other] - base.weights[other]) / ref if ref > 0 else 0.0
    frames = np.asarray(base.frames)[idx]
    summary = {"corrected_rmse_before": before, "corrected_rmse_after": after, "others_moved": moved,
               "corrected_frames": frames, "corrected_shapes": [base.shape_names[k] for k in
                                                                np.flatnonzero(np.isfinite(Wc).any(axis=0))],
               "notes": notes + ([] if tune is None else list(tune.notes))}
    if tune is not None:
        summary.update(mu=tune.mu if np.isfinite(tune.mu) else None, candidate=tune.candidate, model=tune.model,
                       changed_poses=list(tune.changed),
                       gains={n: float(tune.gains[tune.library.shape_names.index(n)]) for n in tune.changed})
    version = replace(version, summary=summary)
    return TakeTuneResult(version=version, result=result, before=base, corrected_rmse_before=before,
                          corrected_rmse_after=after, others_moved=moved, notes=tuple(summary["notes"]),
                          frames=frames, parent_version=source, changed=changed, tune=tune)


def _tune_actor(markers, base, settings, idx, Wc, mu, parent, notes):
    """calibrated/refine: retune the actor library on the aligned actor deltas and pose activations."""

    strategy = base.fitted
    lib = strategy.actor_basis
    deltas, neutral, names = _take_deltas(base, settings)
    D = reorder(deltas, names, lib.marker_names)
    D, _ = align_to(D, reorder(neutral[None], names, lib.marker_names)[0], lib.neutral, mode=strategy.align)
    pose = _pose_corrections(strategy.mapping, base.shape_names, Wc, notes)
    keep = np.isfinite(pose).any(axis=1)
    if not keep.any():
        raise FacecapError("tuning: no corrected shape maps back to a single actor pose; nothing to retune from")
    corr = {int(t): row for t, row in zip(idx[keep], pose[keep])}
    tune = retune(lib, D, base.source_weights, corr, mu=mu, solver=_actor_solver(strategy),
                  frame_solver=_actor_solver(strategy, per_frame=True), parent=parent)
    return tune.library, tune


def _take_deltas(base, settings):
    """The stabilised, neutral-normalised actor deltas (F, M, 3), neutral (M, 3) and marker names the
    pipeline solved: its final stabilisation and the same normalisation (``pipeline.stages.normalise_stabilised``)."""

    stab = base.stabilise
    neutral, offsets, _ = normalise_stabilised(stab, settings, [])
    positions = stab.markers.positions if offsets is None else stab.markers.positions + offsets
    return positions - neutral[None], neutral, tuple(stab.markers.names)


def _actor_solver(strategy, *, per_frame=False):
    """The strategy's own actor solve (its priors) as (Basis, deltas) -> activations, NaN unsolved."""

    def solve(lib, D):
        F, M, Dm = D.shape
        res = solve_bounded(lib.matrix(), D.reshape(F, M * Dm), dims=Dm, lower=lib.lower, upper=lib.upper,
                            regularisation=strategy.regularisation, sparsity=strategy.sparsity,
                            symmetry=symmetric_pairs(lib.shape_names) if strategy.symmetry > 0 else (),
                            symmetry_weight=strategy.symmetry,
                            smoothing=(0.0, 0.0) if per_frame else strategy.smoothing, relative=True)
        w = np.array(res.weights, dtype=np.float64)
        w[~res.solved] = np.nan
        return w

    return solve


def _pose_corrections(mapping, shape_names, Wc, notes):
    """Character corrections (T, K) -> actor pose corrections (T, S) through single-source rows."""
    G, off = mapping.matrix, mapping.offset
    T, S = Wc.shape[0], G.shape[1]
    total, count = np.zeros((T, S)), np.zeros((T, S))
    spread = np.zeros(S)
    skipped = []
    for k in np.flatnonzero(np.isfinite(Wc).any(axis=0)):
        src = np.flatnonzero(G[k])
        if len(src) != 1:
            skipped.append(shape_names[k])
            continue
        i = src[0]
        v = (Wc[:, k] - off[k]) / G[k, i]
        ok = np.isfinite(v)
        first = np.where(count[:, i] > 0, total[:, i] / np.maximum(count[:, i], 1), np.nan)
        spread[i] = max(spread[i], float(np.nanmax(np.abs(np.where(ok, v, np.nan) - first), initial=0.0)))
        total[ok, i] += v[ok]
        count[ok, i] += 1
    if skipped:
        notes.append(f"tuning: {len(skipped)} corrected shape(s) have no single actor pose driving them and were "
                     f"not used: {skipped}")
    disagree = [mapping.source_names[i] for i in np.flatnonzero(spread > 1e-6)]
    if disagree:
        notes.append(f"tuning: shapes driven by the same pose were corrected differently (averaged): {disagree}")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def _tune_character(markers, character, base, settings, idx, Wc, mu, parent, notes):
    """geometric: retune the character's shapes at the bound points on the aligned character-space deltas."""

    if markers.dim != 3:
        raise FacecapError("tuning: retuning a 2D (video) geometric solve is not supported; use the shape controls")
    used = tuple(base.marker_names)
    actor, _, names = _take_deltas(base, settings)
    deltas = base.alignment.apply_vectors(actor[:, [names.index(n) for n in used]])
    sub = character.subset_markers(used)
    lower, upper = resolve_bounds(sub.shape_names, sub.lower, sub.upper, settings.bounds)
    lib = Basis(sub.shape_names, used, sub.neutral, sub.deltas, lower, upper)
    locks = resolve_locks(sub.shape_names, settings.locks, n_frames=deltas.shape[0])  # (K,) or per frame (F, K)
    regions, _ = resolve_regions(sub.shape_names, used, settings.regions, dims=3)
    options = GeometricOptions(regularisation=settings.regularisation, sparsity=settings.sparsity,
                               symmetry=settings.symmetry, smoothing=tuple(settings.smoothing))

    def solver(b, D, per_frame=False):
        held = locks if locks.ndim == 1 or not per_frame else locks[0] * np.nan  # single frames: no per-frame locks
        res = solve_geometric(b, D, options=replace(options, smoothing=(0.0, 0.0)) if per_frame else options,
                              locks=None if np.isnan(held).all() else held, regions=regions)
        w = np.array(res.weights, dtype=np.float64)
        w[~res.solved] = np.nan
        return w

    corr = {int(t): row for t, row in zip(idx, Wc)}
    tune = retune(lib, deltas, base.weights, corr, mu=mu, solver=solver,
                  frame_solver=lambda b, D: solver(b, D, per_frame=True), parent=parent)
    # the version keeps the character's own slider ranges ([solve] bounds stay a solve option)
    return Basis(sub.shape_names, used, sub.neutral, tune.library.deltas, sub.lower, sub.upper), tune


def _current_examples(inputs, settings, shape_names):
    """The examples a linear/rbf/pca solve used, as ExamplePairs over the character's shapes."""
    ex = None if inputs is None else inputs.examples
    if ex is None:
        raise FacecapError(f"tuning: strategy '{settings.strategy}' has no examples to retune")
    if ex.markers is not None:
        raise FacecapError("tuning: the examples belong to another take ([examples] markers); a retune adds frames of "
                           "this take, so pose the examples on the take being solved")
    frames = np.asarray(ex.frames, dtype=np.float64)
    values = np.asarray(ex.weights, dtype=np.float64)
    if settings.examples.frames:
        rows = [i for i, f in enumerate(frames) if any(abs(f - g) < 1e-6 for g in settings.examples.frames)]
        frames, values = frames[rows], values[rows]
    col = {name_key(n): j for j, n in enumerate(ex.names)}
    W = np.zeros((len(frames), len(shape_names)))
    for k, n in enumerate(shape_names):
        j = col.get(name_key(n))
        if j is not None:
            W[:, k] = values[:, j]
    return ExamplePairs(frames, W, tuple(shape_names), None)


def _tune_examples(current, base, idx, Wc):
    """The corrected frames as examples: set shapes from the animator, the rest from the example
    already at that frame or the solve."""
    frames = list(np.asarray(current.frames, dtype=np.float64))
    W = [row for row in np.asarray(current.weights, dtype=np.float64)]
    for t, row in zip(idx, Wc):
        f = float(base.frames[t])
        hit = [i for i, g in enumerate(frames) if abs(g - f) < 1e-6]
        start = W[hit[0]].copy() if hit else np.asarray(base.weights[t], dtype=np.float64).copy()
        new = np.where(np.isfinite(row), row, start)
        if not np.isfinite(new).all():
            raise FacecapError(f"tuning: frame {f:g} was not solved; set every shape on it to use it as an example")
        if hit:
            W[hit[0]] = new
        else:
            frames.append(f)
            W.append(new)
    order = np.argsort(frames, kind="stable")
    return ExamplePairs(np.asarray(frames)[order], np.asarray(W)[order], tuple(current.names), None)
