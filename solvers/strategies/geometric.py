"""The ``geometric`` strategy: stabilised actor marker deltas against the character's shape keys.

The actor's deltas are carried into character space by the similarity that maps the actor's
neutral markers onto the character's bound points (per region with separate scales when asked;
a 2D similarity for image tracks), then solved against the shape-key deltas at those points with
bounded, regularised least squares (gaps masked out). Its solve predicts the markers themselves,
so the pipeline refits the head against it (``PredictsMarkers``).
"""

from dataclasses import dataclass, replace

import numpy as np

from ..capture.align import align_actor
from ..character.basis import Basis
from ..character.diagnostics import basis_warnings
from ..character.shape_options import resolve_bounds, resolve_locks, resolve_regions
from ..engine import solve_bounded
from ..errors import FacecapError
from ..options import default
from ..transforms import fit_similarity_2d
from .base import StrategyResult
from .sources import as_deltas

#: Solve options of a quick prediction (the head refits): active-set iterations per frame, no exact
#: fallback. Measured on the 36,000-frame sample take: the same final accuracy as exact per-frame
#: refits, at half their cost.
QUICK_SOLVE = dict(max_iter=2, exact=False)


@dataclass(frozen=True)
class GeometricOptions:
    """Priors of the geometric solve, all relative to the mean squared norm of a basis column
    (unit free: the same values work for millimetre and metre rigs).

    regularisation : ridge weight on every shape (keeps weights of shapes the markers barely see small)
    sparsity : L1 weight (most shapes are off most of the time; pulls noise-level activations to 0)
    symmetry : coupling of each ``<name>Left`` / ``<name>Right`` pair (off by default: it lets a
        side whose markers are missing follow the other side, but biases asymmetric expressions)
    smoothing : (first, second) temporal difference weights; (0, 0) solves frames independently.
        The default keeps a 3-frame lip closure at 60 fps and halves frame-to-frame jitter.
    """

    regularisation: float = default("solve.regularisation")
    sparsity: float = default("solve.sparsity")
    symmetry: float = default("solve.symmetry")
    smoothing: tuple = default("solve.smoothing")


def symmetric_pairs(shape_names):
    """Index pairs (left, right) of shapes named ``<base>Left`` / ``<base>Right`` (ARKit style)."""
    index = {n: i for i, n in enumerate(shape_names)}
    pairs = []
    for name, i in index.items():
        if name.endswith("Left") and name[:-4] + "Right" in index:
            pairs.append((i, index[name[:-4] + "Right"]))
    return pairs


def solve_geometric(basis, deltas, *, options=GeometricOptions(), confidence=None, lower=None, upper=None,
                    locks=None, regions=None, start=None, max_iter=None, exact=True):
    """Solve weights for character-space marker deltas.

    Parameters
    ----------
    basis : Basis with M markers, D dims
    deltas : ndarray, shape (F, M, D), NaN for gaps, already in the basis' space and units
    options : GeometricOptions
    confidence : ndarray (F, M), optional
        Trust per marker sample (0 = ignore).
    lower, upper : ndarray (K,), optional
        Weight bounds (default: the basis' slider range).
    locks : ndarray (K,) or (F, K), optional
        Values held fixed, NaN = free.
    regions : list of (shape indices, coordinate indices), optional
        See :func:`solvers.engine.solve_bounded`.
    start : ndarray (F, K), optional
        Weights of an earlier solve of similar deltas: the solve starts from them (faster, same result).
    max_iter, exact : see :func:`solvers.engine.solve_bounded` (``exact=False`` with a small
        ``max_iter``: a quick per-frame prediction instead of the optimum)

    Returns
    -------
    SolveResult; its residuals have shape (F, M * D)
    """
    F, M, D = deltas.shape
    pairs = symmetric_pairs(basis.shape_names) if options.symmetry > 0 else ()
    return solve_bounded(
        basis.matrix(), deltas.reshape(F, M * D), mask=confidence, dims=D,
        lower=basis.lower if lower is None else lower, upper=basis.upper if upper is None else upper,
        locks=locks, regions=regions, regularisation=options.regularisation, sparsity=options.sparsity,
        symmetry=pairs, symmetry_weight=options.symmetry, smoothing=tuple(options.smoothing), relative=True,
        start=start, max_iter=max_iter, exact=exact,
    )


class GeometricStrategy:
    """Actor deltas aligned onto the character, solved against its shape keys at the bound points.

    Parameters (keyword-only): the priors ``regularisation``, ``sparsity``, ``symmetry``,
    ``smoothing`` (see ``GeometricOptions``); ``align_regions`` ((region, (marker patterns...)),
    ...) aligns regions with separate scales; ``align_flag_mm`` the alignment residual that flags a
    binding (None: robust).
    """

    name = "geometric"
    source_kind = "markers"

    def __init__(self, *, regularisation=GeometricOptions.regularisation, sparsity=GeometricOptions.sparsity,
                 symmetry=GeometricOptions.symmetry, smoothing=GeometricOptions.smoothing, align_regions=(),
                 align_flag_mm=None):
        self.options = GeometricOptions(regularisation=regularisation, sparsity=sparsity, symmetry=symmetry,
                                        smoothing=tuple(smoothing))
        self.align_regions, self.align_flag_mm = tuple(align_regions), align_flag_mm
        self.basis = None
        self.notes = ()

    def fit(self, character, *, names=None, bounds=(), locks=(), regions=()):
        """Bind the take's markers to the character.

        character : Basis, the character's shapes at the bound points (3D, or projected to 2D)
        names : the take's marker names (default: every bound point); markers without a binding
            are left out with a note, and at least 3 must be bound
        bounds, locks, regions : ``[solve]`` shape options (patterns, ``RetargetSettings``)
        """
        if not isinstance(character, Basis):
            raise FacecapError("strategy 'geometric' needs the character's shapes at the bound points (a Basis)")
        names = tuple(character.marker_names if names is None else names)
        used, notes = bound_markers(character, names)
        self.basis = character.subset_markers(used)
        self.lower, self.upper = resolve_bounds(character.shape_names, character.lower, character.upper, bounds)
        self.lock_patterns = tuple(locks)
        self.regions, held = resolve_regions(character.shape_names, used, regions, dims=character.neutral.shape[1])
        if held:
            notes.append(f"{len(held)} shape(s) are in no region and are held: {list(held)}")
        notes.extend(dict.fromkeys(basis_warnings(self.basis.matrix(), self.basis.shape_names)))
        self.notes = tuple(notes)
        return self

    @property
    def marker_names(self):
        return self.basis.marker_names

    def solve(self, source, *, names=None, neutral=None, confidence=None, start=None, quick=False,
              overwrite=False):
        """Character weights for actor-space deltas ``source`` (F, M, D) named ``names``.

        ``neutral`` (M, D), the take's neutral, aligns the take onto the bound points (a similarity);
        without it the deltas must already be in character space. ``start`` (F, K): weights of an
        earlier solve to start from; ``quick``: a cheap per-frame prediction (no temporal smoothing,
        a few active-set iterations), as the head refits use. ``overwrite``: the caller gives
        ``source`` up (its contents are undefined afterwards), so the aligned deltas are made in its
        memory instead of in a second (F, M, D) array (issue 18).
        """
        if self.basis is None:
            raise FacecapError("geometric: call fit() before solve()")
        deltas = as_deltas(source, overwrite=overwrite)
        names = tuple(self.basis.marker_names if names is None else names)
        idx = [names.index(n) for n in self.basis.marker_names]
        alignment, residual = None, None
        if neutral is not None:
            alignment, residual = self._align(np.asarray(neutral, dtype=np.float64)[idx])
        deltas = taken_markers(deltas, idx, alignment, overwrite=overwrite)
        if confidence is not None:
            confidence = np.take(np.nan_to_num(np.asarray(confidence, dtype=np.float64)), idx, axis=1)
        options = replace(self.options, smoothing=(0.0, 0.0)) if quick else self.options
        locks = resolve_locks(self.basis.shape_names, self.lock_patterns, n_frames=deltas.shape[0])
        res = solve_geometric(self.basis, deltas, options=options, confidence=confidence, lower=self.lower,
                              upper=self.upper, locks=None if np.isnan(locks).all() else locks,
                              regions=self.regions, start=start, **(QUICK_SOLVE if quick else {}))
        rms = residual_rms(res.weights, self.basis.deltas, deltas)
        rms[~res.solved] = np.nan
        warnings = [*self.notes, *res.warnings]
        flagged = getattr(alignment, "flagged", ())
        if flagged:
            used = self.basis.marker_names
            warnings.append(f"binding(s) {', '.join(flagged)} are far from their marker after the actor->character "
                            f"alignment ({', '.join(f'{residual[used.index(n)] * 1e3:.1f} mm' for n in flagged)}); "
                            "check the binding (vertex groups, [binding] map or landmarks)")
        return StrategyResult(
            weights=res.weights, shape_names=self.basis.shape_names, solved=res.solved, warnings=tuple(warnings),
            residual_rms=rms, clamped=np.zeros(len(deltas), dtype=int),
            info={"mode": res.mode} if alignment is None else {"mode": res.mode, "alignment_scale": alignment.scale},
            solve=res, marker_names=self.basis.marker_names, alignment=alignment, alignment_residual=residual,
        )

    def predict(self, result):
        """Actor-space deltas (F, U, D) of ``result.marker_names`` that ``result``'s weights explain."""
        K, U, D = self.basis.deltas.shape
        char = (np.nan_to_num(result.weights) @ self.basis.deltas.reshape(K, U * D)).reshape(-1, U, D)
        return char if result.alignment is None else result.alignment.inverse_vectors(char)

    def _align(self, neutral):
        """The similarity from the take's neutral (U, D) onto the bound points, and each marker's
        distance from its point after it."""
        bound = self.basis.neutral
        if neutral.shape[1] == 2:
            sim = fit_similarity_2d(neutral, bound)
            return sim, np.linalg.norm(sim.apply(neutral) - bound, axis=1)
        align = align_actor(neutral, bound, self.basis.marker_names, regions=self.align_regions,
                            flag_mm=self.align_flag_mm)
        return align, align.residual


def bound_markers(character, names, *, source="take"):
    """The markers of ``names`` bound on ``character`` (a Basis), in its order, and notes on the
    unbound ones; at least 3 must be bound (``source`` names the take in the error)."""
    taken, bound = set(names), set(character.marker_names)
    used = tuple(n for n in character.marker_names if n in taken)
    notes = []
    unbound = [n for n in names if n not in bound]
    absent = [n for n in character.marker_names if n not in taken]
    if unbound:
        notes.append(f"{len(unbound)} marker(s) have no binding on the character and are not solved from: "
                     f"{', '.join(unbound)}")
    if absent:
        notes.append(f"{len(absent)} bound point(s) have no marker in the take: {absent}")
    if len(used) < 3:
        raise FacecapError(
            f"{source}: only {len(used)} of its {len(names)} marker(s) are bound on the character (need 3; "
            f"markers bind to vertex groups of the same name); take markers: {list(names)[:10]}..., "
            f"bound points: {list(character.marker_names)[:10]}...")
    return used, notes


#: Frames per block of the per-frame array work below: temporaries of a few MB that the allocator
#: reuses, not (F, M, D) ones (587 MB each on 100 minutes at 60 fps of 68 markers; issue 18).
BLOCK = 8192


def taken_markers(deltas, idx, alignment, *, overwrite=False):
    """``deltas[:, idx]`` (F, U, D), carried by ``alignment`` when given, in blocks of frames; np.take
    keeps the frame-major layout (deltas[:, idx] would be marker-major, 2x slower later).

    With ``overwrite`` the result is written over ``deltas`` (U <= M). That is safe block by block:
    each block is copied out before it is written, and it is written no further into the array than
    where its own rows started, so no later block has been overwritten yet."""
    F, M, D = deltas.shape
    U = len(idx)
    if alignment is None and list(idx) == list(range(M)):
        return deltas if overwrite else deltas.copy()
    if overwrite and deltas.flags.c_contiguous:
        out = deltas.reshape(-1)[: F * U * D].reshape(F, U, D)
    else:
        out = np.empty((F, U, D))
    for a in range(0, F, BLOCK):
        part = np.take(deltas[a : a + BLOCK], idx, axis=1)
        out[a : a + BLOCK] = part if alignment is None else alignment.apply_vectors(part)
    return out


def residual_rms(weights, basis_deltas, deltas):
    """RMS residual per frame (F,) over the observed markers of ``deltas`` (F, M, D), in blocks of frames."""
    K, M, D = basis_deltas.shape
    out = np.empty(deltas.shape[0])
    for a in range(0, deltas.shape[0], BLOCK):
        s = slice(a, a + BLOCK)
        res = (np.nan_to_num(weights[s]) @ basis_deltas.reshape(K, M * D)).reshape(-1, M, D) - deltas[s]
        measured = ~np.isnan(deltas[s, :, 0])
        sq = np.where(measured, (res**2).sum(axis=2), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[s] = np.sqrt(sq.sum(axis=1) / measured.sum(axis=1))
    return out
