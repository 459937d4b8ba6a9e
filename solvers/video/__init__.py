"""Video input: reading footage, sparse LK tracking, dense optical flow, flow PCA and its features.

2D stabilisation of image tracks is ``solvers.stabilise.stabilise_2d`` (re-exported).

Needs OpenCV (``cv2``, contrib for TV-L1); never imports Blender modules. Importing this package
is cheap; cv2 is imported by the modules that use it.
"""

from ..capture.stabilise import (
                   stabilise_2d,  # the one 2D stabilisation (image tracks), re-exported here
)
from .features import FlowFeatures, flow_features, remove_similarity, solve_from_flow
from .flow import (
                   DenseFlowResult,
                   FlowEstimator,
                   ReferenceFlow,
                   compose,
                   dense_flow,
                   dense_flow_job,
                   endpoint_error,
                   reverse,
                   sample_flow,
                   track_with_flow,
                   track_with_flow_job,
                   warp,
)
from .flow_solve import FlowSolveSettings, retarget_flow, retarget_flow_job
from .pca import FlowPCA, flow_pca
from .reading import Cancelled, Footage, FootageInfo, Job, open_footage, write_video
from .tracking import (
                   LKTracker,
                   TrackResult,
                   auto_seeds,
                   read_seed_points,
                   track_points,
                   track_points_job,
)

__all__ = [
    "Cancelled", "DenseFlowResult", "FlowEstimator", "FlowFeatures", "FlowPCA", "FlowSolveSettings", "Footage",
    "FootageInfo", "Job", "LKTracker", "ReferenceFlow", "TrackResult", "auto_seeds", "compose", "dense_flow",
    "dense_flow_job", "endpoint_error", "flow_features", "flow_pca", "open_footage", "read_seed_points",
    "remove_similarity", "retarget_flow", "retarget_flow_job", "reverse", "sample_flow", "solve_from_flow",
    "stabilise_2d", "track_points", "track_points_job", "track_with_flow", "track_with_flow_job", "warp", "write_video",
]
