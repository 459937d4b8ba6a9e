"""Sidebar settings of video takes, as ``Scene.facecap.video``: how a 2D take sees the character,
the options of Track Clip Footage, and of Solve from Clip Flow (flow-PCA features, no markers)."""

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, IntVectorProperty, PointerProperty

from .option_props import from_option

PROJECTION_ITEMS = [
    ("front", "Front View", "Solve 2D tracks against the character seen from the front (orthographic)"),
    ("camera", "Camera", "Solve 2D tracks against the character seen through the camera that filmed the take"),
]


METHOD_ITEMS = [
    ("lk", "Lucas-Kanade", "Sparse pyramidal LK with re-registration to the reference frame"),
    ("dis", "DIS Flow", "Dense DIS optical flow relative to the reference frame, sampled at the points"),
    ("farneback", "Farneback Flow", "Dense Farneback optical flow, sampled at the points"),
    ("tvl1", "TV-L1 Flow", "Dense TV-L1 optical flow (slow, accurate), sampled at the points"),
]


FLOW_METHOD_ITEMS = [item for item in METHOD_ITEMS if item[0] != "lk"]

FLOW_STRATEGY_ITEMS = [
    ("linear", "Linear", "Ridge regression from the flow features to the posed weights"),
    ("rbf", "RBF", "Radial-basis interpolation between the posed frames"),
    ("pca", "PCA", "Related-mode PCA regression on the flow features"),
]


def _is_camera(_self, obj):
    return obj.type == "CAMERA"


class FACECAP_PG_video(bpy.types.PropertyGroup):
    """Video takes: projection of the character for 2D solves, Track Clip Footage options."""

    projection: EnumProperty(items=PROJECTION_ITEMS, **from_option("solve.projection", label="Projection"))
    camera: PointerProperty(name="Camera", type=bpy.types.Object, poll=_is_camera,
                            description="Camera that filmed the take (empty: the scene camera)")
    region: IntVectorProperty(name="Region", size=4, default=(0, 0, 0, 0), min=0,
                              description="The face: x, y, width, height in pixels (origin top-left). Track Clip "
                                          "Footage seeds automatic features there when the clip has no track "
                                          "markers at the current frame; Solve from Clip Flow follows the flow "
                                          "there (all zero: the whole frame)")
    max_points: IntProperty(name="Max Points", default=100, min=1, description="Automatic features to track")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="lk", description="How the points are followed")
    flow_method: EnumProperty(items=FLOW_METHOD_ITEMS, **from_option("tracking.method", label="Flow"))
    landmark_smoothing: BoolProperty(**from_option("tracking.smoothing", label="Smoothing"))
    stable_region: IntVectorProperty(name="Stable Region", size=4, default=(0, 0, 0, 0), min=0,
                                     description="x, y, width, height in pixels of an area that moves with the head "
                                                 "only (forehead, temples, a head-cam rig): its motion is removed "
                                                 "from the features (all zero: head motion stays in)")
    flow_components: IntProperty(**from_option("flow.components", label="Components"))
    flow_grid_step: IntProperty(name="Grid Step", default=0, min=0, max=64,
                                description="Flow sample spacing in pixels (0: about 4,000 samples over the region)")
    flow_strategy: EnumProperty(name="Strategy", items=FLOW_STRATEGY_ITEMS, default="linear",
                                description="How the flow features map to the weights posed in the Examples action "
                                            "(options from the Solve panel)")


CLASSES = (FACECAP_PG_video,)
