"""A rig as the target: its controls, evaluated by Blender at the bound points, keyed and delivered."""
