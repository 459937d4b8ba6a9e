"""Choose the neutral / T-pose frame range."""

import bpy
from bpy.props import IntProperty

from ..solvers.errors import FacecapError


class FACECAP_OT_set_neutral(bpy.types.Operator):
    """Set the neutral (T-pose) frame range; defaults to the preview range, or 30 frames from the current frame"""

    bl_idname = "facecap.set_neutral"
    bl_label = "Set Neutral"
    bl_options = {"REGISTER", "UNDO"}

    first: IntProperty(name="First", default=-1, description="First frame (-1: from the timeline)")
    last: IntProperty(name="Last", default=-1, description="Last frame (-1: from the timeline)")

    @classmethod
    def poll(cls, context):
        return context.scene.facecap.marker_collection is not None

    def execute(self, context):
        from ..facecap_addon import take
        from ..solvers.neutral import neutral_from_frames

        scene = context.scene
        first, last = self.first, self.last
        if first < 0 or last < 0:
            if scene.use_preview_range:
                first, last = scene.frame_preview_start, scene.frame_preview_end
            else:
                first, last = scene.frame_current, scene.frame_current + 29
        settings = scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            neutral_from_frames(markers, first, last)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        settings.neutral_first, settings.neutral_last = first, last
        self.report({"INFO"}, f"Neutral: frames {first}-{last}")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_set_neutral,)
