"""A rig as the target of the one solve path: its basis for the linear solve, then its controls.

``RigTarget`` is what a front end hands ``solvers.solve`` (``SolveRequest.rig``): either a probed
``RigModel`` (the controls are the solve's columns; the linear solve starts the bounded nonlinear
solve of ``nonlinear``, then frames where the real rig differs from the model are refined through
the rig) or a ``PoseLibrary`` (the poses are the columns; any strategy solves them by name; the
weights become control values). ``finish`` turns the pipeline's ``RetargetResult`` over the
columns into one over the controls: ``shape_names`` are the control names, ``weights`` the raw
control values, the residuals those of the final solve, and ``info["rig"]`` says what was done.

A probed rig's columns are its controls' offsets from rest in units of each control's span
(``RigModel.normalised``): a bone moving in metres, one turning in radians and a 0..1 slider each
run over about -1..1, so the solve's priors (regularisation, sparsity, smoothing, relative to the
mean squared column like every solve's) weigh each control by its range, never by its effect per
unit of its own. What crosses into the solve in control values (corrections, locks, bounds) is
converted on the way in (``offsets_of``, ``column_settings``) and the controls on the way out.
"""

import glob
import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from ..character.shape_options import resolve_bounds, resolve_locks
from ..errors import FacecapError
from ..pipeline import stages
from . import head
from .nonlinear import iterate_nonlinear
from .start import curved_start
from .poses import PoseLibrary

METHODS = ("probed", "poses")
#: A frame's Gauss-Newton block is formed again once a control moved this share of its span.
HESSIAN_REUSE = 0.02
#: Frames each side of a refined frame that are solved again with it.
REFINE_PAD = 8
#: Gauss-Newton iterations at most of a solve started from the one before (after a head refit, a
#: refinement round): the data moved a little.
WARM_ITER = 5
#: A solve that another follows (a head refit, a refinement round) stops once a step lowers the
#: objective by less than this share of it; the last one by less than ``FINAL_TOL``.
LOOSE_TOL, FINAL_TOL = 1e-3, 1e-4
#: A frame is refined through the rig where the rig's defect exceeds this share of the solve's
#: residual there (and ``refine_mm``): on a capture the model does not fit to a small part of a
#: millimetre, refining every frame would not change what the markers say.
REFINE_SHARE = 0.1


@dataclass(frozen=True, eq=False)
class RigTarget:
    """What the solve needs of a rig.

    method : "probed" (``model``) or "poses" (``library`` with ``library_basis``, the poses at the bound points)
    model : RigModel over the controls (probed; optional for poses, unused there)
    nonlinear : solve the model's curvature and pair terms after the linear solve (probed)
    evaluate : optional callable, control offsets (N, C) -> real deltas (N, M, D) at ``model.marker_names``:
        the refinement through the rig
    refine_mm : frames where the rig and the model differ by more than this (mm, RMS over the
        markers) are refined through the rig
    refine_rounds : refinement rounds at most
    refine_stride : the rig is evaluated on every n-th frame of a refinement round (1: every frame)
    max_iter : Gauss-Newton iterations per solve
    info : what building the target found (probing report), carried into ``info["rig"]``
    notes : warnings of building the target (drivers that could not run, driven shapes left out),
        added to the result's
    tuned : ndarray (C, M, D), optional: what a library version (a retune, *Use Library Version*)
        changed of the columns the linear solve sees; the nonlinear model takes it as a change of
        each control's first-order term (``with_columns``)
    reference : the slow path the fast one is checked against: Gauss-Newton blocks formed in float64
        on every frame at every iteration, and each refinement round a solve of the whole take (the
        fast path forms them in float32, keeps a frame's block while its controls barely move, and
        re-solves only windows around the frames the rig refines, their neighbours held)
    """

    method: str
    model: object = None
    library: PoseLibrary = None
    library_basis: object = None
    nonlinear: bool = True
    evaluate: object = None
    refine_mm: float = 0.05
    refine_rounds: int = 2
    refine_stride: int = 1
    max_iter: int = 20
    info: dict = field(default_factory=dict)
    reference: bool = False
    notes: tuple = ()
    tuned: object = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise FacecapError(f"[rig] method must be one of {', '.join(METHODS)}; got '{self.method}'")
        if self.method == "probed" and self.model is None:
            raise FacecapError("[rig] method \"probed\" needs the rig's model (probe the rig first)")
        if self.method == "poses" and (self.library is None or self.library_basis is None):
            raise FacecapError("[rig] method \"poses\" needs a pose library evaluated at the bound points")

    @property
    def control_names(self):
        return self.model.control_names if self.method == "probed" else self.library.control_names

    @cached_property
    def unit_model(self):
        """The model over each control's offset in units of its span (probed), with ``tuned``."""
        model = self.model.normalised()
        if self.tuned is None:
            return model
        # a change of a control's column is a gain on its whole own response (a retune's usual
        # answer) plus what remains, added to its first-order term on the side of its secant
        secant = model.secant().reshape(model.n_controls, -1)
        change = self.tuned.reshape(model.n_controls, -1)
        norm = np.einsum("cp,cp->c", secant, secant)
        gain = 1.0 + np.where(norm > 0, np.einsum("cp,cp->c", change, secant) / np.where(norm > 0, norm, 1.0), 0.0)
        rest = (change - (gain - 1.0)[:, None] * secant).reshape(self.tuned.shape)
        g = gain[:, None, None]
        linear, square, cube, negative = model.linear * g, model.square * g, model.cube * g, model.negative * g
        down = model.split & (model.secant_ends() < 0)
        linear[~down] += rest[~down]
        negative[0, down] += rest[down]
        return replace(model, linear=linear, square=square, cube=cube, negative=negative)

    def with_columns(self, basis):
        """This target solving the columns ``basis`` (a library version of ``character``: a retune's,
        or the one the animator chose) instead of its own, the nonlinear model's first-order terms
        moved to match; itself when they are its own."""
        if self.method != "probed" or basis is None:
            return self
        own = self.model.normalised().basis()
        if basis.shape_names != own.shape_names or basis.marker_names != own.marker_names:
            return self
        change = np.asarray(basis.deltas) - own.deltas
        if not np.any(change):
            return self
        return replace(self, tuned=change)

    @property
    def character(self):
        """The Basis the pipeline solves: the normalised model's secant basis, or the poses."""
        return self.unit_model.basis() if self.method == "probed" else self.library_basis

    def to_columns(self, values, name):
        """Control values -> the solve's column values for control ``name`` (probed)."""
        k = self.model.control_names.index(name)
        return (np.asarray(values, dtype=np.float64) - self.model.rest[k]) / self.model.span[k]

    def column_settings(self, settings, n_frames):
        """``settings`` with its locks and bounds (control values) in the solve's columns (probed)."""
        if self.method != "probed" or not (settings.locks or settings.bounds):
            return settings
        names, model = self.model.control_names, self.model
        locks = resolve_locks(names, settings.locks, n_frames=n_frames) if settings.locks else None
        held = [] if locks is None else [(glob.escape(n), self.to_columns(locks[..., k], n)) for k, n in
                                         enumerate(names) if not np.isnan(locks[..., k]).all()]
        bounds = ()
        if settings.bounds:
            lo, hi = resolve_bounds(names, model.lower, model.upper, settings.bounds)
            bounds = tuple((glob.escape(n), float(self.to_columns(a, n)), float(self.to_columns(b, n)))
                           for n, a, b in zip(names, lo, hi))
        return replace(settings, locks=tuple((p, v if np.ndim(v) else float(v)) for p, v in held), bounds=bounds)

    @property
    def weight_controls(self):
        """The controls that read as shape weights: at rest at 0, limited to 0 and 1 (probed rigs; a pose library
        says no limits). A landmark take's blendshape scores and eye locks reach these alone: a weight of 0-1
        written into a control of another range would be a value on another scale."""
        if self.method != "probed":
            return ()
        m = self.model
        like = (np.abs(m.rest) < 1e-6) & (np.abs(m.lower) < 1e-6) & (np.abs(m.upper - 1.0) < 1e-6)
        return tuple(n for n, ok in zip(m.control_names, like) if ok)

    @property
    def defers_head_refits(self):
        """Whether the head refits of hierarchical stabilisation are done by the nonlinear solve,
        against the rig model (``solvers.rig.head``), instead of by the pipeline's linear solve."""
        return self.method == "probed" and self.nonlinear and not self.model.is_linear()

    def steps_for(self, settings):
        """Job steps ``finish_steps`` may take with ``settings`` (for a progress bar)."""
        if self.method == "poses" or not self.nonlinear:
            return 1
        refits = settings.fine_iterations if self.defers_head_refits else 0
        return self.max_iter + min(self.max_iter, WARM_ITER) * (refits + self.refine_rounds) + 1

    def offsets_of(self, controls):
        """Corrections in control values {frame: {control: value}} -> the solve's column values (probed)."""
        if controls is None:
            return None
        if self.method != "probed":
            raise FacecapError("tuning from corrections needs [rig] method = \"probed\" (the controls are the columns)")
        known = set(self.model.control_names)
        return {f: {n: (float(self.to_columns(v, n)) if n in known else v) for n, v in row.items()}
                for f, row in controls.items()}

    def finish_steps(self, result, markers, settings):
        """Generator: the pipeline's ``result`` over the columns -> a RetargetResult over the controls."""
        t0 = time.perf_counter()
        if self.method == "poses":
            controls = self.library.controls(result.weights)
            info = {"method": "poses", "poses": list(self.library.pose_names), **self.info}
            yield None
            return replace(result, shape_names=self.library.control_names, weights=controls,
                           source_weights=result.weights, source_names=self.library.pose_names,
                           warnings=tuple(self.notes) + tuple(result.warnings),
                           info={**result.info, "rig": info}, timings={**result.timings, "rig": time.perf_counter() - t0})
        model = self.model
        info = {"method": "probed", "nonlinear": False, **self.info}
        out = result
        if self.nonlinear and not model.is_linear() and _markers_3d(result, markers):
            out, solve_info = yield from self._refine(result, markers, settings)
            info.update(solve_info)
        else:
            yield None
        weights = model.controls(np.asarray(out.weights, dtype=np.float64) * model.span)
        timings = {**result.timings, "rig": round(time.perf_counter() - t0, 6)}
        return replace(out, shape_names=model.control_names, weights=weights, info={**out.info, "rig": info},
                       timings=timings, warnings=tuple(self.notes) + tuple(out.warnings))

    def _refine(self, result, markers, settings):
        """The nonlinear solve from the linear one, the head refitted against it and solved again
        (``settings.fine_iterations`` times), then frames refined through the rig: a generator of
        Gauss-Newton steps returning (result, info)."""
        model = self.unit_model.subset_markers(result.marker_names)
        # [solve] bounds (in the columns' units already) replace the rig's limits, as in the linear solve
        bounds = resolve_bounds(model.control_names, model.lower, model.upper, settings.bounds)
        deltas = character_deltas(result, settings)
        F = deltas.shape[0]
        solved = np.isfinite(result.weights).all(axis=1)
        locks = resolve_locks(model.control_names, settings.locks, n_frames=F)
        locks = None if np.isnan(locks).all() else locks
        priors = dict(regularisation=settings.regularisation, sparsity=settings.sparsity, smoothing=settings.smoothing,
                      locks=locks, max_iter=self.max_iter, bounds=bounds)
        fast = {} if self.reference else {"hessian": np.float32, "reuse": HESSIAN_REUSE}
        refits = settings.fine_iterations if self.defers_head_refits else 0
        evaluate = None if self.evaluate is None else (lambda v, span=self.model.span: self.evaluate(v * span))
        rounds = self.refine_rounds if evaluate is not None else 0
        warm = {"max_iter": min(self.max_iter, WARM_ITER), "tol": FINAL_TOL}
        first = {"tol": LOOSE_TOL if refits or rounds else FINAL_TOL}
        start = curved_start(model, deltas, regularisation=settings.regularisation, lower=bounds[0] - model.rest,
                             upper=bounds[1] - model.rest, locks=locks)
        start = result.weights if start is None else start
        nl = yield from iterate_nonlinear(model, deltas, start=np.where(solved[:, None], start, 0.0),
                                          **priors, **first, **fast)
        iterations = nl.iterations
        stab = result.stabilise
        for _ in range(refits):
            stab = head.refit(model, nl.offsets, result, stab, markers, settings)
            deltas = character_deltas(replace(result, stabilise=stab), settings)
            nl = yield from iterate_nonlinear(model, deltas, start=nl.offsets, **{**priors, **warm}, **fast)
            iterations += nl.iterations
        result = replace(result, stabilise=stab)
        info = {"nonlinear": True, "linear_residual_mm": _mean_mm(result.residual_rms[solved]),
                "model_residual_mm": _mean_mm(nl.residual_rms[solved])}
        u, rms, refined, last, changed = nl.offsets, nl.residual_rms.copy(), 0, nl, None
        for _ in range(rounds):
            defect, bad = rig_defect(evaluate, model, u, self.model.marker_names, result.marker_names, self.refine_mm,
                                     self.refine_stride, frames=changed, residual=REFINE_SHARE * rms)
            if not bad.any():
                break
            refined = max(refined, int(bad.sum()))
            if self.reference:
                last = yield from iterate_nonlinear(model, deltas, start=u, defect=defect, **priors)
                u, rms = last.offsets, last.residual_rms
                iterations += last.iterations
                continue
            # only windows around the refined frames are solved again; their edges are held, which
            # decouples them exactly (the temporal term reaches two frames)
            window, held = refine_windows(bad, REFINE_PAD)
            idx = np.flatnonzero(window)
            sub_locks = np.full((idx.size, model.n_controls), np.nan)
            if locks is not None:
                sub_locks[:] = np.broadcast_to(locks, (F, model.n_controls))[idx]
            sub_locks[held[idx]] = u[idx][held[idx]]
            last = yield from iterate_nonlinear(model, deltas[idx], start=u[idx], defect=defect[idx],
                                                **{**priors, "locks": sub_locks, **warm}, **fast)
            u[idx], rms[idx], changed = last.offsets, last.residual_rms, window
            iterations += last.iterations
        info.update(iterations=iterations, converged=bool(last.converged), last_step_drop=float(last.last_drop))
        if evaluate is not None:
            info["refined_frames"] = refined
        u[~solved] = np.nan
        rms = np.where(solved, rms, np.nan)
        notes = () if last.converged else (
            f"rig solve: the Gauss-Newton steps stopped at their limit ({last.iterations}) while the last one still "
            f"lowered the objective by {100 * last.last_drop:.2f}% (settled is under {100 * FINAL_TOL:g}%): the "
            f"controls may still move a little; [rig] refine = false or fewer frames take fewer steps",)
        return replace(result, weights=u, residual_rms=rms, warnings=tuple(result.warnings) + notes), info


def _markers_3d(result, markers):
    return markers is not None and markers.dim == 3 and result.alignment is not None and result.stabilise is not None


def _mean_mm(values):
    values = np.asarray(values)
    values = values[np.isfinite(values)]
    return round(float(values.mean() * 1e3), 6) if values.size else None


def rig_defect(evaluate, model, u, all_markers, used, refine_mm, stride=1, frames=None, residual=None):
    """What the real rig adds to ``model`` at offsets ``u`` (F, C), on the frames where it matters
    (above ``refine_mm`` and ``residual`` (F,) metres, RMS over the markers): (defect (F, M, D) zero
    elsewhere, those frames (F,) bool). The rig is evaluated on every ``stride``-th frame (and the
    last) and the defect interpolated between them: the controls move smoothly, and so does what the
    model misses. ``frames`` (F,) bool: only these (the rest is taken as under the threshold),
    sampled on the same grid plus the ends of each run."""
    idx = [list(all_markers).index(n) for n in used]
    F = u.shape[0]
    at = np.unique(np.r_[np.arange(0, F, max(int(stride), 1)), F - 1])
    if frames is not None:
        edges = np.flatnonzero(np.diff(np.r_[0, frames.astype(np.int8), 0]))  # run starts, ends + 1
        at = np.union1d(at[frames[at]], np.r_[edges[0::2], edges[1::2] - 1]).astype(np.intp)
    real = evaluate(u[at])[:, idx]
    sampled = (real - model.deltas(u[at])).reshape(len(at), -1)
    # linear interpolation between the sampled frames, all columns at once
    right = np.clip(np.searchsorted(at, np.arange(F)), 1, max(len(at) - 1, 1)) if len(at) > 1 else np.zeros(F, int)
    left = np.maximum(right - 1, 0)
    span = np.maximum(at[right] - at[left], 1)
    w = np.clip((np.arange(F) - at[left]) / span, 0.0, 1.0)[:, None]
    defect = ((1.0 - w) * sampled[left] + w * sampled[right]).reshape((F,) + real.shape[1:])
    size = np.sqrt((defect ** 2).sum(axis=2).mean(axis=1))
    bad = size > refine_mm * 1e-3
    if residual is not None:
        bad &= size > np.nan_to_num(residual, nan=np.inf)
    if frames is not None:
        bad &= frames
    defect[~bad] = 0.0
    return defect, bad


def refine_windows(bad, pad, edge=2):
    """(window, held) (F,) bool: the frames within ``pad`` of a refined frame plus ``edge`` frames
    each side, and those edge frames (held: the temporal term couples a frame with two each side)."""
    def grow(mask, n):
        return np.convolve(mask.astype(np.int32), np.ones(2 * n + 1, dtype=np.int32), mode="same") > 0

    core = grow(bad, pad)
    window = grow(core, edge)
    return window, window & ~core


def character_deltas(result, settings):
    """The take's marker deltas in character space (F, M, D) at ``result.marker_names``: the final
    stabilisation normalised again and carried by the result's alignment (what the geometric
    strategy solved)."""
    take, _ = stages.normalised(result.stabilise, settings, [])
    idx = [take.names.index(n) for n in result.marker_names]
    return result.alignment.apply_vectors(np.take(take.deltas, idx, axis=1))
