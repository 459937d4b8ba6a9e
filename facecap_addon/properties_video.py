"""Sidebar settings of video takes, as ``Scene.facecap.video``: how a 2D take sees the character,
and the options of Track Clip Footage."""

import bpy
from bpy.props import EnumProperty, IntProperty, IntVectorProperty, PointerProperty

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


def _is_camera(_self, obj):
    return obj.type == "CAMERA"


class FACECAP_PG_video(bpy.types.PropertyGroup):
    """Video takes: projection of the character for 2D solves, Track Clip Footage options."""

    projection: EnumProperty(name="Projection", items=PROJECTION_ITEMS, default="front",
                             description="How the character's bound points are projected to compare with 2D tracks")
    camera: PointerProperty(name="Camera", type=bpy.types.Object, poll=_is_camera,
                            description="Camera that filmed the take (empty: the scene camera)")
    region: IntVectorProperty(name="Region", size=4, default=(0, 0, 0, 0), min=0,
                              description="x, y, width, height in pixels for automatic features when the clip "
                                          "has no track markers at the current frame")
    max_points: IntProperty(name="Max Points", default=100, min=1, description="Automatic features to track")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="lk", description="How the points are followed")


CLASSES = (FACECAP_PG_video,)
