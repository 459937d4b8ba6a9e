"""Video input: reading footage, sparse LK tracking, dense optical flow, flow PCA, 2D stabilisation.

Needs OpenCV (``cv2``, contrib for TV-L1); never imports Blender modules. Importing this package
is cheap; cv2 is imported by the modules that use it.
"""

from .flow import (DenseFlowResult, FlowEstimator, ReferenceFlow, compose, dense_flow, endpoint_error, reverse,
                   sample_flow, track_with_flow, warp)
from .pca import FlowPCA, flow_pca
from .reading import Cancelled, Footage, FootageInfo, open_footage, write_video
from .stabilise2d import Stabilise2DResult, stabilise_2d
from .tracking import LKTracker, TrackResult, auto_seeds, read_seed_points, track_points

__all__ = [
    "Cancelled", "DenseFlowResult", "FlowEstimator", "FlowPCA", "Footage", "FootageInfo", "LKTracker",
    "ReferenceFlow", "Stabilise2DResult", "TrackResult", "auto_seeds", "compose", "dense_flow", "endpoint_error",
    "flow_pca", "open_footage", "read_seed_points", "reverse", "sample_flow", "stabilise_2d", "track_points",
    "track_with_flow", "warp", "write_video",
]
