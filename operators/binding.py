"""Bind the take's markers to the character (Take panel > Binding), landmarks, clear."""

import bpy

from ..facecap_addon.scene import scene_binding, take
from ..facecap_addon.ui.greyed import needs, unless
from ..solvers.errors import FacecapError


class FACECAP_OT_bind_markers(bpy.types.Operator):
    """Bind the take's markers to the character as the Binding mode says (vertex groups, map, or the nearest
    surface point after aligning the neutral), store the binding on the character and show the bound points"""

    bl_idname = "facecap.bind_markers"
    bl_label = "Bind Markers"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character", "take")

    def execute(self, context):
        s = context.scene.facecap
        try:
            markers = take.markers_from_collection(s)
            binding = scene_binding.binding_from_sidebar(s)
            bound = scene_binding.geometric_character(s.target, markers, take.retarget_settings(s), binding,
                                                      rebind=True, driven=s.rig_preset != "NONE")
            scene_binding.draw_points(context.scene, s.target, bound.record)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        scene_binding.show_markers(s, bound)
        for note in bound.notes:
            self.report({"WARNING"} if note.startswith("warning") else {"INFO"}, note)
        self.report({"INFO"}, bound.summary())
        return {"FINISHED"}


class FACECAP_OT_clear_binding(bpy.types.Operator):
    """Remove the binding stored on the character and the empties showing it (the next solve binds again)"""

    bl_idname = "facecap.clear_binding"
    bl_label = "Clear Binding"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character")

    def execute(self, context):
        s = context.scene.facecap
        scene_binding.store_record(s.target, None)
        scene_binding.clear_points(s.target)
        for item in s.markers:
            item.bound, item.bind_distance = False, -1.0
        s.binding_summary = ""
        return {"FINISHED"}


class FACECAP_OT_binding_landmark_add(bpy.types.Operator):
    """Add a landmark: the marker selected in the marker list (Stabilise panel) at the character's active
    vertex group"""

    bl_idname = "facecap.binding_landmark_add"
    bl_label = "Add Landmark"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.facecap
        row = s.binding_landmarks.add()
        if 0 <= s.active_marker < len(s.markers):
            row.name = s.markers[s.active_marker].name
        group = s.target.vertex_groups.active if s.target is not None else None
        if group is not None:
            row.vertex_group = group.name
        s.active_binding_landmark = len(s.binding_landmarks) - 1
        return {"FINISHED"}


class FACECAP_OT_binding_landmark_remove(bpy.types.Operator):
    """Remove the selected landmark"""

    bl_idname = "facecap.binding_landmark_remove"
    bl_label = "Remove Landmark"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.binding_landmarks) > 0, "No landmarks: nothing to remove")

    def execute(self, context):
        s = context.scene.facecap
        s.binding_landmarks.remove(s.active_binding_landmark)
        s.active_binding_landmark = max(0, s.active_binding_landmark - 1)
        return {"FINISHED"}


CLASSES = (FACECAP_OT_bind_markers, FACECAP_OT_clear_binding, FACECAP_OT_binding_landmark_add,
           FACECAP_OT_binding_landmark_remove)
