"""The "FaceCap" tab in the 3D viewport sidebar: Take, Stabilise (sub-panels: Neutral, Master T-Pose, Head Fit
and Alignment), Solve (sub-panels: Strategy Inputs, Priors and Smoothing, Shapes; each only where it applies)."""

import bpy

from ..scene import rom_markers


def _draw_rig(layout, s):
    """The solve's target: the shape keys, or a rig's controls (``[rig]``)."""
    box = layout.box().column(align=True)
    box.prop(s, "rig_preset")
    if s.rig_preset == "NONE":
        return
    if s.rig_preset != "shape_keys":
        box.prop(s, "rig_object")
    box.prop(s, "rig_method")
    if s.rig_method == "poses":
        box.prop(s, "rig_poses")
    else:
        row = box.row(align=True)
        row.prop(s, "rig_nonlinear")
        row.prop(s, "rig_refine")
        box.prop(s, "rig_probes")

class FACECAP_UL_markers(bpy.types.UIList):
    """Markers of the take with their stable flag and gap count."""

    def draw_item(self, _context, layout, data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "stable", text="")
        row.label(text=item.name)
        if item.stable_score >= 0:
            row.label(text=f"{item.stable_score:.1f}")
        if item.gaps:
            row.label(text=f"{item.gaps} gaps")
        if item.bound and item.bind_distance >= 0:  # bound by position: its distance to the surface
            row.label(text=f"{item.bind_distance:.1f} mm")
        elif not item.bound and getattr(data, "binding_summary", ""):  # after a binding
            row.label(text="unbound", icon="UNLINKED")


class FACECAP_UL_landmarks(bpy.types.UIList):
    """Landmarks of the nearest binding: a marker of the take and a vertex group of the character."""

    def draw_item(self, context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        s = context.scene.facecap
        row = layout.row(align=True)
        row.prop_search(item, "name", s, "markers", text="")
        if s.target is not None:
            row.prop_search(item, "vertex_group", s.target, "vertex_groups", text="")
        else:
            row.prop(item, "vertex_group", text="")


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


class FACECAP_UL_calib_poses(bpy.types.UIList):
    """Calibration poses: name, first and last frame, split into Left/Right."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "name", text="", emboss=False)
        row.prop(item, "first", text="")
        row.prop(item, "last", text="")
        row.prop(item, "split", text="", icon="MOD_MIRROR")


class FACECAP_UL_mapping(bpy.types.UIList):
    """Mapping rows: source channel -> character shape, gain."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index):
        row = layout.row(align=True)
        row.prop(item, "source", text="")
        row.prop(item, "target", text="")
        row.prop(item, "gain", text="")


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
        row = layout.row(align=True)
        row.operator("facecap.use_selected_empties", icon="EMPTY_DATA", text="Selected Empties")
        row.operator("facecap.import_clip_tracks", icon="TRACKER", text="Clip Tracks")
        layout.operator("facecap.track_clip", icon="TRACKING")
        layout.operator("facecap.clean_markers", icon="BRUSH_DATA")
        col = layout.column(align=True)
        col.prop(s, "take_name")
        col.prop(s, "marker_collection", text="Markers")
        col.prop(s, "fps")
        layout.prop(s, "target")
        _draw_binding(layout, s)


def _editable_list(layout, list_type, s, prop, active, add, remove, *, rows):
    """A UI list of ``s.<prop>`` with its add and remove buttons beside it."""
    row = layout.row()
    row.template_list(list_type, "", s, prop, s, active, rows=rows)
    col = row.column(align=True)
    col.operator(add, icon="ADD", text="")
    col.operator(remove, icon="REMOVE", text="")


def _draw_binding(layout, s):
    box = layout.box()
    box.prop(s, "binding_mode")
    if s.binding_mode == "map":
        box.prop(s, "binding_map")
    if s.binding_mode == "nearest":
        box.label(text="Landmarks (marker, vertex group): 3 or more, or none")
        _editable_list(box, "FACECAP_UL_landmarks", s, "binding_landmarks", "active_binding_landmark",
                       "facecap.binding_landmark_add", "facecap.binding_landmark_remove", rows=3)
    if s.binding_mode != "vertex_groups":
        box.prop(s, "binding_max_distance")
    row = box.row(align=True)
    row.operator("facecap.bind_markers", icon="SNAP_FACE")
    row.operator("facecap.clear_binding", icon="X", text="")
    if s.binding_summary:
        box.label(text=s.binding_summary)


class FACECAP_PT_stabilise(FacecapPanel, bpy.types.Panel):
    """Stable markers and head-motion removal; the neutral, the master T-pose and the head in sub-panels."""

    bl_label = "Stabilise"
    bl_idname = "FACECAP_PT_stabilise"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        n_stable = sum(m.stable for m in s.markers)
        layout.label(text=f"Stable markers: {n_stable} of {len(s.markers)}")
        layout.template_list("FACECAP_UL_markers", "", s, "markers", s, "active_marker", rows=5)
        row = layout.row(align=True)
        row.operator("facecap.suggest_stable", icon="VIEWZOOM")
        row.prop(s, "auto_stable")
        if s.stable_gap:
            layout.label(text=f"Suggested set: score gap x{s.stable_gap:.1f}",
                         icon="CHECKMARK" if s.stable_gap >= 2.0 else "ERROR")
        layout.prop(s, "stabilise_mode")
        layout.operator("facecap.stabilise", icon="ORIENTATION_GIMBAL")
        if s.head_object is not None:
            layout.prop(s, "head_object")
        if s.flagged_frames:
            layout.label(text=f"{s.flagged_frames} frame(s) could not be stabilised", icon="ERROR")
        if s.unreliable_frames:
            layout.label(text=f"{s.unreliable_frames} frame(s) with an unreliable head fit", icon="ERROR")


class FACECAP_PT_stabilise_neutral(FacecapPanel, bpy.types.Panel):
    """The actor's neutral: frame ranges, detected, or a file."""

    bl_label = "Neutral"
    bl_idname = "FACECAP_PT_stabilise_neutral"
    bl_parent_id = "FACECAP_PT_stabilise"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.prop(s, "neutral_mode")
        if s.neutral_mode in ("RANGE", "RANGES"):
            row = layout.row(align=True)
            row.prop(s, "neutral_first")
            row.prop(s, "neutral_last")
            layout.operator("facecap.set_neutral", icon="RESTRICT_SELECT_OFF")
        if s.neutral_mode == "RANGES":
            row = layout.row(align=True)
            row.prop(s, "neutral_end_first")
            row.prop(s, "neutral_end_last")
        elif s.neutral_mode == "DETECT":
            layout.operator("facecap.detect_neutral", icon="VIEWZOOM")
        elif s.neutral_mode == "FILE":
            layout.prop(s, "neutral_file")


class FACECAP_PT_stabilise_master(FacecapPanel, bpy.types.Panel):
    """The performer's master T-pose (marker placement offsets between sessions)."""

    bl_label = "Master T-Pose"
    bl_idname = "FACECAP_PT_stabilise_master"
    bl_parent_id = "FACECAP_PT_stabilise"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.prop(s, "use_master")
        layout.label(text=f"Master: {s.master_source}" if s.master_data else "No master T-pose stored")
        row = layout.row(align=True)
        row.operator("facecap.load_master", icon="FILE_FOLDER")
        row.operator("facecap.master_from_take", icon="IMPORT")
        layout.prop(s, "landmarks")


class FACECAP_PT_stabilise_head(FacecapPanel, bpy.types.Panel):
    """The head fit's refinement, the actor-to-character alignment and where the head motion is keyed."""

    bl_label = "Head Fit and Alignment"
    bl_idname = "FACECAP_PT_stabilise_head"
    bl_parent_id = "FACECAP_PT_stabilise"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.prop(s, "align_regions")
        col = layout.column(align=True)
        col.prop(s, "fine_iterations")
        col.prop(s, "head_smoothing")
        col = layout.column(align=True)
        col.prop(s, "head_target")
        if s.head_target is not None and s.head_target.type == "ARMATURE":
            col.prop(s, "head_bone")


MARKER_FIT = ("semantic", "geometric", "calibrated", "refine")  # strategies with a bounded solve (priors apply)
EXAMPLES = ("linear", "rbf", "pca")
WITH_OPTIONS = ("semantic", "calibrated", "refine", "parallel") + EXAMPLES  # strategies with inputs of their own


class FACECAP_PT_solve(FacecapPanel, bpy.types.Panel):
    """The strategy and the solve; its inputs, priors and shapes in sub-panels (only those that apply)."""

    bl_label = "Solve"
    bl_idname = "FACECAP_PT_solve"

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        _draw_rig(layout, s)
        layout.prop(s, "strategy")
        layout.operator("facecap.solve", icon="SHAPEKEY_DATA")
        row = layout.row(align=True)
        row.operator("facecap.export_take", icon="EXPORT")
        row.operator("facecap.export_review", icon="DOCUMENTS")
        if s.last_report:
            box = layout.box()
            for line in s.last_report.split(", "):
                box.label(text=line)


class FACECAP_PT_solve_inputs(FacecapPanel, bpy.types.Panel):
    """What the strategy learns from: the calibration, the solved weights, the posed examples, the mapping."""

    bl_label = "Strategy Inputs"
    bl_idname = "FACECAP_PT_solve_inputs"
    bl_parent_id = "FACECAP_PT_solve"

    @classmethod
    def poll(cls, context):
        return context.scene.facecap.strategy in WITH_OPTIONS

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        if s.strategy == "semantic":
            _draw_actor(layout, s)
        if s.strategy in ("calibrated", "refine", "semantic"):
            _draw_calibration(layout, s)
        if s.strategy == "parallel":
            _draw_parallel(layout, s)
        if s.strategy in EXAMPLES:
            _draw_examples(layout, s)
        if s.strategy in ("calibrated", "refine", "parallel"):
            _draw_mapping(layout, s)
        if s.strategy == "refine":
            col = layout.box().column(align=True)
            col.label(text="Refine the library on this take")
            col.prop(s, "refine_max_iterations")
            col.prop(s, "refine_tol")
            col.prop(s, "refine_stiffness")


class FACECAP_PT_solve_priors(FacecapPanel, bpy.types.Panel):
    """How the weights are held back: regularisation, sparsity, symmetry, smoothing over time."""

    bl_label = "Priors and Smoothing"
    bl_idname = "FACECAP_PT_solve_priors"
    bl_parent_id = "FACECAP_PT_solve"

    @classmethod
    def poll(cls, context):
        s = context.scene.facecap
        return s.strategy in MARKER_FIT or (s.strategy == "pca" and s.pca_mode == "posed")

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        if s.strategy in MARKER_FIT:
            col = layout.column(align=True)
            col.prop(s, "regularisation")
            col.prop(s, "sparsity")
            col.prop(s, "symmetry")
        col = layout.column(align=True)
        col.prop(s, "smoothing_first")
        col.prop(s, "smoothing_second")


class FACECAP_PT_solve_shapes(FacecapPanel, bpy.types.Panel):
    """The character's shapes: locks and bounds, and (geometric) face regions."""

    bl_label = "Shapes"
    bl_idname = "FACECAP_PT_solve_shapes"
    bl_parent_id = "FACECAP_PT_solve"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.facecap
        layout = self.layout
        layout.label(text="Lock, min, max" + (", region" if s.strategy == "geometric" else ""))
        layout.template_list("FACECAP_UL_shapes", "", s, "shapes", s, "active_shape", rows=4)
        layout.operator("facecap.refresh_shapes", icon="FILE_REFRESH")
        if s.strategy == "geometric":
            _editable_list(layout, "FACECAP_UL_regions", s, "regions", "active_region",
                           "facecap.region_add", "facecap.region_remove", rows=2)


def _draw_actor(layout, s):
    """What is known of the actor's face (the semantic solve's tier after a solve) and its options."""
    box = layout.box()
    box.label(text="The actor's face")
    for i, line in enumerate(_wrapped(s.actor_tier, 60)):
        box.label(text=line, icon="INFO" if i == 0 else "NONE")
    box.prop(s, "actor_profile")
    row = box.row(align=True)
    row.prop(s, "actor_template")
    row.operator("facecap.install_template", text="", icon="IMPORT")  # from the ICT-FaceKit download
    row.operator("facecap.download_template", text="", icon="URL")  # or downloaded here (online access)
    row = box.row(align=True)
    row.prop(s, "unseen_shapes")
    row.prop(s, "exclusive", text="Exclusive")


def _wrapped(text, width):
    """``text`` in lines of about ``width`` characters (a panel label does not wrap)."""
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + len(word) + 1 > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    return lines + ([line] if line else [])


def _draw_calibration(layout, s):
    box = layout.box()
    box.label(text="Actor calibration" + (" (optional: poses measure the actor's shapes)"
                                          if s.strategy == "semantic" else ""))
    rom = s.strategy == "semantic" and s.calib_sheet != "NONE"
    if s.strategy == "semantic":
        box.prop(s, "calib_sheet")
    box.prop(s, "calib_source", **({"text": "ROM Take"} if rom else {}))
    if s.calib_source == "COLLECTION":
        box.prop(s, "calib_collection", text="Markers")
    else:
        box.prop(s, "calib_path", text="File")
        box.prop(s, "calib_units")
    row = box.row(align=True)
    row.label(text="Neutral")
    row.prop(s, "calib_neutral_first")
    row.prop(s, "calib_neutral_last")
    row.operator("facecap.calib_neutral_from_timeline", icon="TIME", text="")
    if s.strategy == "semantic" and rom_markers.keeps_scores(s):  # a landmark take: a guide it followed
        box.prop(s, "calib_guide")
    if s.strategy == "semantic" and s.calib_guide.strip() and not rom:
        box.operator("facecap.rom_save_profile", icon="FILE_TICK")
    elif rom:
        _draw_rom(box, s)
    else:  # poses typed as frame ranges
        box.label(text="Poses (name, first, last, split)")
        _editable_list(box, "FACECAP_UL_calib_poses", s, "calib_poses", "active_calib_pose",
                       "facecap.calib_pose_add", "facecap.calib_pose_remove", rows=3)
        row = box.row(align=True)
        row.prop(s, "calib_pose_name", text="")
        row.operator("facecap.calib_pose_add", icon="TIME")
    box.prop(s, "calib_align")


def _draw_rom(box, s):
    """The ROM session: find its poses, save the profile, and how many holds the timeline marks."""
    row = box.row(align=True)
    row.operator("facecap.rom_find_poses", icon="VIEWZOOM")
    row.operator("facecap.rom_save_profile", icon="FILE_TICK")
    marked = len(rom_markers.rom_markers(s.id_data))
    poses = len(rom_markers.sheet_poses(s))
    box.label(icon="MARKER_HLT", text=f"{marked} of {poses} poses marked on the timeline: drag a marker to move its "
              "hold" if marked else "Find Poses marks each hold on the timeline ('ROM: <pose>')")


def _draw_mapping(layout, s):
    box = layout.box()
    box.label(text="Mapping (empty rows: one-to-one by name)")
    _editable_list(box, "FACECAP_UL_mapping", s, "mapping", "active_mapping",
                   "facecap.mapping_add", "facecap.mapping_remove", rows=3)
    row = box.row(align=True)
    row.operator("facecap.mapping_fill_by_name", icon="SORTALPHA")
    row.operator("facecap.mapping_clear", icon="X")
    box.prop(s, "mapping_aliases")


def _draw_parallel(layout, s):
    box = layout.box()
    box.label(text="Solved weights")
    box.prop(s, "weights_path", text="File")
    col = box.column(align=True)
    col.prop(s, "parallel_gain")
    col.prop(s, "parallel_offset")
    col.prop(s, "parallel_curve")
    if s.parallel_curve == "gamma":
        col.prop(s, "parallel_gamma")
    box.prop(s, "parallel_mirror")
    row = box.row(align=True)
    row.prop(s, "parallel_use_neutral")
    if s.parallel_use_neutral:
        row.prop(s, "parallel_neutral_first")
        row.prop(s, "parallel_neutral_last")


def _draw_examples(layout, s):
    box = layout.box()
    box.label(text="Posed examples (keyed frames of an action)")
    box.prop(s, "examples_action")
    col = box.column(align=True)
    if s.strategy == "linear":
        col.prop(s, "ridge")
    elif s.strategy == "rbf":
        col.prop(s, "rbf_kernel")
        col.prop(s, "rbf_smoothing")
        col.prop(s, "rbf_degree")
        col.prop(s, "rbf_far")
        col.prop(s, "n_components")
    else:
        col.prop(s, "pca_mode")
        col.prop(s, "pca_ica")
        col.prop(s, "pca_n_basis")
        col.prop(s, "pca_variance")
        col.prop(s, "n_components")


CLASSES = (FACECAP_UL_markers, FACECAP_UL_landmarks, FACECAP_UL_shapes, FACECAP_UL_regions, FACECAP_UL_calib_poses,
           FACECAP_UL_mapping, FACECAP_PT_take, FACECAP_PT_stabilise, FACECAP_PT_stabilise_neutral,
           FACECAP_PT_stabilise_master, FACECAP_PT_stabilise_head, FACECAP_PT_solve, FACECAP_PT_solve_inputs,
           FACECAP_PT_solve_priors, FACECAP_PT_solve_shapes)
