"""Remove head motion and keep it on an empty (or the character's head); suggest the stable set."""

import bpy
import numpy as np

from ..facecap_addon.scene import take
from ..facecap_addon.ui.greyed import needs
from ..solvers.capture.stable_markers import suggest_stable_markers
from ..solvers.errors import FacecapError
from ..solvers.pipeline.stages import stabilise_take


class FACECAP_OT_stabilise(bpy.types.Operator):
    """Fit the stable markers per frame, report the fit and key the removed head motion on an empty
    (and on the character's head object or bone when one is set)"""

    bl_idname = "facecap.stabilise"
    bl_label = "Stabilise"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take", "stable set")

    def execute(self, context):
        settings = context.scene.facecap
        notes = []
        try:
            markers = take.markers_from_collection(settings)
            opts = take.retarget_settings(settings)
            stab, _ = stabilise_take(markers, opts, notes)
            head = take.key_head_motion(context.scene, stab, f"FaceCap Head {settings.take_name}")
            if opts.head_target:
                take.key_head_on_target(opts.head_target, stab, f"FaceCap Head {settings.take_name} on target")
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        settings.head_object = head
        settings.flagged_frames = int(stab.flagged.sum())
        settings.unreliable_frames = int(np.sum(stab.unreliable)) if stab.unreliable is not None else 0
        for note in notes:
            self.report({"WARNING"}, note)
        rms = float(np.nanmean(stab.rms) * 1e3) if np.isfinite(stab.rms).any() else float("nan")
        bad = settings.flagged_frames + settings.unreliable_frames
        self.report(
            {"WARNING" if bad else "INFO"},
            f"Stabilised {markers.n_frames} frames on {len(stab.stable_names)} markers ({stab.mode}), "
            f"stable-marker RMS {rms:.3f} mm, {settings.flagged_frames} frame(s) flagged, "
            f"{settings.unreliable_frames} unreliable; head motion on '{head.name}'",
        )
        return {"FINISHED"}


class FACECAP_OT_suggest_stable(bpy.types.Operator):
    """Suggest the markers that move only with the head, tick them and show each marker's score
    (expression-synchronous motion in noise units: about 1 or less is rigid)"""

    bl_idname = "facecap.suggest_stable"
    bl_label = "Suggest Stable Markers"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            suggestion = suggest_stable_markers(markers)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        # No reliable set: tick the best candidates for the user to check, and say so.
        chosen = set(suggestion.names if suggestion.ok else suggestion.candidates)
        for m in settings.markers:
            m.stable = m.name in chosen
            m.stable_score = suggestion.scores.get(m.name, -1.0)
        settings.stable_gap = suggestion.gap
        if not suggestion.ok:
            self.report({"WARNING"}, f"{suggestion.message()[0].upper()}{suggestion.message()[1:]}: ticked them; "
                                     "check them before stabilising")
            return {"FINISHED"}
        top = ", ".join(f"{n} {suggestion.scores[n]:.2f}" for n in suggestion.names)
        warning = suggestion.conditioning.get("warning")
        self.report(
            {"INFO" if warning is None else "WARNING"},
            f"Suggested {len(chosen)} stable markers (head-fit error at the face "
            f"{suggestion.conditioning.get('face_error_mm', float('nan')):.2f} mm"
            f"{'' if warning is None else '; ' + warning}): {top}",
        )
        return {"FINISHED"}


CLASSES = (FACECAP_OT_stabilise, FACECAP_OT_suggest_stable)
