"""Choose the neutral / T-pose frame range."""

import warnings
from dataclasses import replace

import bpy
import numpy as np
from bpy.props import IntProperty, StringProperty

from ..facecap_addon.scene import take
from ..facecap_addon.ui.greyed import needs
from ..solvers.capture.neutral import neutral_from_frames
from ..solvers.capture.normalise import detect_neutral_frames
from ..solvers.errors import FacecapError
from ..solvers.io import import_markers
from ..solvers.pipeline.stages import spans, stabilise_take


class FACECAP_OT_set_neutral(bpy.types.Operator):
    """Set the neutral (T-pose) frame range; defaults to the preview range, or 30 frames from the current frame"""

    bl_idname = "facecap.set_neutral"
    bl_label = "Set Neutral"
    bl_options = {"REGISTER", "UNDO"}

    first: IntProperty(name="First", default=-1, description="First frame (-1: from the timeline)")
    last: IntProperty(name="Last", default=-1, description="Last frame (-1: from the timeline)")

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take")

    def execute(self, context):
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


class FACECAP_OT_detect_neutral(bpy.types.Operator):
    """Find the most neutral frames (the pose the face holds longest) and use them as the neutral"""

    bl_idname = "facecap.detect_neutral"
    bl_label = "Detect Neutral"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take", "stable set")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            opts = replace(take.retarget_settings(settings), neutral_detect=True, neutral_ranges=())
            stab, _ = stabilise_take(markers, opts, [])
            frames, _dev = detect_neutral_frames(stab.markers)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        settings.neutral_mode = "DETECT"
        self.report({"INFO"}, f"Neutral detected from {len(frames)} frame(s): {spans(frames)}")
        return {"FINISHED"}


class FACECAP_OT_load_master(bpy.types.Operator):
    """Read the performer's master T-pose from a marker file and store it in this .blend"""

    bl_idname = "facecap.load_master"
    bl_label = "Load Master"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(subtype="FILE_PATH")

    def invoke(self, context, _event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        settings = context.scene.facecap
        try:
            markers = import_markers(bpy.path.abspath(self.filepath)).markers.to_units("m")
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            pose = np.nanmedian(markers.positions, axis=0)
        missing = [n for n, p in zip(markers.names, pose) if np.isnan(p).any()]
        if missing:
            self.report({"ERROR"}, f"master T-pose {self.filepath}: marker(s) {missing[:8]} have no sample")
            return {"CANCELLED"}
        take.store_master(settings, markers.names, pose, bpy.path.basename(self.filepath))
        settings.use_master = True
        self.report({"INFO"}, f"Master T-pose: {len(markers.names)} markers from {markers.n_frames} frame(s) stored")
        return {"FINISHED"}


class FACECAP_OT_master_from_take(bpy.types.Operator):
    """Store this take's T-pose (the neutral frames, head motion removed) as the performer's master T-pose"""

    bl_idname = "facecap.master_from_take"
    bl_label = "Master From Take"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take", "stable set")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            opts = replace(take.retarget_settings(settings), master=None)
            stab, _ = stabilise_take(markers, opts, [])
            pose = neutral_from_frames(stab.markers, settings.neutral_first, settings.neutral_last)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        take.store_master(settings, markers.names, pose,
                          f"{settings.take_name or 'take'} frames {settings.neutral_first}-{settings.neutral_last}")
        self.report({"INFO"}, f"Master T-pose stored from frames {settings.neutral_first}-{settings.neutral_last} "
                    f"({len(markers.names)} markers)")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_set_neutral, FACECAP_OT_detect_neutral, FACECAP_OT_load_master, FACECAP_OT_master_from_take)
