"""The "Tune" panel of the FaceCap sidebar: corrections that teach the solver, per-shape controls,
library versions and the way to the worst frames."""

import bpy

from .panels import FacecapPanel


class FACECAP_UL_tuning_frames(bpy.types.UIList):
    """Tuning frames: frame, how much the animator changed it, error after the last retune."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.label(text=f"Frame {item.frame}", icon="KEYFRAME_HLT")
        row.label(text=f"changed {item.change:.3f}")
        row.label(text="" if item.error < 0 else f"now {item.error:.3f}")


class FACECAP_UL_library_versions(bpy.types.UIList):
    """Library versions: name, corrected-frame error before -> after, the one in use."""

    def draw_item(self, context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        active = context.scene.facecap.library_active == item.name
        row = layout.row(align=True)
        row.label(text=item.name, icon="CHECKMARK" if active else "BLANK1")
        if item.corrected_before >= 0:
            row.label(text=f"{item.corrected_before:.3f} -> {item.corrected_after:.3f}")


class FACECAP_PT_tune(FacecapPanel, bpy.types.Panel):
    """After a solve: mark corrected frames, retune, keep versions, shape controls."""

    bl_label = "Tune"
    bl_idname = "FACECAP_PT_tune"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        row = layout.row(align=True)
        row.operator("facecap.jump_worst", icon="ERROR")
        row.prop(s, "worst_spread")

        layout.label(text="Corrected frames")
        row = layout.row()
        row.template_list("FACECAP_UL_tuning_frames", "", s, "tuning_frames", s, "tuning_index", rows=3)
        col = row.column(align=True)
        col.operator("facecap.tuning_add_current", icon="ADD", text="")
        col.operator("facecap.tuning_add_edited", icon="KEYINGSET", text="")
        col.operator("facecap.tuning_remove", icon="REMOVE", text="")
        col.operator("facecap.tuning_clear", icon="X", text="")
        row = layout.row(align=True)
        row.prop(s, "tune_auto_mu")
        sub = row.row(align=True)
        sub.enabled = not s.tune_auto_mu
        sub.prop(s, "tune_mu")
        row = layout.row(align=True)
        row.operator("facecap.retune", icon="FILE_REFRESH")
        row.operator("facecap.fit_gain_offset", icon="DRIVER")

        layout.label(text=f"Library in use: {s.library_active or 'original'}")
        layout.template_list("FACECAP_UL_library_versions", "", s, "library_versions", s, "library_index", rows=2)
        row = layout.row(align=True)
        if 0 <= s.library_index < len(s.library_versions):
            row.operator("facecap.library_use", text="Use Selected").name = s.library_versions[s.library_index].name
        row.operator("facecap.library_revert", icon="LOOP_BACK", text="Back")
        row.operator("facecap.library_use", text="Original").name = ""

        if 0 <= s.active_shape < len(s.shapes):
            shape = s.shapes[s.active_shape]
            box = layout.box()
            box.label(text=f"Controls: {shape.name}", icon="SHAPEKEY_DATA")
            col = box.column(align=True)
            col.prop(shape, "gain")
            col.prop(shape, "offset")
            row = col.row(align=True)
            row.prop(shape, "curve", text="")
            if shape.curve == "gamma":
                row.prop(shape, "gamma")
            col.prop(shape, "smoothing")
            row = col.row(align=True)
            row.prop(shape, "use_clamp")
            sub = row.row(align=True)
            sub.enabled = shape.use_clamp
            sub.prop(shape, "clamp_min", text="")
            sub.prop(shape, "clamp_max", text="")
            row = col.row(align=True)
            row.prop(shape, "mute")
            row.prop(shape, "lock")
        row = layout.row(align=True)
        row.operator("facecap.controls_load", icon="IMPORT", text="Load Preset")
        row.operator("facecap.controls_save", icon="EXPORT", text="Save Preset")


CLASSES = (FACECAP_UL_tuning_frames, FACECAP_UL_library_versions, FACECAP_PT_tune)
