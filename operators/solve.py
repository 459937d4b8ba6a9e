"""Solve the take onto the character and key the weights in a new action."""

import bpy

from ..solvers.errors import FacecapError


class FACECAP_OT_solve(bpy.types.Operator):
    """Solve shape-key weights for every frame and key them in a new action named after the take"""

    bl_idname = "facecap.solve"
    bl_label = "Solve and Key"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = context.scene.facecap
        return s.target is not None and s.marker_collection is not None

    def execute(self, context):
        import numpy as np

        from ..facecap_addon import anim, take
        from ..facecap_addon.scene_data import basis_from_object
        from ..solvers.pipeline import retarget

        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            basis = basis_from_object(settings.target, markers.names)
            result = retarget(markers, basis, take.retarget_settings(settings))
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        action = take.key_weights(settings.target, result, anim.unique_action_name(settings.take_name or "FaceCap"))
        settings.last_action = action.name
        rms = float(np.nanmean(result.residual_rms) * 1e3)
        summary = (
            f"Solved {len(result.shape_names)} shapes over {result.frames.size} frames from "
            f"{len(result.marker_names)} markers, RMS residual {rms:.2f} mm, action '{action.name}'"
        )
        settings.last_report = summary
        for note in result.warnings:
            self.report({"WARNING"}, note)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


CLASSES = (FACECAP_OT_solve,)
