"""A pose library: one control pose per semantic shape (ARKit / FACS names), as a Basis column.

Each pose is evaluated once on the rig at the bound points (``facecap_addon.rig.rig_eval``); the poses'
displacements are the columns of the existing solve, so every strategy (geometric, calibrated,
parallel...) solves for the poses by name, and the weights become control values as
``rest + sum_k w_k (pose_k - rest)``, clipped to the controls' limits.
"""

from dataclasses import dataclass

import numpy as np

from ..character.basis import Basis
from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class PoseLibrary:
    """K poses over C controls.

    pose_names : tuple of str (K,), the semantic shapes
    control_names : tuple of str (C,)
    poses : ndarray (K, C), each pose's control values
    rest, lower, upper : ndarray (C,)
    """

    pose_names: tuple
    control_names: tuple
    poses: np.ndarray
    rest: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        K, C = len(self.pose_names), len(self.control_names)
        poses = np.asarray(self.poses, dtype=np.float64)
        if poses.shape != (K, C):
            raise FacecapError(f"pose library: poses must have shape ({K}, {C}); got {poses.shape}")
        if K == 0:
            raise FacecapError("pose library: no poses")
        if len(set(self.pose_names)) != K:
            raise FacecapError("pose library: pose names must be unique")
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "pose_names", tuple(self.pose_names))
        object.__setattr__(self, "control_names", tuple(self.control_names))
        for name in ("rest", "lower", "upper"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (C,):
                raise FacecapError(f"pose library: {name} must have shape ({C},); got {arr.shape}")
            object.__setattr__(self, name, arr)
        idle = [n for n, row in zip(self.pose_names, poses) if np.allclose(row, self.rest)]
        if idle:
            raise FacecapError(f"pose library: pose(s) {idle[:5]} leave every control at rest")

    def basis(self, marker_names, neutral, deltas):
        """The Basis of the poses from their displacements ``deltas`` (K, M, D) at the bound points."""
        return Basis(self.pose_names, marker_names, neutral, deltas)

    def controls(self, weights):
        """Pose weights (F, K) -> control values (F, C), within the controls' limits (NaN rows stay NaN)."""
        w = np.asarray(weights, dtype=np.float64)
        out = self.rest + w @ (self.poses - self.rest)
        return np.clip(out, self.lower, self.upper)
