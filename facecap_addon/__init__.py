"""The Blender layer: settings, panels, scene <-> numpy adapters and the headless CLI."""
