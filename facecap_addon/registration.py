"""Register every class of the add-on: PropertyGroups first, unregistered in reverse."""

import bpy

from ..operators import CLASSES as OPERATOR_CLASSES
from . import panels, properties

CLASSES = properties.CLASSES + OPERATOR_CLASSES + panels.CLASSES


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register_properties()


def unregister():
    properties.unregister_properties()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
