"""facecap core: numpy/scipy only, never Blender modules (tests assert this)."""

from .capture.neutral import neutral_from_frames
from .capture.stabilise import StabiliseResult, stabilise_rigid
from .character.basis import Basis
from .config import TakeConfig, load_take_config
from .engine import SolveResult, solve_bounded
from .errors import ConfigError, FacecapError, InputFileError
from .io.csv import (
    read_markers_csv,
    read_weights_csv,
    write_markers_csv,
    write_weights_csv,
)
from .markers import MarkerSet
from .pipeline import RetargetResult, RetargetSettings, retarget
from .transforms import Similarity, fit_rigid_batch, fit_similarity

__all__ = [
    "Basis", "ConfigError", "FacecapError", "InputFileError", "MarkerSet", "RetargetResult",
    "RetargetSettings", "Similarity", "SolveResult", "StabiliseResult", "TakeConfig",
    "fit_rigid_batch", "fit_similarity", "load_take_config", "neutral_from_frames",
    "read_markers_csv", "read_weights_csv", "retarget", "solve_bounded", "stabilise_rigid",
    "write_markers_csv", "write_weights_csv",
]
