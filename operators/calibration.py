"""Calibration poses of the Solve panel: named frame ranges of the actor's calibration take."""

import bpy

from ..facecap_addon.ui.greyed import unless


class FACECAP_OT_calib_pose_add(bpy.types.Operator):
    """Add a calibration pose named after 'Pose Name' over the timeline's preview range (or the current frame)"""

    bl_idname = "facecap.calib_pose_add"
    bl_label = "Add Pose From Timeline"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        scene = context.scene
        settings = scene.facecap
        name = settings.calib_pose_name.strip()
        if not name:
            self.report({"ERROR"}, "type a pose name first (e.g. jawOpen, AU12)")
            return {"CANCELLED"}
        if scene.use_preview_range:
            first, last = scene.frame_preview_start, scene.frame_preview_end
        else:
            first = last = scene.frame_current
        pose = settings.calib_poses.add()
        pose.name, pose.first, pose.last = name, first, last
        settings.active_calib_pose = len(settings.calib_poses) - 1
        self.report({"INFO"}, f"Pose '{name}': frames {first}-{last}")
        return {"FINISHED"}


class FACECAP_OT_calib_pose_remove(bpy.types.Operator):
    """Remove the active calibration pose"""

    bl_idname = "facecap.calib_pose_remove"
    bl_label = "Remove Pose"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.calib_poses) > 0, "No calibration poses: nothing to remove")

    def execute(self, context):
        settings = context.scene.facecap
        settings.calib_poses.remove(settings.active_calib_pose)
        settings.active_calib_pose = max(0, min(settings.active_calib_pose, len(settings.calib_poses) - 1))
        return {"FINISHED"}


class FACECAP_OT_calib_neutral_from_timeline(bpy.types.Operator):
    """Use the timeline's preview range (or the current frame) as the calibration take's neutral"""

    bl_idname = "facecap.calib_neutral_from_timeline"
    bl_label = "Neutral From Timeline"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        scene = context.scene
        settings = scene.facecap
        if scene.use_preview_range:
            first, last = scene.frame_preview_start, scene.frame_preview_end
        else:
            first = last = scene.frame_current
        settings.calib_neutral_first, settings.calib_neutral_last = first, last
        self.report({"INFO"}, f"Calibration neutral: frames {first}-{last}")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_calib_pose_add, FACECAP_OT_calib_pose_remove, FACECAP_OT_calib_neutral_from_timeline)
