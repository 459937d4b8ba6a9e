"""The "Video" panel of the FaceCap sidebar: track the active clip, solve the character from its flow (no
markers), and how 2D takes see the character."""

import bpy

from ...solvers.video.landmarker_bundle import bundle_path
from .panels import FacecapPanel


class FACECAP_PT_video(FacecapPanel, bpy.types.Panel):
    """Track movie-clip footage or solve from its dense flow (Esc cancels), and choose the projection 2D takes
    are solved through."""

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
        box = layout.box()
        box.label(text="Without markers: the face's landmarks")
        box.prop(v, "landmark_smoothing")
        row = box.row(align=True)
        row.operator("facecap.track_face_landmarks", icon="USER").smoothing = v.landmark_smoothing
        op = row.operator("facecap.track_face_landmarks", text="Track and Solve", icon="PLAY")
        op.smoothing, op.solve = v.landmark_smoothing, True
        if not _face_models_installed():
            box.operator("facecap.download_face_models", icon="URL")
        box = layout.box()
        box.label(text="Without markers: flow over the Region")
        col = box.column(align=True)
        col.prop(v, "stable_region")
        col.prop(v, "flow_method")
        col.prop(v, "flow_components")
        col.prop(v, "flow_grid_step")
        col.prop(v, "flow_strategy")
        if getattr(scene.facecap, "examples_action", None) is None:
            box.label(text="Pose frames in an Examples action (Solve panel)", icon="INFO")
        box.operator("facecap.solve_clip_flow", icon="FORCE_TURBULENCE")
        layout.label(text="2D takes are solved against")
        layout.prop(v, "projection", expand=True)
        if v.projection == "camera":
            layout.prop(v, "camera")
            if v.camera is None and scene.camera is None:
                layout.label(text="The scene has no camera: set one or pick it here", icon="ERROR")


def _face_models_installed():
    """The Face Landmarker bundle is in the cache (found, not hash-checked: drawing stays instant)."""
    return bundle_path().is_file()


CLASSES = (FACECAP_PT_video,)
