"""Export Review Report: the take solved with the sidebar's settings, written as the review page."""

import bpy
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

from ..facecap_addon.render import review
from ..facecap_addon.ui.greyed import needs
from ..solvers.errors import FacecapError


class FACECAP_OT_export_review(bpy.types.Operator, ExportHelper):
    """Solve the take with these settings (as Solve and Key does) and write an HTML page to review it: the weight curves, the residual per frame and per marker, the removed head motion, and renders of the character at the worst frames and the strongest expressions. Nothing in the scene changes"""

    bl_idname = "facecap.export_review"
    bl_label = "Export Review Report"
    bl_options = {"REGISTER"}
    filename_ext = ".html"
    filter_glob: StringProperty(default="*.html", options={"HIDDEN"})
    truth_path: StringProperty(name="Truth Weights", subtype="FILE_PATH",
                               description="Optional: known weights (CSV frame,<shape>,...) drawn over the solved curves")
    render: BoolProperty(name="Render Contact Sheet", default=True,
                         description="Render the character at the worst frames and the strongest expressions (Workbench)")

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character", "take or weights")

    def execute(self, context):
        try:
            written = review.export_scene_review(context.scene.facecap, context.scene, self.filepath,
                                                 truth=self.truth_path or None, render=self.render)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if written["note"]:
            self.report({"WARNING"}, f"No contact sheet: {written['note']}")
        self.report({"INFO"}, f"Review report written to {written['path']} ({written['bytes'] / 1e6:.1f} MB)")
        return {"FINISHED"}


CLASSES = (FACECAP_OT_export_review,)
