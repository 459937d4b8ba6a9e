"""Frozen settings and data inputs of the non-geometric strategies, as the pipeline receives them.

The take config (``solvers.config``) and the Blender sidebar (``facecap_addon.scene.take``) both build
these; ``wiring.fit_strategy`` turns them into a fitted strategy. Settings are small values that
live in a config or a .blend (names, frame ranges, gains, options); inputs are data read from
files or the scene (a calibration take, posed example weights, a training take, solved weights).
"""

from dataclasses import dataclass, field

from ..options import default


@dataclass(frozen=True)
class CalibrationSettings:
    """``[calibration]``: the actor's calibration session (``calibrated`` and ``refine``).

    poses : ((name, ((first, last), ...)), ...) inclusive frame ranges of each held pose; a name
        may carry several ranges (the pose performed more than once)
    neutral_frames : (first, last) of the calibration take's relaxed neutral; None = the take's
        ``[neutral] frames``
    split : pose names split into ``<pose>Left`` / ``<pose>Right`` by marker side
    stable_markers : markers the calibration take is stabilised on; () = ``[stabilise] markers``
    align : "rigid" (default), "similarity" or "none": how the take's neutral is brought onto the
        calibration neutral (the master T-pose alignment)
    sequence : a range-of-motion session's poses in the order performed (``rom.sheets.Pose``s, a built-in sheet
        or the config's list); their holds are found in the calibration take (or the take itself) and the
        actor's shapes estimated from them (``semantic``)
    holds : ((label, middle frame), ...) where the user put the ROM's poses (Find Poses' timeline markers
        moved, or ``[calibration] holds``): used instead of the holds found
    """

    poses: tuple = ()
    neutral_frames: tuple = None
    split: tuple = ()
    stable_markers: tuple = ()
    align: str = default("calibration.align")
    sequence: tuple = ()
    holds: tuple = None

    def pose_table(self):
        """``{name: [[first, last], ...]}`` for ``actor_basis_from_poses``."""
        return {name: [list(r) for r in ranges] for name, ranges in self.poses}


@dataclass(frozen=True)
class ActorSettings:
    """``[actor]`` and the ``semantic`` solve's shape options.

    template : "auto" (the installed human template, if any), "none", or a path
    normalise : range-normalise the actor's motion per marker when nothing is known about the actor
    unseen_shapes : "rest" (shapes that move no marker are held at 0) or "solve"
    exclusive : opposing shapes are never both active
    """

    template: str = default("actor.template")
    normalise: bool = default("actor.normalise")
    unseen_shapes: str = default("solve.unseen_shapes")
    exclusive: bool = default("solve.exclusive")


@dataclass(frozen=True)
class MappingSettings:
    """``[mapping]``: source channels (actor poses, capture channels) -> character shapes.

    table : ((source, target, gain), ...); channels the table does not mention map by name/alias
    keyed_by : "source" or "target" (how the config's table was keyed; rows are the same either way)
    aliases : match names through the alias tables (ARKit, Live Link Face, MediaPipe, FACS units)
    gain, offset : float or ((shape, value), ...) per character shape (``parallel``)
    clamp : None (the shape's slider range), (lo, hi) or ((shape, (lo, hi)), ...) (``parallel``)
    curve : "linear", "smoothstep", "gamma:<g>" or ((shape, curve), ...) (``parallel``)
    mirror : swap Left/Right source channels (``parallel``)
    neutral_frames : (first, last) of the source weights whose median is subtracted (``parallel``)
    """

    table: tuple = ()
    keyed_by: str = default("mapping.keyed_by")
    aliases: bool = default("mapping.aliases")
    gain: object = default("mapping.gain")
    offset: object = default("mapping.offset")
    clamp: object = None
    curve: object = default("mapping.curve")
    mirror: bool = default("mapping.mirror")
    neutral_frames: tuple = None

    def table_dict(self):
        """``{source: {target: gain}}`` for ``Mapping.from_table`` (keyed by source), or None."""
        if not self.table:
            return None
        out = {}
        for source, target, gain in self.table:
            row = out.setdefault(source, {})
            row[target] = row.get(target, 0.0) + float(gain)
        return out


@dataclass(frozen=True)
class ExampleSettings:
    """``[examples]``: posed example frames (``linear``, ``rbf``, ``pca``) and their options.

    frames : frame numbers to use (subset of the example weights' frames); () = all of them
    ridge : ``linear`` ridge weight (relative), default 1e-3
    kernel, rbf_smoothing, degree, far : ``rbf`` options (see ``RBFStrategy``)
    n_components : ``rbf`` / ``pca`` component count; None = the strategy's default
    """

    frames: tuple = ()
    ridge: float = default("examples.ridge")
    kernel: str = default("examples.kernel")
    rbf_smoothing: float = default("examples.rbf_smoothing")
    degree: int = default("examples.degree")
    n_components: int = None
    far: float = default("examples.far")


@dataclass(frozen=True)
class PCASettings:
    """``[pca]``: mode "related" (default) or "posed", FastICA, basis frames, kept variance."""

    mode: str = default("pca.mode")
    ica: bool = default("pca.ica")
    n_basis: int = default("pca.n_basis")
    variance: float = default("pca.variance")


@dataclass(frozen=True)
class RefineSettings:
    """``[refine]``: Choe & Ko iteration limits and the pull towards the original library."""

    max_iterations: int = default("refine.max_iterations")
    tol: float = default("refine.tol")
    stiffness: float = default("refine.stiffness")


@dataclass(frozen=True, eq=False)
class ExamplePairs:
    """Character weights an animator posed for frames of a take.

    frames : (N,) frame numbers of the example take (``markers``, or the take being solved)
    weights : (N, S) posed values
    names : S character shape names of ``weights`` columns (matched to the character's shapes;
        shapes not named here are 0 in every example)
    markers : MarkerSet or None; the take the frames belong to (None = the take being solved)
    """

    frames: object
    weights: object
    names: tuple
    markers: object = None


@dataclass(frozen=True, eq=False)
class StrategyInputs:
    """Data a strategy learns from or solves, besides the take's markers and the character.

    calibration : MarkerSet of the actor's calibration session (``calibrated``, ``refine``)
    actor_basis : Basis, a stored actor library used instead of ``calibration`` + poses
    examples : ExamplePairs (``linear``, ``rbf``, ``pca``)
    training : MarkerSet of a training take (``refine``; default: the take being solved)
    weights : WeightTrack of already-solved weights (``parallel``; the source itself)
    profile : Basis, a stored performer profile (``semantic``, ``[actor] profile``)
    template : HumanTemplate (``semantic``, ``[actor] template``)
    notes : what reading the inputs reported (carried into the result's warnings)
    """

    calibration: object = None
    actor_basis: object = None
    examples: object = None
    training: object = None
    weights: object = None
    profile: object = None
    template: object = None
    notes: tuple = field(default_factory=tuple)
