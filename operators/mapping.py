"""The mapping table of the Solve panel: source channel -> character shape with a gain."""

import bpy

from ..facecap_addon.scene import take
from ..facecap_addon.ui.greyed import needs, unless
from ..solvers.errors import FacecapError
from ..solvers.strategies.mapping import Mapping


class FACECAP_OT_mapping_add(bpy.types.Operator):
    """Add a mapping row (source channel drives a character shape with a gain)"""

    bl_idname = "facecap.mapping_add"
    bl_label = "Add Mapping Row"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        settings = context.scene.facecap
        settings.mapping.add()
        settings.active_mapping = len(settings.mapping) - 1
        return {"FINISHED"}


class FACECAP_OT_mapping_remove(bpy.types.Operator):
    """Remove the active mapping row"""

    bl_idname = "facecap.mapping_remove"
    bl_label = "Remove Mapping Row"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.mapping) > 0, "The mapping is empty")

    def execute(self, context):
        settings = context.scene.facecap
        settings.mapping.remove(settings.active_mapping)
        settings.active_mapping = max(0, min(settings.active_mapping, len(settings.mapping) - 1))
        return {"FINISHED"}


class FACECAP_OT_mapping_fill_by_name(bpy.types.Operator):
    """Preset: fill the table one-to-one by name and alias (calibration poses or weights-file channels -> shape keys)"""

    bl_idname = "facecap.mapping_fill_by_name"
    bl_label = "One-to-One by Name"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return needs(cls, context, "character", "mapping strategy")

    def execute(self, context):
        settings = context.scene.facecap
        try:
            sources = take.source_channel_names(settings)
            targets = take.character_target(settings.target).names
            mapping = Mapping.by_name(sources, targets, aliases=settings.mapping_aliases)
        except FacecapError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        settings.mapping.clear()
        for source, row in mapping.table().items():
            for target, gain in row.items():
                item = settings.mapping.add()
                item.source, item.target, item.gain = source, target, gain
        settings.active_mapping = 0
        for note in mapping.notes:
            self.report({"WARNING"}, note)
        self.report({"INFO"}, f"{len(settings.mapping)} mapping row(s) from {len(sources)} source channel(s)")
        return {"FINISHED"}


class FACECAP_OT_mapping_clear(bpy.types.Operator):
    """Preset: clear the table (every channel then maps one-to-one by name and alias at solve time)"""

    bl_idname = "facecap.mapping_clear"
    bl_label = "Clear Mapping"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return unless(cls, len(context.scene.facecap.mapping) > 0, "The mapping is empty")

    def execute(self, context):
        settings = context.scene.facecap
        settings.mapping.clear()
        settings.active_mapping = 0
        return {"FINISHED"}


CLASSES = (FACECAP_OT_mapping_add, FACECAP_OT_mapping_remove, FACECAP_OT_mapping_fill_by_name, FACECAP_OT_mapping_clear)
