"""Import a marker take into the scene."""

from pathlib import Path

import bpy
from bpy.props import EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..facecap_addon.properties import UNIT_ITEMS
from ..solvers.errors import FacecapError


class FACECAP_OT_import_markers(bpy.types.Operator, ImportHelper):
    """Import a marker take (wide CSV) as animated empties, one per marker"""

    bl_idname = "facecap.import_markers"
    bl_label = "Import Markers"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".csv"
    filter_glob: StringProperty(default="*.csv", options={"HIDDEN"})
    units: EnumProperty(name="Units", items=UNIT_ITEMS, default="mm")
    fps: FloatProperty(name="FPS", default=60.0, min=1.0)

    def execute(self, context):
        import warnings

        from ..facecap_addon import take
        from ..solvers.io_csv import read_markers_csv

        path = Path(bpy.path.abspath(self.filepath))
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                markers = read_markers_csv(path, units=self.units, fps=self.fps)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for w in caught:
            self.report({"WARNING"}, str(w.message))

        settings = context.scene.facecap
        take_name = path.stem
        coll = take.create_marker_empties(context.scene, markers, take_name)
        settings.take_name = take_name
        settings.markers_path = str(path)
        settings.units = self.units
        settings.fps = self.fps
        settings.marker_collection = coll
        settings.markers.clear()
        gaps = markers.gap_counts()
        for name in markers.names:
            item = settings.markers.add()
            item.name = name
            item.gaps = gaps[name]
            item.stable = name.startswith("head")  # layout convention; editable in the panel
        first, last = int(markers.frames[0]), int(markers.frames[-1])
        context.scene.frame_start, context.scene.frame_end = first, last
        context.scene.render.fps = int(round(self.fps))
        if not (first <= settings.neutral_first <= settings.neutral_last <= last):
            settings.neutral_first, settings.neutral_last = first, min(first + 29, last)
        self.report(
            {"INFO"},
            f"Imported {markers.n_markers} markers over {markers.n_frames} frames "
            f"({sum(gaps.values())} gap samples) into '{coll.name}'",
        )
        return {"FINISHED"}


CLASSES = (FACECAP_OT_import_markers,)
