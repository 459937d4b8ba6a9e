"""Remove head motion and keep it on an empty."""

import bpy

from ..solvers.errors import FacecapError


class FACECAP_OT_stabilise(bpy.types.Operator):
    """Fit the stable markers per frame, report the fit and key the removed head motion on an empty"""

    bl_idname = "facecap.stabilise"
    bl_label = "Stabilise"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = context.scene.facecap
        return s.marker_collection is not None and sum(m.stable for m in s.markers) >= 3

    def execute(self, context):
        from ..facecap_addon import take
        from ..solvers.stabilise import stabilise_rigid

        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            opts = take.retarget_settings(settings)
            stab = stabilise_rigid(markers, opts.stable_markers, reference_frames=opts.neutral_frames)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        head = take.key_head_motion(context.scene, stab, f"FaceCap Head {settings.take_name}")
        settings.head_object = head
        settings.flagged_frames = int(stab.flagged.sum())
        import numpy as np

        moving = [n for n, w in stab.marker_trust.items() if w < 0.5]
        if moving:
            self.report({"WARNING"}, f"Stable markers {moving} move with the face; they were left out of the fit")

        rms = float(np.nanmean(stab.rms) * 1e3) if np.isfinite(stab.rms).any() else float("nan")
        self.report(
            {"WARNING" if stab.flagged.any() else "INFO"},
            f"Stabilised {markers.n_frames} frames on {len(opts.stable_markers)} markers, "
            f"stable-marker RMS {rms:.3f} mm, {int(stab.flagged.sum())} frame(s) flagged; head motion on '{head.name}'",
        )
        return {"FINISHED"}


CLASSES = (FACECAP_OT_stabilise,)
