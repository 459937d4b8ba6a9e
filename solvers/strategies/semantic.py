"""The ``semantic`` strategy (the default): solve what the ACTOR does, shape by shape, against the actor's own
face as well as it is known (``actor_model``: calibration, poses, a performer profile, a human template, or
nothing but the character), and key those activations on the character's shapes of the same name.

The solve is the engine's bounded, sparse, temporally smooth least squares in actor space, with:

* shapes no marker sees held at rest (``ActorModel.unseen``);
* opposing shapes kept exclusive (``jawLeft``/``jawRight``, gaze in/out, blink/wide, ...): a quick per-frame
  solve (or the head refits' last one) decides, frame by frame (smoothed), which side of each pair is active,
  and the final solve holds the other side at 0, so a pair never cancels itself to explain motion neither
  side makes;
* the eyes turning together (``CONJUGATE_GAZE``: one eye's look in with the other's look out, up with up);
* an approximate actor model (template, character) trusts a marker less where it predicts large motion
  (its error grows with the motion), and shapes it pins at their limit are solved again with firmer priors;
* the priors of ``geometric`` (relative to the mean size of the shapes: per-shape priors let marker noise
  into the subtle shapes and measured worse on self-retargets).

It predicts the markers (``PredictsMarkers``), so the pipeline refits the head against it as for
``geometric``.
"""

import numpy as np

from ..character.shape_options import resolve_bounds, resolve_locks, resolve_regions
from ..engine import solve_bounded
from ..errors import FacecapError
from ..options import default
from .actor_model import ActorKnowledge, build_actor_model
from .base import StrategyResult, as_target
from .geometric import QUICK_SOLVE, residual_rms, symmetric_pairs, taken_markers
from .mapping import Mapping
from .sources import as_deltas

#: Pairs of shapes that act against each other: at most one of each is active in a frame.
OPPOSING = (
    ("jawLeft", "jawRight"), ("mouthLeft", "mouthRight"),
    ("eyeLookInLeft", "eyeLookOutLeft"), ("eyeLookInRight", "eyeLookOutRight"),
    ("eyeLookUpLeft", "eyeLookDownLeft"), ("eyeLookUpRight", "eyeLookDownRight"),
    ("eyeBlinkLeft", "eyeWideLeft"), ("eyeBlinkRight", "eyeWideRight"),
)
#: How wrong the actor model is, relative to the motion it predicts (the trust of a marker sample falls as the
#: motion predicted there passes noise / MODEL_ERROR).
MODEL_ERROR = 0.1
#: The noise the model error is compared with is at least this (metres): filtered captures show less.
NOISE_FLOOR = 2e-4
#: The priors' factor when nothing is known of the actor and the character's shapes do not explain the markers
#: (the solve then shrinks towards rest; realism benchmark, 3 draws onto the sample character: weights RMSE
#: 0.197 -> 0.179, the share at the upper bound 1.2 -> 0.6 %).
UNCERTAIN_PRIORS = 10.0
#: The priors' factor on shapes completed from the character's through measured poses (12 poses on the sample
#: character: 0.187 -> 0.178 weights RMSE against 10x, mean per-shape r 0.23 -> 0.38).
TRANSFERRED_PRIORS = 3.0
#: A shape of an approximate actor model at its upper limit in more than this share of frames is solved again
#: with its priors this much firmer (a held limit for seconds is a model that cannot explain the motion;
#: Facial-Sing onto the sample character: 2.7 -> 1.0 % of the weights at 1.0).
PINNED_SHARE, PINNED_PRIORS = 0.2, 10.0
#: Frames over which a pair's active side is decided (a running mean of their difference).
DECIDE_FRAMES = 9
#: The eyes turn together: each eye's look in goes with the other's look out, up with up, down with down.
CONJUGATE_GAZE = (
    ("eyeLookInLeft", "eyeLookOutRight"), ("eyeLookOutLeft", "eyeLookInRight"),
    ("eyeLookUpLeft", "eyeLookUpRight"), ("eyeLookDownLeft", "eyeLookDownRight"),
)
#: How firmly (in the priors' relative units) the gaze pairs are held together when markers drive the gaze shapes
#: (the template's or measured gaze shapes move the lid markers). Facial-Sing with the template: eyeLookInLeft
#: above 0.3 in 31 % of the frames while eyeLookOutRight was in 9 % -> both 18 %; realism benchmark (5 draws,
#: dense): template 0.086 -> 0.085, a pose per shape 0.057 -> 0.056 (r 0.89 -> 0.91), 12 poses + template
#: 0.074 -> 0.073; 0.3 and 3 measured the same.
CONJUGATE_WEIGHT = 1.0


def with_conjugate_gaze(regularisation, shape_names, weight=None):
    """The priors ``regularisation`` (scalar or (K,)) as a (K, K) matrix that also penalises
    ``weight * (w_a - w_b)^2`` for every ``CONJUGATE_GAZE`` pair the shapes have (unchanged without one)."""
    weight = CONJUGATE_WEIGHT if weight is None else weight
    index = {n: i for i, n in enumerate(shape_names)}
    pairs = [(index[a], index[b]) for a, b in CONJUGATE_GAZE if a in index and b in index]
    if not pairs or weight <= 0:
        return regularisation
    K = len(shape_names)
    R = np.diag(np.broadcast_to(np.asarray(regularisation, dtype=np.float64), (K,)).copy())
    for a, b in pairs:
        R[a, a] += weight
        R[b, b] += weight
        R[a, b] -= weight
        R[b, a] -= weight
    return R


def opposing_pairs(shape_names):
    """Index pairs of ``OPPOSING`` shapes that ``shape_names`` has."""
    index = {n: i for i, n in enumerate(shape_names)}
    return [(index[a], index[b]) for a, b in OPPOSING if a in index and b in index]


def exclusive_locks(weights, pairs, locks):
    """``locks`` (F, K) with the weaker side of every pair held at 0, decided on a running mean of the
    pair's difference in ``weights`` (F, K) (a side may take over only smoothly)."""
    out = locks.copy()
    kernel = np.ones(DECIDE_FRAMES) / DECIDE_FRAMES
    for a, b in pairs:
        diff = np.nan_to_num(weights[:, a] - weights[:, b])
        diff = np.convolve(np.pad(diff, DECIDE_FRAMES // 2, mode="edge"), kernel, mode="valid")
        out[:, b] = np.where((diff > 0) & np.isnan(out[:, b]), 0.0, out[:, b])
        out[:, a] = np.where((diff <= 0) & np.isnan(out[:, a]), 0.0, out[:, a])
    return out


class SemanticStrategy:
    """Solve the actor's activations of the character's (semantic) shapes against the actor model.

    Parameters (keyword-only): the priors ``regularisation``, ``sparsity``, ``symmetry``, ``smoothing`` (as
    ``geometric``); ``exclusive`` keeps opposing shapes apart; ``model_error`` (see ``MODEL_ERROR``).
    """

    name = "semantic"
    source_kind = "markers"

    def __init__(self, *, regularisation=default("solve.regularisation"), sparsity=default("solve.sparsity"),
                 symmetry=default("solve.symmetry"), smoothing=default("solve.smoothing"), exclusive=True,
                 model_error=MODEL_ERROR):
        for key, value in (("regularisation", regularisation), ("sparsity", sparsity), ("symmetry", symmetry)):
            if not value >= 0:
                raise FacecapError(f"semantic: `{key}` must be >= 0; got {value}")
        self.regularisation, self.sparsity, self.symmetry = float(regularisation), float(sparsity), float(symmetry)
        self.smoothing = (float(smoothing[0]), float(smoothing[1]))
        self.exclusive = bool(exclusive)
        self.model_error = float(model_error)
        self.noise = float("nan")
        self.model = None
        self.notes = ()
        self.rom = None  # the RomResult the actor model was measured from ([calibration] sequence)

    def fit(self, character, *, names, neutral, knowledge=ActorKnowledge(), character_deltas=None, deltas=None,
            noise=None, alignment=None, alignment_names=(), bounds=(), locks=(), regions=()):
        """Build the actor model (``actor_model.build_actor_model``) for the take's markers ``names`` with
        neutral ``neutral`` (M, 3); ``bounds``/``locks`` are the ``[solve]`` shape options; ``alignment`` (the
        actor -> character alignment of the markers ``alignment_names``, for the report) is returned with every
        solve."""
        self.alignment, self.alignment_names = alignment, tuple(alignment_names)
        target = as_target(character)
        self.model = build_actor_model(character, tuple(names), np.asarray(neutral, dtype=np.float64), knowledge,
                                       character_deltas=character_deltas, deltas=deltas, noise=noise)
        self.lower, self.upper = resolve_bounds(target.names, target.lower, target.upper, bounds)
        self.lock_patterns = tuple(locks)
        basis = self.model.basis
        self.regions, held = resolve_regions(basis.shape_names, basis.marker_names, regions, dims=3)
        self.notes = self.model.notes + ((f"{len(held)} shape(s) are in no region and are held: {', '.join(held)}",)
                                         if held else ())
        self.noise = float("nan") if noise is None else float(noise)
        # measured shapes are the actor's own: only a template's or the character's carry model error
        # (all of it for a template's; for the character's, as far as they fail to explain the markers)
        tier = self.model.tier
        self.error = 0.0 if tier in ("calibration", "profile") else \
            self.model_error * (self.model.mismatch if tier == "character" else 1.0)
        # shapes taken from a character that does not describe the actor are uncertain: firmer priors (all of
        # them when nothing is known and the character's shapes do not explain the markers; the ones completed
        # from the character when some are measured)
        weak = np.array([s.endswith("(character)") for s in self.model.sources])
        self.prior_scale = np.where(weak, TRANSFERRED_PRIORS, 1.0 + (UNCERTAIN_PRIORS - 1.0) * self.model.mismatch)
        return self

    @property
    def marker_names(self):
        return self.model.basis.marker_names

    # What the feedback loop retunes (``tuning.take``): the actor model as an actor library, solved one-to-one
    # onto the shapes of the same name, in the take's own head frame.
    align = "none"

    @property
    def actor_basis(self):
        return None if self.model is None else self.model.basis

    @property
    def mapping(self):
        names = self.model.basis.shape_names
        return Mapping.by_name(names, names, aliases=False)

    def _model_error_confidence(self, weights, deltas, confidence, D):
        """(F, U) trust per marker sample: the actor model is wrong by about ``self.error`` of the motion it
        predicts, so a marker moving far (the lips when the jaw opens) is trusted less than its noise alone
        says, and its model error is not explained by other shapes (a jaw open turned into ``jawRight``)."""
        K, U, _ = deltas.shape
        motion = np.linalg.norm((np.nan_to_num(weights) @ deltas.reshape(K, -1)).reshape(-1, U, 3), axis=2)
        noise = max(self.noise, NOISE_FLOOR)  # a capture system's filtering can hide most of its noise
        trust = 1.0 / (1.0 + (self.error * motion / noise) ** 2)
        seen = np.isfinite(D[:, :, 0])
        trust[~seen] = 0.0
        trust /= trust[seen].mean() if seen.any() else 1.0  # the same total trust: the priors keep their weight
        return trust if confidence is None else trust * confidence

    def solve(self, source, *, names=None, neutral=None, confidence=None, start=None, quick=False,
              overwrite=False):
        """Character weights for actor-space deltas ``source`` (F, M, 3) named ``names`` (see ``geometric``
        for ``start``, ``quick`` and ``overwrite``; ``neutral`` is not needed: the model is in actor space)."""
        if self.model is None:
            raise FacecapError("semantic: call fit() before solve()")
        basis = self.model.basis
        deltas = as_deltas(source, overwrite=overwrite)
        names = tuple(basis.marker_names if names is None else names)
        missing = [n for n in basis.marker_names if n not in names]
        if missing:
            raise FacecapError(f"semantic: the take has no marker(s) {missing[:8]} of the actor model")
        idx = [names.index(n) for n in basis.marker_names]
        D = taken_markers(deltas, idx, None, overwrite=overwrite)  # in the take's memory when it is given up
        F, U, _ = D.shape
        if confidence is not None:
            confidence = np.take(np.nan_to_num(np.asarray(confidence, dtype=np.float64)), idx, axis=1)
        A = basis.matrix()
        locks = resolve_locks(basis.shape_names, self.lock_patterns, n_frames=F)
        locks = np.broadcast_to(locks, (F, basis.n_shapes)).copy() if locks.ndim == 1 else locks.copy()
        for name in self.model.unseen:
            locks[:, basis.shape_names.index(name)] = 0.0
        pairs = symmetric_pairs(basis.shape_names) if self.symmetry > 0 else ()
        if self.regions:  # a coupled pair must share a region
            region_of = {int(k): i for i, (shapes, _) in enumerate(self.regions) for k in shapes}
            pairs = [(a, b) for a, b in pairs if region_of.get(a, -1) == region_of.get(b, -2)]
        kwargs = dict(mask=confidence, dims=3, lower=self.lower, upper=self.upper, regions=self.regions,
                      regularisation=with_conjugate_gaze(self.regularisation * self.prior_scale, basis.shape_names),
                      sparsity=self.sparsity * self.prior_scale, symmetry=pairs,
                      symmetry_weight=self.symmetry, smoothing=(0.0, 0.0) if quick else self.smoothing, relative=True)
        extra = QUICK_SOLVE if quick else {}
        flat = D.reshape(F, U * 3)
        opposing = opposing_pairs(basis.shape_names) if self.exclusive and not quick else []
        reweight = self.error > 0 and not quick and np.isfinite(self.noise) and self.noise > 0
        if opposing or reweight:
            # what each frame does, roughly: the head refits' last quick solve, or a quick per-frame one
            guess = start if start is not None else solve_bounded(
                A, flat, locks=locks, **{**kwargs, "smoothing": (0.0, 0.0)}, **QUICK_SOLVE).weights
            if opposing:
                locks = exclusive_locks(guess, opposing, locks)
            if reweight:
                kwargs["mask"] = self._model_error_confidence(guess, basis.deltas, kwargs["mask"], D)
            start = guess
        locks = None if np.isnan(locks).all() else locks
        res = solve_bounded(A, flat, locks=locks, start=start, **kwargs, **extra)
        notes = []
        pinned = self._pinned(res.weights) if not quick and self.error > 0 else []
        if pinned:  # an approximate actor model pins shapes to explain what it cannot: firmer priors on them
            factor = np.where(np.isin(np.arange(basis.n_shapes), pinned), PINNED_PRIORS, 1.0) * self.prior_scale
            kwargs.update(regularisation=with_conjugate_gaze(self.regularisation * factor, basis.shape_names),
                          sparsity=self.sparsity * factor)
            res = solve_bounded(A, flat, locks=locks, start=res.weights, **kwargs, **extra)
            notes.append(f"{len(pinned)} shape(s) sat at their upper limit in more than {100 * PINNED_SHARE:.0f}% of "
                         f"frames and were solved again with firmer priors (the actor model does not explain what "
                         f"drives them): {', '.join(basis.shape_names[k] for k in pinned)}")
        rms = residual_rms(res.weights, basis.deltas, D)
        rms[~res.solved] = np.nan
        info = {"mode": res.mode, "actor_model": self.model.report()}
        if self.rom is not None:
            info["rom"] = self.rom.report()
        return StrategyResult(weights=res.weights, shape_names=basis.shape_names, solved=res.solved,
                              source_weights=res.weights, source_names=basis.shape_names,
                              warnings=tuple(self.notes) + tuple(notes) + tuple(res.warnings), residual_rms=rms,
                              clamped=np.zeros(F, dtype=int), info=info, solve=res, marker_names=basis.marker_names,
                              alignment=self.alignment, alignment_residual=self._alignment_residual(basis.marker_names))

    def _pinned(self, weights):
        """Shapes at their upper limit in more than ``PINNED_SHARE`` of the frames."""
        top = np.nan_to_num(weights) >= np.asarray(self.upper)[None] - 1e-3
        return [k for k in np.flatnonzero(top.mean(axis=0) > PINNED_SHARE)]

    def _alignment_residual(self, names):
        """Each of ``names``' distance from its bound point after the alignment (NaN where not bound)."""
        if self.alignment is None:
            return None
        bound = list(self.alignment_names)
        return np.array([self.alignment.residual[bound.index(n)] if n in bound else np.nan for n in names])

    def predict(self, result):
        """Actor-space deltas (F, U, 3) of ``result.marker_names`` that ``result``'s weights explain."""
        K, U, D = self.model.basis.deltas.shape
        return (np.nan_to_num(result.weights) @ self.model.basis.deltas.reshape(K, U * D)).reshape(-1, U, D)
