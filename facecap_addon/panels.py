"""The "FaceCap" tab in the 3D viewport sidebar: Take, Stabilise, Solve."""

import bpy


class FACECAP_UL_markers(bpy.types.UIList):
    """Markers of the take with their stable flag and gap count."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "stable", text="")
        row.label(text=item.name)
        if item.gaps:
            row.label(text=f"{item.gaps} gaps")


class FACECAP_UL_shapes(bpy.types.UIList):
    """Shapes with lock, bounds and region."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "lock", text="", icon="LOCKED" if item.lock else "UNLOCKED", emboss=False)
        row.label(text=item.name)
        if item.lock:
            row.prop(item, "lock_value", text="")
        else:
            row.prop(item, "lower", text="")
            row.prop(item, "upper", text="")
        row.prop(item, "region", text="")


class FACECAP_UL_regions(bpy.types.UIList):
    """Regions with their marker patterns."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "name", text="", emboss=False)
        row.prop(item, "markers", text="")


class FacecapPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "FaceCap"


class FACECAP_PT_take(FacecapPanel, bpy.types.Panel):
    """Import a take and choose the character."""

    bl_label = "Take"
    bl_idname = "FACECAP_PT_take"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.operator("facecap.import_markers", icon="IMPORT")
        col = layout.column(align=True)
        col.prop(s, "take_name")
        col.prop(s, "marker_collection", text="Markers")
        col.prop(s, "fps")
        layout.prop(s, "target")


class FACECAP_PT_stabilise(FacecapPanel, bpy.types.Panel):
    """Stable markers, neutral range and head-motion removal."""

    bl_label = "Stabilise"
    bl_idname = "FACECAP_PT_stabilise"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        n_stable = sum(m.stable for m in s.markers)
        layout.label(text=f"Stable markers: {n_stable} of {len(s.markers)}")
        layout.template_list("FACECAP_UL_markers", "", s, "markers", s, "active_marker", rows=5)
        row = layout.row(align=True)
        row.prop(s, "neutral_first")
        row.prop(s, "neutral_last")
        layout.operator("facecap.set_neutral", icon="RESTRICT_SELECT_OFF")
        col = layout.column(align=True)
        col.prop(s, "fine_iterations")
        col.prop(s, "head_smoothing")
        layout.operator("facecap.stabilise", icon="ORIENTATION_GIMBAL")
        if s.head_object is not None:
            layout.prop(s, "head_object")
        if s.flagged_frames:
            layout.label(text=f"{s.flagged_frames} frame(s) could not be stabilised", icon="ERROR")


class FACECAP_PT_solve(FacecapPanel, bpy.types.Panel):
    """Strategy options and the solve."""

    bl_label = "Solve"
    bl_idname = "FACECAP_PT_solve"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.prop(s, "strategy")
        col = layout.column(align=True)
        col.prop(s, "regularisation")
        col.prop(s, "sparsity")
        col.prop(s, "symmetry")
        col = layout.column(align=True)
        col.prop(s, "smoothing_first")
        col.prop(s, "smoothing_second")
        layout.label(text="Shapes (lock, min, max, region)")
        layout.template_list("FACECAP_UL_shapes", "", s, "shapes", s, "active_shape", rows=4)
        layout.operator("facecap.refresh_shapes", icon="FILE_REFRESH")
        row = layout.row()
        row.template_list("FACECAP_UL_regions", "", s, "regions", s, "active_region", rows=2)
        col = row.column(align=True)
        col.operator("facecap.region_add", icon="ADD", text="")
        col.operator("facecap.region_remove", icon="REMOVE", text="")
        layout.operator("facecap.solve", icon="SHAPEKEY_DATA")
        if s.last_report:
            box = layout.box()
            for line in s.last_report.split(", "):
                box.label(text=line)


CLASSES = (FACECAP_UL_markers, FACECAP_UL_shapes, FACECAP_UL_regions, FACECAP_PT_take, FACECAP_PT_stabilise, FACECAP_PT_solve)
