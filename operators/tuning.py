"""The animator feedback loop in the sidebar: tuning frames, Retune, library versions, gain/offset,
shape-control presets and "jump to the next worst frame".

Corrections are the *final* weights (solve layer + the animator's layer above it) at the tuning
frames; see ``facecap_addon/scene/layers.py`` and ``solvers/tuning_take.py``.
"""

import bpy
import numpy as np
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..facecap_addon.scene import scene_solve, tuning_scene
from ..facecap_addon.ui.greyed import needs, unless
from ..solvers.character.shape_controls import load_preset, save_preset
from ..solvers.errors import FacecapError
from ..solvers.tuning.retune import fit_gain_offset
from .solve import SolveJobOperator


def _solved(context):
    return tuning_scene.solved(context.scene.facecap)


def _add_frames(settings, frames):
    have = {t.frame for t in settings.tuning_frames}
    new = [int(f) for f in frames if int(f) not in have]
    if new:
        for f, change in zip(new, tuning_scene.frame_change(settings, new)):
            item = settings.tuning_frames.add()
            item.frame, item.change = f, float(change)
        order = sorted((t.frame, t.change, t.error) for t in settings.tuning_frames)
        for item, (f, change, error) in zip(settings.tuning_frames, order):
            item.frame, item.change, item.error = f, change, error
    return new


class FACECAP_OT_tuning_add_current(bpy.types.Operator):
    """Add the current frame to the tuning frames (its weights, as you set them, become a correction)"""

    bl_idname = "facecap.tuning_add_current"
    bl_label = "Add Current Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "solve")

    def execute(self, context):
        settings = context.scene.facecap
        new = _add_frames(settings, [context.scene.frame_current])
        tuning_scene.sync_markers(context.scene)
        self.report({"INFO"}, f"Frame {context.scene.frame_current} " + ("added" if new else "is already listed"))
        return {"FINISHED"}


class FACECAP_OT_tuning_add_edited(bpy.types.Operator):
    """Add every frame you keyed on the layer above the solve where the result differs from the solve"""

    bl_idname = "facecap.tuning_add_edited"
    bl_label = "Add Edited Frames"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "solve")

    def execute(self, context):
        settings = context.scene.facecap
        frames = tuning_scene.edited_frames(settings)
        new = _add_frames(settings, frames)
        tuning_scene.sync_markers(context.scene)
        self.report({"INFO"}, f"{len(new)} edited frame(s) added ({len(frames)} edited in all)")
        return {"FINISHED"}


class FACECAP_OT_tuning_remove(bpy.types.Operator):
    """Remove the selected tuning frame"""

    bl_idname = "facecap.tuning_remove"
    bl_label = "Remove Tuning Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.tuning_frames) > 0, "No tuning frames: nothing to remove")

    def execute(self, context):
        settings = context.scene.facecap
        settings.tuning_frames.remove(settings.tuning_index)
        settings.tuning_index = max(0, min(settings.tuning_index, len(settings.tuning_frames) - 1))
        tuning_scene.sync_markers(context.scene)
        return {"FINISHED"}


class FACECAP_OT_tuning_clear(bpy.types.Operator):
    """Remove every tuning frame"""

    bl_idname = "facecap.tuning_clear"
    bl_label = "Clear Tuning Frames"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        context.scene.facecap.tuning_frames.clear()
        tuning_scene.sync_markers(context.scene)
        return {"FINISHED"}


class FACECAP_OT_retune(SolveJobOperator, bpy.types.Operator):
    """Re-optimise the library from the tuning frames, store it as a new version and re-solve the take. The status bar shows how long; Esc cancels with nothing stored or keyed"""

    bl_idname = "facecap.retune"
    bl_label = "Retune"
    bl_options = {"REGISTER", "UNDO"}

    consume: BoolProperty(
        name="Take In Corrections", default=True,
        description="Afterwards, the layer above the solve continues as a copy without the keys at the tuning "
        "frames (the library has learned them); the original layer action is kept unchanged",
    )

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "solve", "tuning frames")

    def _start(self, context):
        settings = context.scene.facecap
        corrections = tuning_scene.corrections(settings)
        mu = None if settings.tune_auto_mu else settings.tune_mu
        session = scene_solve.start_session(settings, context.scene, what="Retune", corrections=corrections, mu=mu)
        session.corrections = corrections  # what _write compares the re-solve with
        return session

    def _write(self, context, session):
        scene = context.scene
        settings = scene.facecap
        result, corrections = session.wait(), session.corrections
        tuned = result.retune
        if tuned.changed:
            tuning_scene.store_version(scene, tuned.version)
            settings.library_active = tuned.version.name
            settings.library_index = list(settings.library_versions.keys()).index(tuned.version.name)
        if self.consume:
            tuning_scene.take_in_corrections(settings, sorted(corrections))
        scene_solve.key_solve(settings, result)
        rows = {float(f): i for i, f in enumerate(result.frames)}
        for item in settings.tuning_frames:
            want = np.array(list(corrections[float(item.frame)].values()))
            got = result.weights[rows[float(item.frame)], [result.shape_names.index(n) for n in corrections[float(item.frame)]]]
            item.error = float(np.sqrt(np.nanmean((got - want) ** 2)))
        summary = (f"Retune: corrected frames RMS {tuned.corrected_rmse_before:.4f} -> {tuned.corrected_rmse_after:.4f}, "
                   f"other frames moved {tuned.others_moved * 100:.1f}%"
                   + (f", library '{tuned.version.name}'" if tuned.changed else ", library unchanged"))
        settings.last_report = summary
        for note in tuned.notes:
            self.report({"WARNING"}, note)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


class FACECAP_OT_library_use(bpy.types.Operator):
    """Solve with this library version (empty name: the original) and key the result as the solve layer"""

    bl_idname = "facecap.library_use"
    bl_label = "Use Library Version"
    bl_options = {"REGISTER", "UNDO"}

    name: StringProperty(name="Version", description="Stored version name; empty = the original library")

    def execute(self, context):
        settings = context.scene.facecap
        if self.name and self.name not in settings.library_versions:
            self.report({"ERROR"}, f"no library version '{self.name}' in this .blend")
            return {"CANCELLED"}
        previous = settings.library_active
        settings.library_active = self.name
        try:
            result = scene_solve.solve_take(settings, context.scene)
            scene_solve.key_solve(settings, result)
        except FacecapError as exc:
            settings.library_active = previous
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Solved with library '{self.name or 'original'}'")
        return {"FINISHED"}


class FACECAP_OT_library_revert(bpy.types.Operator):
    """Go back to the version the active library was tuned from (or the original) and re-solve"""

    bl_idname = "facecap.library_revert"
    bl_label = "Revert Library"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, bool(context.scene.facecap.library_active),
                      "No library version in use: the strategy solves with what it fitted")

    def execute(self, context):
        settings = context.scene.facecap
        row = settings.library_versions.get(settings.library_active)
        parent = row.parent if row is not None and row.parent in settings.library_versions else ""
        return bpy.ops.facecap.library_use(name=parent)


class FACECAP_OT_fit_gain_offset(SolveJobOperator, bpy.types.Operator):
    """Fit each shape's gain and offset to the tuning frames (least squares), then re-solve and key. The status bar shows how long; Esc cancels with nothing changed"""

    bl_idname = "facecap.fit_gain_offset"
    bl_label = "Fit Gain and Offset"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "solve", "tuning frames")

    def _start(self, context):
        settings = context.scene.facecap
        corrections = tuning_scene.corrections(settings)
        frames = sorted(corrections)
        names, solve, _ = tuning_scene.channel_values(settings, frames)
        gain, offset = fit_gain_offset(solve, {i: np.array([corrections[f][n] for n in names])
                                               for i, f in enumerate(frames)})
        # solved with the fitted controls before they are written: Esc leaves the shape list as it was
        controls = tuning_scene.controls_with_gain_offset(settings, names, gain, offset)
        session = scene_solve.start_session(settings, context.scene, what="Fit Gain and Offset", controls=controls)
        session.fit = (names, gain, offset, frames)
        return session

    def _write(self, context, session):
        settings = context.scene.facecap
        result = session.wait()
        names, gain, offset, frames = session.fit
        changed = tuning_scene.compose_gain_offset(settings, names, gain, offset)
        tuning_scene.take_in_corrections(settings, frames)
        scene_solve.key_solve(settings, result)
        self.report({"INFO"}, f"Gain/offset fitted on {len(changed)} shape(s): {', '.join(changed[:6])}"
                    + ("..." if len(changed) > 6 else ""))
        return {"FINISHED"}


class FACECAP_OT_jump_worst(bpy.types.Operator):
    """Jump to the worst frame (largest solve residual); pressed again, to the next worst (neighbours of a worse frame are skipped)"""

    bl_idname = "facecap.jump_worst"
    bl_label = "Next Worst Frame"

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "solve")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            frames, residual = tuning_scene.residual_curve(tuning_scene.diagnostics_owner(settings))
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if not frames.size:
            self.report({"WARNING"}, "the solve has no residual to rank frames by")
            return {"CANCELLED"}
        current = context.scene.frame_current
        walking = current == settings.worst_last  # pressed again where the last jump landed: go on down
        frame = tuning_scene.next_worst_frame(frames, residual, current if walking else None,
                                              spread=settings.worst_spread)
        context.scene.frame_set(int(frame))
        settings.worst_last = int(frame)
        value = residual[list(frames).index(frame)]
        self.report({"INFO"}, f"Frame {int(frame)}: residual {value:.2f} mm")
        return {"FINISHED"}


class FACECAP_OT_controls_save(bpy.types.Operator, ExportHelper):
    """Save the per-shape controls (gain, offset, clamp, curve, smoothing, mute, lock) as a JSON preset"""

    bl_idname = "facecap.controls_save"
    bl_label = "Save Controls Preset"
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context):
        try:
            save_preset(self.filepath, tuning_scene.shape_controls(context.scene.facecap, with_locks=True))
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Saved {self.filepath}")
        return {"FINISHED"}


class FACECAP_OT_controls_load(bpy.types.Operator, ImportHelper):
    """Load per-shape controls from a JSON preset into the shape list"""

    bl_idname = "facecap.controls_load"
    bl_label = "Load Controls Preset"
    bl_options = {"REGISTER", "UNDO"}
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "shapes")

    def execute(self, context):
        try:
            tuning_scene.set_controls(context.scene.facecap, load_preset(self.filepath))
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Loaded {self.filepath}")
        return {"FINISHED"}


CLASSES = (
    FACECAP_OT_tuning_add_current, FACECAP_OT_tuning_add_edited, FACECAP_OT_tuning_remove, FACECAP_OT_tuning_clear,
    FACECAP_OT_retune, FACECAP_OT_library_use, FACECAP_OT_library_revert, FACECAP_OT_fit_gain_offset,
    FACECAP_OT_jump_worst, FACECAP_OT_controls_save, FACECAP_OT_controls_load,
)
