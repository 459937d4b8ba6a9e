"""``RetargetSettings``: everything a retarget needs besides the data (defaults: ``solvers.options``)."""

from dataclasses import dataclass

from ..options import STRATEGIES, default
from ..strategies.options import (
    ActorSettings,
    CalibrationSettings,
    ExampleSettings,
    MappingSettings,
    PCASettings,
    RefineSettings,
)

__all__ = ["RetargetSettings", "STRATEGIES"]


@dataclass(frozen=True)
class RetargetSettings:
    """Everything a retarget needs besides the data; built from the take config or the sidebar."""

    stable_markers: tuple
    neutral_frames: tuple  # (first, last), inclusive
    strategy: str = default("solve.strategy")
    regularisation: float = default("solve.regularisation")
    sparsity: float = default("solve.sparsity")
    symmetry: float = default("solve.symmetry")
    smoothing: tuple = default("solve.smoothing")
    fine_iterations: int = default("stabilise.fine_iterations")  # hierarchical stabilisation: refits of the head on all markers
    fine_weight: float = default("stabilise.fine_weight")  # trust of deforming markers in the refit, relative to stable ones
    head_smoothing: float = default("stabilise.head_smoothing")  # half-window (s) of the zero-phase head-pose smoothing; 0 = off
    bounds: tuple = ()  # ((shape pattern, lower, upper), ...) overriding the slider ranges
    locks: tuple = ()  # ((shape pattern, value or (F,) values per frame), ...) shapes held fixed (animator-owned)
    regions: tuple = ()  # (Region, ...) shapes solved from their own marker subsets (geometric only)
    actor: ActorSettings = ActorSettings()  # semantic: what is known of the actor, unseen and opposing shapes
    calibration: CalibrationSettings = CalibrationSettings()  # calibrated, refine, semantic
    mapping: MappingSettings = MappingSettings()  # calibrated, refine, parallel
    examples: ExampleSettings = ExampleSettings()  # linear, rbf, pca
    pca: PCASettings = PCASettings()
    refine: RefineSettings = RefineSettings()
    stabilise_mode: str = default("stabilise.mode")  # "rigid" | "similarity" (captures from different days)
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
