"""The ``calibrated`` strategy (Sony Monster House FACS library, Weta King Kong expression space).

The actor performs calibration poses (named frame ranges of a calibration take, each pose held
from a relaxed neutral). The actor basis is, per pose, the median marker position over its frames
minus the median over the neutral frames, in the stabilised calibration head frame. A take is
solved for the actor's pose activations against that basis (``solve_bounded``), and the
activations are carried to the character's shapes by a mapping table: one-to-one by name/alias
by default, many-to-many with gains otherwise. Nothing of the character's geometry enters the
solve, so this is the strategy for characters whose proportions differ from the actor's.
"""

import warnings

import numpy as np

from ..capture.neutral import neutral_from_frames
from ..capture.noise import POSE_SHRINK, marker_noise, shrink_pose_noise
from ..capture.stabilise import stabilise_2d, stabilise_rigid
from ..character.aliases import name_key
from ..character.basis import Basis
from ..engine import solve_bounded
from ..errors import FacecapError
from ..markers import UNIT_SCALE
from ..options import default
from .base import StrategyResult, as_target
from .geometric import symmetric_pairs
from .linear import align_source
from .mapping import Mapping
from .sources import as_deltas, clamp_to, flat, reorder


def _ranges(name, spec):
    """[first, last] or [[first, last], ...] -> list of (first, last)."""
    spec = list(spec) if isinstance(spec, (list, tuple)) else None
    if spec and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spec) and len(spec) == 2:
        spec = [spec]
    if not spec or not all(isinstance(r, (list, tuple)) and len(r) == 2 for r in spec):
        raise FacecapError(f"calibration: pose '{name}' needs [first, last] or a list of them; got {spec!r}")
    out = []
    for first, last in spec:
        if last < first:
            raise FacecapError(f"calibration: pose '{name}' frame range {first}-{last} is empty (last < first)")
        out.append((first, last))
    return out


def _side(marker):
    """+1 for the subject's left (``_L``, ``Left``), -1 for the right, 0 for the midline/unknown."""
    low = marker.lower()
    if low.endswith(("_l", ".l", "left")):
        return 1
    if low.endswith(("_r", ".r", "right")):
        return -1
    return 0


def actor_basis_from_poses(calibration, *, poses, neutral, stable_markers=None, split=(), min_frames=3,
                           shrink=POSE_SHRINK):
    """Build the actor basis from a calibration take.

    Parameters
    ----------
    calibration : MarkerSet (3D, any of m/cm/mm), or 2D image tracks (px) of a filmed calibration:
        then stabilised by a per-frame 2D similarity on ``stable_markers`` and the basis is in pixels
    poses : dict {pose name: [first, last] or [[first, last], ...]}, inclusive frame numbers
    neutral : (first, last), the relaxed neutral the poses are measured from
    stable_markers : sequence of str, optional
        If given, the take is first stabilised on them (rigid, reference = the neutral frames);
        otherwise it must already be stabilised.
    split : sequence of pose names
        Poses performed on both sides at once, split into ``<pose>Left`` / ``<pose>Right`` by
        marker side (``_L`` / ``_R`` suffix; midline markers get half the delta on each side).
    min_frames : int
        Fewer samples of a marker in a pose's frames than this is a warning; no sample at all
        leaves that marker's delta at 0.
    shrink : float
        A marker's delta within this many times its standard error (the take's noise over the pose's and
        the neutral's samples) is shrunk towards 0 (``capture.noise.shrink_pose_noise``); 0 keeps it.

    Returns
    -------
    basis : Basis (metres, or pixels for 2D tracks), shapes in ``poses`` order (split poses in place), bounds [0, 1]
    notes : tuple of str
    """
    if not poses:
        raise FacecapError("calibration: `poses` is empty; name at least one pose and its frame range")
    first, last = neutral
    if calibration.dim == 2:  # image tracks: pixels, head motion removed as a 2D similarity
        markers = calibration
        if stable_markers:
            markers = stabilise_2d(markers, tuple(stable_markers), reference_frames=(first, last)).markers
    else:
        if calibration.units not in UNIT_SCALE:
            raise FacecapError(f"calibration: markers must be in m, cm or mm; got '{calibration.units}'")
        markers = calibration.to_units("m")
        if stable_markers:
            markers = stabilise_rigid(markers, tuple(stable_markers), reference_frames=(first, last)).markers
    rest = neutral_from_frames(markers, first, last)
    neutral_counts = np.isfinite(markers.positions[markers.frame_range_mask(first, last)][:, :, 0]).sum(axis=0)
    noise = marker_noise(markers.positions - rest[None])
    names, deltas, counts, notes, thin_poses = [], [], [], [], {}
    unknown_split = set(split) - set(poses)
    if unknown_split:
        raise FacecapError(f"calibration: `split` names poses that are not in `poses`: {sorted(unknown_split)}")
    for pose, spec in poses.items():
        sel = np.zeros(markers.n_frames, dtype=bool)
        for a, b in _ranges(pose, spec):
            sel |= markers.frame_range_mask(a, b)
        if not sel.any():
            raise FacecapError(
                f"calibration: pose '{pose}' frames {spec} are outside the take "
                f"({markers.frames[0]:g}-{markers.frames[-1]:g})"
            )
        block = markers.positions[sel]
        count = (~np.isnan(block[:, :, 0])).sum(axis=0)
        thin = [markers.names[i] for i in np.flatnonzero(count < min_frames)]
        if thin:
            thin_poses[pose] = thin
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: handled below
            delta = np.nanmedian(block, axis=0) - rest
        delta[~np.isfinite(delta).all(axis=1)] = 0.0
        if pose in split:
            side = np.array([_side(n) for n in markers.names], dtype=np.float64)
            left = np.where(side > 0, 1.0, np.where(side == 0, 0.5, 0.0))
            names += [pose + "Left", pose + "Right"]
            deltas += [delta * left[:, None], delta * (1.0 - left)[:, None]]
            counts += [count, count]
        else:
            names.append(pose)
            deltas.append(delta)
            counts.append(count)
    if thin_poses:
        notes.append(f"calibration: {len(thin_poses)} pose(s) have markers with fewer than {min_frames} samples "
                     f"(median of what there is; none = delta 0): {thin_poses}")
    if len(set(names)) != len(names):
        raise FacecapError(f"calibration: duplicate pose names {sorted({n for n in names if names.count(n) > 1})}")
    deltas = shrink_pose_noise(np.stack(deltas), np.stack(counts), neutral_counts, noise, factor=shrink)
    return Basis(tuple(names), markers.names, rest, deltas), tuple(notes)


class CalibratedStrategy:
    """Solve actor pose activations against a calibrated actor basis, then map them to the character.

    Parameters (keyword-only)
    ----------
    mapping : None, Mapping or dict
        None: one-to-one by name and alias. A dict is a table for ``Mapping.from_table`` (with
        ``keyed_by``; channels the table does not mention map by name).
    keyed_by : "source" or "target", how a dict ``mapping`` is keyed
    aliases : bool, match names through the alias tables (ARKit, Live Link Face, FACS units)
    regularisation, sparsity, symmetry, smoothing : priors of the actor solve, relative to the
        actor basis scale (as in ``GeometricOptions``)
    align : "rigid" (default), "similarity" or "none": how a take's neutral (``solve(neutral=)``)
        is brought onto the calibration neutral before solving (the master T-pose alignment)
    pose_bounds : (lower, upper) bounds on the actor activations (default (0, 1))
    """

    name = "calibrated"
    source_kind = "markers"

    def __init__(self, *, mapping=None, keyed_by="source", aliases=True, regularisation=default("solve.regularisation"),
                 sparsity=default("solve.sparsity"), symmetry=default("solve.symmetry"),
                 smoothing=default("solve.smoothing"), align=default("calibration.align"), pose_bounds=(0.0, 1.0)):
        if align not in ("rigid", "similarity", "none"):
            raise FacecapError(f"calibrated: `align` must be 'rigid', 'similarity' or 'none'; got {align!r}")
        for key, value in (("regularisation", regularisation), ("sparsity", sparsity), ("symmetry", symmetry)):
            if not value >= 0:
                raise FacecapError(f"calibrated: `{key}` must be >= 0; got {value}")
        if len(smoothing) != 2 or min(smoothing) < 0:
            raise FacecapError(f"calibrated: `smoothing` must be (first, second) >= 0; got {smoothing}")
        lo, hi = pose_bounds
        if not lo <= hi:
            raise FacecapError(f"calibrated: `pose_bounds` must be (lower, upper) with lower <= upper; got {pose_bounds}")
        self.mapping_spec = mapping
        self.keyed_by = keyed_by
        self.aliases = aliases
        self.regularisation = float(regularisation)
        self.sparsity = float(sparsity)
        self.symmetry = float(symmetry)
        self.smoothing = (float(smoothing[0]), float(smoothing[1]))
        self.align = align
        self.pose_bounds = (float(lo), float(hi))
        self.actor_basis = None
        self.mapping = None
        self.target = None
        self.notes = ()

    # -- fitting -----------------------------------------------------------------------------
    def fit(self, character, *, calibration=None, poses=None, neutral=None, stable_markers=None, split=(),
            actor_basis=None):
        """Learn the actor basis and the mapping.

        Either ``calibration`` (MarkerSet) + ``poses`` + ``neutral`` (see ``actor_basis_from_poses``)
        or an ``actor_basis`` (Basis, e.g. a stored library or a refined version).
        ``character`` : Basis or shape names (the output shapes and their bounds).
        """
        self.target = as_target(character)
        notes = []
        if actor_basis is not None:
            if calibration is not None:
                raise FacecapError("calibrated: give either `calibration` (+ poses, neutral) or `actor_basis`, not both")
            if not isinstance(actor_basis, Basis):
                raise FacecapError(f"calibrated: `actor_basis` must be a Basis; got {type(actor_basis).__name__}")
            basis = actor_basis
        else:
            if calibration is None or poses is None or neutral is None:
                raise FacecapError("calibrated: fit needs `calibration`, `poses` and `neutral` (or an `actor_basis`)")
            basis, pose_notes = actor_basis_from_poses(
                calibration, poses=poses, neutral=neutral, stable_markers=stable_markers, split=split
            )
            notes += pose_notes
        lo, hi = self.pose_bounds
        self.actor_basis = Basis(basis.shape_names, basis.marker_names, basis.neutral, basis.deltas,
                                 np.full(basis.n_shapes, lo), np.full(basis.n_shapes, hi))
        self.mapping = self._mapping(basis.shape_names)
        notes += self.mapping.notes
        self.notes = tuple(notes)
        return self

    def _mapping(self, pose_names):
        spec = self.mapping_spec
        if spec is None:
            return Mapping.by_name(pose_names, self.target.names, aliases=self.aliases)
        if isinstance(spec, Mapping):
            if [name_key(n) for n in spec.source_names] != [name_key(n) for n in pose_names] or \
                    spec.target_names != self.target.names:
                raise FacecapError("calibrated: the given Mapping's names do not match the actor poses / character shapes")
            return spec
        if isinstance(spec, dict):
            return Mapping.from_table(spec, pose_names, self.target.names, keyed_by=self.keyed_by, aliases=self.aliases)
        raise FacecapError(f"calibrated: `mapping` must be None, a Mapping or a dict; got {type(spec).__name__}")

    # -- solving -----------------------------------------------------------------------------
    def solve(self, source, *, names=None, neutral=None, confidence=None):
        """Character weights for stabilised, neutral-normalised actor marker deltas.

        Parameters
        ----------
        source : ndarray (F, M, 3), metres, NaN for gaps; or (F, M, 2) pixels against a basis
            calibrated from 2D tracks
        names : marker names of ``source`` (matched to the calibration's markers); default: same order
        neutral : ndarray (M, 3), optional; the take's neutral positions (same order as ``source``),
            aligned onto the calibration neutral per ``align``
        confidence : ndarray (F, M), optional trust per sample (0 = ignore), in ``source`` order
        """
        if self.actor_basis is None:
            raise FacecapError("calibrated: call fit() before solve()")
        basis = self.actor_basis
        deltas = reorder(as_deltas(source), names, basis.marker_names)
        if neutral is not None:
            neutral = reorder(np.asarray(neutral, dtype=np.float64)[None], names, basis.marker_names)[0]
        if confidence is not None:
            confidence = reorder(np.asarray(confidence, dtype=np.float64)[:, :, None], names, basis.marker_names)[:, :, 0]
            confidence = np.nan_to_num(confidence)
        if deltas.shape[2] != basis.neutral.shape[1]:
            raise FacecapError(f"calibrated: the take has {deltas.shape[2]}D markers, the actor basis "
                               f"{basis.neutral.shape[1]}D (calibrate from the same kind of capture)")
        deltas, sim = align_source(deltas, neutral, basis.neutral, mode=self.align)
        return self._solve_aligned(deltas, confidence, info={"alignment_scale": None if sim is None else sim.scale})

    def _solve_aligned(self, deltas, confidence, info):
        basis = self.actor_basis
        F, M, D = deltas.shape
        pairs = symmetric_pairs(basis.shape_names) if self.symmetry > 0 else ()
        res = solve_bounded(
            basis.matrix(), flat(deltas), mask=confidence, dims=D, lower=basis.lower, upper=basis.upper,
            regularisation=self.regularisation, sparsity=self.sparsity, symmetry=pairs,
            symmetry_weight=self.symmetry, smoothing=self.smoothing, relative=True,
        )
        act = res.weights
        weights, clamped = clamp_to(self.target, self.mapping.apply(np.nan_to_num(act)))
        weights[~res.solved] = np.nan
        seen = ~np.isnan(deltas[:, :, 0])
        if confidence is not None:
            seen &= confidence > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt((res.residuals**2).sum(axis=1) / seen.sum(axis=1))
        rms[~res.solved] = np.nan
        return StrategyResult(
            weights=weights, shape_names=self.target.names, solved=res.solved,
            warnings=tuple(self.notes) + tuple(res.warnings), source_weights=act,
            source_names=basis.shape_names, residual_rms=rms, clamped=clamped,
            info={**info, "mode": res.mode, "converged": res.converged}, solve=res,
        )
