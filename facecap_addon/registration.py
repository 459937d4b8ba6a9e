"""Register the Blender layer's classes: the settings (PropertyGroups, ``Scene.facecap``) before the
operators that read them, the panels after the operators they draw (the package's ``register``
orders the three)."""

import bpy

from .ui import panels, panels_tune, panels_video, properties, properties_video

# the video group before the settings that point to it
PROPERTY_CLASSES = properties_video.CLASSES + properties.CLASSES
# in sidebar order
PANEL_CLASSES = panels.CLASSES + panels_video.CLASSES + panels_tune.CLASSES


def register_properties():
    for cls in PROPERTY_CLASSES:
        bpy.utils.register_class(cls)
    properties.register_properties()


def unregister_properties():
    properties.unregister_properties()
    for cls in reversed(PROPERTY_CLASSES):
        bpy.utils.unregister_class(cls)


def register_panels():
    for cls in PANEL_CLASSES:
        bpy.utils.register_class(cls)


def unregister_panels():
    for cls in reversed(PANEL_CLASSES):
        bpy.utils.unregister_class(cls)
