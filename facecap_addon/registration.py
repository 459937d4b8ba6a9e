"""Register every class of the add-on: PropertyGroups first, unregistered in reverse."""

import bpy

from ..operators import CLASSES as OPERATOR_CLASSES
from ..operators import importers
from . import panels, panels_tune, panels_video, properties, properties_video

# PropertyGroups first (the video group before the settings that point to it); panels in sidebar order
CLASSES = (properties_video.CLASSES + properties.CLASSES + OPERATOR_CLASSES + panels.CLASSES + panels_video.CLASSES
           + panels_tune.CLASSES)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register_properties()
    bpy.types.TOPBAR_MT_file_import.append(importers.menu_func_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(importers.menu_func_import)
    properties.unregister_properties()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
