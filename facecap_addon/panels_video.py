"""The "Video" panel of the FaceCap sidebar: track the active clip, and how 2D takes see the character."""

import bpy

from .panels import FacecapPanel


class FACECAP_PT_video(FacecapPanel, bpy.types.Panel):
    """Track movie-clip footage (Esc cancels) and choose the projection 2D takes are solved through."""

    bl_label = "Video"
    bl_idname = "FACECAP_PT_video"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        scene = context.scene
        v = scene.facecap.video
        layout = self.layout
        col = layout.column(align=True)
        col.prop(v, "region")
        col.prop(v, "max_points")
        col.prop(v, "method")
        op = layout.operator("facecap.track_clip", icon="TRACKING")
        op.region, op.max_points, op.method = tuple(v.region), v.max_points, v.method
        layout.label(text="2D takes are solved against")
        layout.prop(v, "projection", expand=True)
        if v.projection == "camera":
            layout.prop(v, "camera")
            if v.camera is None and scene.camera is None:
                layout.label(text="The scene has no camera: set one or pick it here", icon="ERROR")


CLASSES = (FACECAP_PT_video,)
