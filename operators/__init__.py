"""One operator per user action; thin: read settings -> core -> write -> report."""

import bpy

from . import (actor, binding, calibration, export, importers, mapping, neutral, report, rom, solve, stabilise, tuning,
               video, video_models)

CLASSES = (importers.CLASSES + binding.CLASSES + stabilise.CLASSES + neutral.CLASSES + solve.CLASSES + calibration.CLASSES
           + rom.CLASSES + actor.CLASSES + mapping.CLASSES + video.CLASSES + video_models.CLASSES + tuning.CLASSES
           + export.CLASSES + report.CLASSES)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(importers.menu_func_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(importers.menu_func_import)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
