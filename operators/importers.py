"""File > Import operators, one per format family, and drag-and-drop file handlers."""

import warnings
from pathlib import Path

import bpy
from bpy.props import CollectionProperty, EnumProperty, FloatProperty, StringProperty
from bpy.types import OperatorFileListElement
from bpy_extras.io_utils import ImportHelper

from ..facecap_addon.scene import import_scene, take
from ..facecap_addon.scene.scene_sources import markers_from_clip, markers_from_empties
from ..facecap_addon.ui.greyed import needs, unless
from ..solvers.capture.cleaning import CleanSettings, clean
from ..solvers.errors import FacecapError
from ..solvers.io import import_markers

IMPORT_UNIT_ITEMS = [
    ("AUTO", "From File", "Units written in the file (C3D, TRC, JSON) or guessed from the face size"),
    ("mm", "Millimetres", "Coordinates are millimetres"),
    ("cm", "Centimetres", "Coordinates are centimetres"),
    ("m", "Metres", "Coordinates are metres"),
    ("bu", "Blender Units", "Coordinates are Blender units of another scene; Unit Scale gives metres per unit"),
]
AXIS_ITEMS = [
    ("Z", "Z Up", "The file is Z-up, like Blender"),
    ("Y", "Y Up", "The file is Y-up (converted: x, y, z -> x, -z, y)"),
]


class _ImportMarkers(ImportHelper):
    """Shared options and execution; subclasses set the format and file filter."""

    bl_options = {"REGISTER", "UNDO", "PRESET"}
    format = None

    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE", "HIDDEN"})
    files: CollectionProperty(type=OperatorFileListElement, options={"SKIP_SAVE", "HIDDEN"})
    units: EnumProperty(name="Units", items=IMPORT_UNIT_ITEMS, default="AUTO")
    unit_scale: FloatProperty(name="Unit Scale", default=1.0, min=1e-9, precision=6,
                              description="Metres per file unit (for Blender Units)")
    fps: FloatProperty(name="FPS", default=0.0, min=0.0, description="Frame rate; 0 takes the file's")
    up_axis: EnumProperty(name="Up Axis", items=AXIS_ITEMS, default="Z")

    def invoke(self, context, event):
        if self.directory and len(self.files):  # dropped on the viewport: import directly
            return self.execute(context)
        return ImportHelper.invoke(self, context, event)

    def _paths(self):
        if self.directory and len(self.files):
            return [Path(self.directory) / f.name for f in self.files if f.name]
        return [Path(bpy.path.abspath(self.filepath))]

    def execute(self, context):
        options = {"up_axis": self.up_axis}
        if self.units == "bu":
            options["unit_scale"] = self.unit_scale
        imported = []
        for path in self._paths():
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = import_markers(path, format=self.format if self.format != "csv" else None,
                                            units=None if self.units == "AUTO" else self.units,
                                            fps=self.fps or None, **options)
            except FacecapError as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            markers = result.markers
            coll = import_scene.create_take(context.scene, markers, path.stem)
            import_scene.remember_take(context.scene, markers, path, coll)
            for note in result.notes:
                self.report({"INFO"}, f"{path.name}: {note}")
            gaps = sum(markers.gap_counts().values())
            imported.append(f"{markers.n_markers} markers over {markers.n_frames} frames ({gaps} gap samples, "
                            f"{len(markers.segments)} segment labels) into '{coll.name}'")
        self.report({"INFO"}, "Imported " + "; ".join(imported))
        return {"FINISHED"}


class FACECAP_OT_import_markers(bpy.types.Operator, _ImportMarkers):
    """Import a marker take in any supported format (C3D, TRC, CSV, JSON) as animated empties, one per marker"""

    bl_idname = "facecap.import_markers"
    bl_label = "Import Markers"
    format = None  # detected from the extension and the content
    filter_glob: StringProperty(default="*.c3d;*.trc;*.csv;*.tsv;*.txt;*.json", options={"HIDDEN"})


class FACECAP_OT_import_c3d(bpy.types.Operator, _ImportMarkers):
    """Import C3D motion capture points as animated empties (one collection per take)"""

    bl_idname = "facecap.import_c3d"
    bl_label = "Import C3D Markers"
    format = "c3d"
    filename_ext = ".c3d"
    filter_glob: StringProperty(default="*.c3d", options={"HIDDEN"})


class FACECAP_OT_import_trc(bpy.types.Operator, _ImportMarkers):
    """Import a TRC marker file (OpenSim / Motion Analysis) as animated empties"""

    bl_idname = "facecap.import_trc"
    bl_label = "Import TRC Markers"
    format = "trc"
    filename_ext = ".trc"
    filter_glob: StringProperty(default="*.trc", options={"HIDDEN"})


class FACECAP_OT_import_csv(bpy.types.Operator, _ImportMarkers):
    """Import a marker CSV (wide frame,<m>_x,... or long frame,marker,x,y,z); text columns become timeline markers"""

    bl_idname = "facecap.import_csv"
    bl_label = "Import CSV Markers"
    format = "csv"
    filename_ext = ".csv"
    filter_glob: StringProperty(default="*.csv;*.tsv;*.txt", options={"HIDDEN"})


class FACECAP_OT_import_json(bpy.types.Operator, _ImportMarkers):
    """Import a facecap JSON marker file as animated empties"""

    bl_idname = "facecap.import_json"
    bl_label = "Import JSON Markers"
    format = "json"
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})


class FACECAP_OT_use_selected_empties(bpy.types.Operator):
    """Use the selected animated empties as the take's markers (they are linked into a take collection, not copied)"""

    bl_idname = "facecap.use_selected_empties"
    bl_label = "Use Selected Empties"
    bl_options = {"REGISTER", "UNDO"}

    take_name: StringProperty(name="Take", default="", description="Take name (default: the active object's name)")

    @classmethod
    def poll(cls, context):
        return unless(cls, any(o.type == "EMPTY" for o in context.selected_objects),
                      "Select the marker empties first (each an animated empty named after its marker)")

    def execute(self, context):
        empties = sorted((o for o in context.selected_objects if o.type == "EMPTY"), key=lambda o: o.name)
        name = self.take_name or (context.active_object.name if context.active_object else "selection")
        try:
            markers = markers_from_empties(empties, fps=context.scene.render.fps / context.scene.render.fps_base)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        coll = bpy.data.collections.new(f"FaceCap {name}")
        context.scene.collection.children.link(coll)
        coll["facecap_take"] = name
        for obj in empties:
            coll.objects.link(obj)
        import_scene.remember_take(context.scene, markers, Path(name), coll)
        self.report({"INFO"}, f"Take '{name}': {markers.n_markers} empties over {markers.n_frames} keyed frames")
        return {"FINISHED"}


class FACECAP_OT_import_clip_tracks(bpy.types.Operator):
    """Import a movie clip's tracks as a 2D take (pixels, origin top-left; disabled markers are gaps)"""

    bl_idname = "facecap.import_clip_tracks"
    bl_label = "Import Clip Tracks"
    bl_options = {"REGISTER", "UNDO"}

    clip: StringProperty(name="Clip", default="", description="Movie clip (default: the scene's active clip)")

    @classmethod
    def poll(cls, context):
        return unless(cls, context.scene.active_clip is not None or len(bpy.data.movieclips) > 0,
                      "Open a movie clip with tracks first (Movie Clip Editor: Open, then track it)")

    def execute(self, context):
        clip = bpy.data.movieclips.get(self.clip) if self.clip else context.scene.active_clip
        if clip is None:
            self.report({"ERROR"}, f"no movie clip named '{self.clip}'" if self.clip else "the scene has no active clip")
            return {"CANCELLED"}
        try:
            scene_fps = context.scene.render.fps / context.scene.render.fps_base
            markers = markers_from_clip(clip, fallback_fps=scene_fps)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        coll = import_scene.create_take(context.scene, markers, clip.name)
        import_scene.remember_take(context.scene, markers, Path(clip.name), coll)
        gaps = sum(markers.gap_counts().values())
        self.report({"INFO"}, f"Imported {markers.n_markers} tracks over {markers.n_frames} frames ({gaps} gap samples) from '{clip.name}'")
        return {"FINISHED"}


class FACECAP_OT_clean_markers(bpy.types.Operator):
    """Clean the take's markers into a new take collection (the original stays untouched); reports every change"""

    bl_idname = "facecap.clean_markers"
    bl_label = "Clean Markers"
    bl_options = {"REGISTER", "UNDO"}

    fix_swaps: bpy.props.BoolProperty(name="Fix Label Swaps", default=False)
    spike_mad: FloatProperty(name="Spike Threshold", default=0.0, min=0.0,
                             description="Robust standard deviations of the second difference (0 = off)")
    fill_spline: bpy.props.IntProperty(name="Spline Fill", default=8, min=0, description="Longest gap (frames) filled by spline; 0 = off")
    fill_model: bpy.props.IntProperty(name="Model Fill", default=0, min=0,
                                      description="Longest gap (frames) rebuilt from the other markers; 0 = off")
    lowpass_hz: FloatProperty(name="Low-pass (Hz)", default=0.0, min=0.0, description="Zero-phase Butterworth cutoff; 0 = off")

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "take")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            markers = take.markers_from_collection(settings)
            options = CleanSettings(
                fix_swaps=self.fix_swaps,
                spike_mad=self.spike_mad or None,
                fill_spline=self.fill_spline,
                fill_model=self.fill_model,
                lowpass_hz=self.lowpass_hz or None,
            )
            result = clean(markers, options)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        name = f"{settings.take_name} clean"
        stable = {m.name for m in settings.markers if m.stable}
        coll = import_scene.create_take(context.scene, result.markers, name, set_scene_range=False)
        import_scene.remember_take(context.scene, result.markers, Path(settings.markers_path or name), coll)
        settings.take_name = name
        for item in settings.markers:
            item.stable = item.name in stable
        for line in result.report.summary().splitlines():
            self.report({"INFO"}, line)
        self.report({"INFO"}, f"Cleaned take in '{coll.name}'; the original collection is unchanged")
        return {"FINISHED"}


IMPORTERS = (FACECAP_OT_import_c3d, FACECAP_OT_import_trc, FACECAP_OT_import_csv, FACECAP_OT_import_json)
MENU_LABELS = {
    FACECAP_OT_import_c3d: "FaceCap Markers (.c3d)",
    FACECAP_OT_import_trc: "FaceCap Markers (.trc)",
    FACECAP_OT_import_csv: "FaceCap Markers (.csv)",
    FACECAP_OT_import_json: "FaceCap Markers (.json)",
}


def menu_func_import(self, context):
    """Append to ``bpy.types.TOPBAR_MT_file_import``."""
    for cls in IMPORTERS:
        self.layout.operator(cls.bl_idname, text=MENU_LABELS[cls])


class FACECAP_FH_c3d(bpy.types.FileHandler):
    bl_idname = "FACECAP_FH_c3d"
    bl_label = "FaceCap C3D markers"
    bl_import_operator = "facecap.import_c3d"
    bl_file_extensions = ".c3d"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type in {"VIEW_3D", "OUTLINER", "SEQUENCE_EDITOR"}


class FACECAP_FH_trc(bpy.types.FileHandler):
    bl_idname = "FACECAP_FH_trc"
    bl_label = "FaceCap TRC markers"
    bl_import_operator = "facecap.import_trc"
    bl_file_extensions = ".trc"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type in {"VIEW_3D", "OUTLINER", "SEQUENCE_EDITOR"}


# FileHandler exists from Blender 4.1; the extension targets 4.2+, so it is always there.
CLASSES = (
    FACECAP_OT_import_markers,
    FACECAP_OT_use_selected_empties,
    FACECAP_OT_import_clip_tracks,
    FACECAP_OT_clean_markers,
) + IMPORTERS + (
    FACECAP_FH_c3d,
    FACECAP_FH_trc,
)
